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


def test_off_a_terminal_a_line_comes_through_a_phase_without_updates():
    import io
    import time

    from mjexplore.io.progress import Progress

    stream = io.StringIO()  # Not a terminal: plain lines.
    with Progress(10, "train", "decisions", stream=stream, every=0.1) as bar:
        bar.update(2)
        bar.phase("updating")  # A PPO update: no update() for a while.
        during = len(stream.getvalue().splitlines())
        time.sleep(1.5)
        lines = stream.getvalue().splitlines()[during:]
    assert len(lines) >= 2, lines  # The ticker spoke during the silent phase.
    assert all(line.startswith("train: 2/10 decisions (20%), updating;") for line in lines)
    assert "\r" not in stream.getvalue()


def test_lines_at_every_update_still_say_they_are_alive_after_the_heartbeat(monkeypatch):
    import io
    import time

    import mjexplore.io.progress as progress

    monkeypatch.setattr(progress, "HEARTBEAT_S", 0.3)
    stream = io.StringIO()
    with progress.Progress(4, "bench", "episodes", stream=stream, every=0) as bar:
        bar.update(1, detail="last office/nearest/seed0")
        time.sleep(1.5)  # A long episode: no update.
    lines = stream.getvalue().splitlines()
    assert 3 <= len(lines) <= 8, lines  # Not one per tick of the ticker (1 s).
