"""The progress bar of ``mjexplore explore``: on a terminal only, and off with --no-progress."""

from __future__ import annotations

import io
import json
import sys

from mjexplore.cli import main


class Terminal(io.StringIO):
    """A stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def _explore(tmp_path, monkeypatch, stream, *extra: str) -> tuple[dict, str]:
    monkeypatch.setattr(sys, "stderr", stream)
    out = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
    stdout = io.StringIO()
    monkeypatch.setattr(sys, "stdout", stdout)
    assert main(["explore", "--scene", "train_loop", "--max-time", "5", "--no-mcap",
                 "--out", str(out), *extra]) == 0
    return json.loads(stdout.getvalue()), stream.getvalue()


def test_explore_shows_time_ratio_and_decisions_on_a_terminal(tmp_path, monkeypatch):
    metrics, bar = _explore(tmp_path, monkeypatch, Terminal())
    final = bar.replace("\r", "\n").strip().splitlines()[-1]  # The bar as it was left.
    assert final.startswith("explore:")
    assert "5/5 s simulated" in final
    assert f"ratio {metrics['exploration_ratio']:.1%}" in final
    assert f"decisions {metrics['decisions']}" in final
    assert metrics["decisions"] > 0


def test_explore_is_quiet_off_a_terminal_and_with_no_progress(tmp_path, monkeypatch):
    assert _explore(tmp_path, monkeypatch, io.StringIO())[1] == ""
    assert _explore(tmp_path, monkeypatch, Terminal(), "--no-progress")[1] == ""


class _Clock:
    """A monotonic clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_off_a_terminal_a_line_comes_through_a_phase_without_updates(monkeypatch):
    import io

    import mjexplore.io.progress as progress

    clock = _Clock()
    monkeypatch.setattr(progress.time, "monotonic", clock)
    stream = io.StringIO()  # Not a terminal: plain lines.
    with progress.Progress(10, "train", "decisions", stream=stream, every=30, tick=0) as bar:
        bar.update(2)
        bar.phase("updating")  # A PPO update: no update() for a while.
        during = len(stream.getvalue().splitlines())
        for _ in range(90):  # 90 s of ticks, one a second.
            clock.now += 1.0
            bar.heartbeat()
        lines = stream.getvalue().splitlines()[during:]
    # One line every 30 s through the silent phase (the close adds none: nothing new).
    assert len(lines) == 3, lines
    assert all(line.startswith("train: 2/10 decisions (20%), updating;") for line in lines)
    assert [line.rsplit("; ", 1)[1] for line in lines] == [
        "0:00:30 elapsed", "0:01:00 elapsed", "0:01:30 elapsed"]
    assert "\r" not in stream.getvalue()


def test_lines_at_every_update_still_say_they_are_alive_after_the_heartbeat(monkeypatch):
    import io

    import mjexplore.io.progress as progress

    clock = _Clock()
    monkeypatch.setattr(progress.time, "monotonic", clock)
    stream = io.StringIO()
    with progress.Progress(4, "bench", "episodes", stream=stream, every=0, tick=0) as bar:
        bar.update(1, detail="last office/nearest/seed0")
        before = len(stream.getvalue().splitlines())
        for _ in range(int(2.5 * progress.HEARTBEAT_S)):  # A long episode: no update.
            clock.now += 1.0
            bar.heartbeat()
        beats = stream.getvalue().splitlines()[before:]
    assert len(beats) == 2, beats  # One per HEARTBEAT_S of silence, not one per tick.
