"""Ctrl-C on ``explore --video`` and video sizes: what is kept is finished and playable,
nothing half-written sits under a real name, and the message says what was kept."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mjexplore.cli import main
from mjexplore.errors import UserInputError
from mjexplore.io.video import VideoWriter, finished_mp4
from mjexplore.render import gl
from mjexplore.render.recorder import VideoConfig


def _gl_or_skip() -> None:
    try:
        gl.check_rendering()
    except UserInputError as exc:
        pytest.skip(f"no offscreen GL backend loads here: {exc}")


def _frames(path: Path) -> int:
    import imageio.v2 as imageio

    reader = imageio.get_reader(path)
    try:
        return sum(1 for _ in reader)
    finally:
        reader.close()


def _explore(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, Path, Path]:
    """Starts ``explore --video`` in its own session (Ctrl-C in a terminal reaches the whole
    process group, ffmpeg's too): the process, the run folder and the video, which lies
    outside the run folder."""
    out, clips = tmp_path / "run", tmp_path / "clips"
    clips.mkdir()
    video = clips / "P.mp4"
    cmd = [sys.executable, "-m", "mjexplore.cli", "explore", "--explorer", "nearest",
           "--out", str(out), "--video", str(video), "--no-progress", *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    return proc, out, video


def _ctrl_c_when(proc: subprocess.Popen, ready, timeout: float = 60.0) -> tuple[str, str]:
    """Sends SIGINT to ``proc``'s process group once ``ready()``; its stdout and stderr.
    The process group is killed if it does not end."""
    try:
        deadline = time.monotonic() + timeout
        while not ready():
            if proc.poll() is not None:
                out, err = proc.communicate()
                raise AssertionError(f"ended (exit {proc.returncode}) before Ctrl-C: {err}")
            assert time.monotonic() < deadline, "timed out waiting for the moment to interrupt"
            time.sleep(0.005)
        os.killpg(proc.pid, signal.SIGINT)
        return proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()


def _hidden(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.name.startswith(".")]


@pytest.mark.slow
def test_ctrl_c_during_explore_keeps_the_run_folder_and_the_video_at_its_path(tmp_path):
    _gl_or_skip()
    proc, out, video = _explore(tmp_path, "--scene", "office", "--max-time", "900",
                                "--video-size", "160x120")
    tmp_runs = lambda: list(tmp_path.glob(".run.*.tmp"))  # noqa: E731
    started = []

    def episode_running() -> bool:  # For 2 s: its MCAP is being written.
        if not started and any(list(d.glob(".episode.mcap*")) for d in tmp_runs()):
            started.append(time.monotonic())
        return bool(started) and time.monotonic() - started[0] > 2.0

    _, err = _ctrl_c_when(proc, episode_running)
    assert proc.returncode == 130, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["end_reason"] == "interrupted"
    assert 0 < metrics["exploration_time_s"] < 900
    # The video at the path asked for: a finished MP4 with the frames so far (one per
    # simulated second, and the final state), the same file as the run folder's.
    assert finished_mp4(video)
    assert video.read_bytes() == (out / "video.mp4").read_bytes()
    assert _frames(video) >= int(metrics["exploration_time_s"])
    assert err.strip().splitlines() == [
        f"mjexplore explore: interrupted; the run folder {str(out)!r} is complete "
        f"(end_reason 'interrupted' at {metrics['exploration_time_s']:g} s simulated); the "
        f"video {str(video)!r} holds the episode up to then."]
    assert not tmp_runs() and not _hidden(video.parent)


@pytest.mark.slow
def test_ctrl_c_after_the_episode_ended_still_finishes_its_outputs(tmp_path):
    _gl_or_skip()
    proc, out, video = _explore(tmp_path, "--scene", "train_loop", "--video-size", "64x48")
    # metrics.json in the temporary run folder: the episode is over, figures being drawn.
    _, err = _ctrl_c_when(proc, lambda: any(tmp_path.glob(".run.*.tmp/metrics.json")))
    assert proc.returncode == 130, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["end_reason"] != "interrupted"  # It had ended on its own.
    assert (out / "map.png").stat().st_size > 0
    assert finished_mp4(video) and _frames(video) >= 2
    assert err.count("\n") == 1
    assert f"the run folder {str(out)!r} is complete (end_reason {metrics['end_reason']!r}" \
        in err and f"the video {str(video)!r} holds the episode whole" in err
    assert not _hidden(tmp_path) and not _hidden(video.parent)


def test_ctrl_c_before_the_episode_starts_says_nothing_was_kept(tmp_path):
    pytest.importorskip("foxglove")
    _gl_or_skip()
    # --live-wait holds the episode until Foxglove subscribes: it never starts.
    proc, out, video = _explore(tmp_path, "--scene", "train_loop", "--video-size", "64x48",
                                "--live", "0", "--live-wait")
    _, err = _ctrl_c_when(proc, lambda: any(tmp_path.glob(".run.*.tmp")))
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == (
        f"mjexplore explore: interrupted; nothing was kept: the run folder {str(out)!r} and "
        f"the video {str(video)!r} were not written.")
    assert not out.exists() and not video.exists()
    assert not _hidden(tmp_path) and not _hidden(video.parent)


@pytest.mark.parametrize("command", ["render", "explore"])
@pytest.mark.parametrize("size", ["10000x10000", "8194x16", "4098x4352"])
def test_a_video_size_no_h264_video_can_have_is_refused_up_front(tmp_path, capsys, command,
                                                                  size):
    video = tmp_path / "x.mp4"
    if command == "render":  # Refused before the run folder is even read.
        argv = ["render", str(tmp_path), "--out", str(video)]
    else:
        argv = ["explore", "--scene", "train_loop", "--out", str(tmp_path / "run"),
                "--video", str(video)]
    assert main([*argv, "--video-size", size, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"video size {size} per panel" in err
    assert "H.264" in err and "--video-size" in err
    assert list(tmp_path.iterdir()) == []  # No video, no run folder, no temp file.


def test_the_largest_h264_frames_are_accepted():
    for w, h in ((4096, 4352), (8192, 16), (16, 16384)):
        assert VideoConfig(width=w, height=h).width == w


def test_a_failing_encoder_leaves_no_file_under_the_real_name(tmp_path):
    path = tmp_path / "v.mp4"
    with pytest.raises(OSError, match="video encoder"), VideoWriter(path, 5.0) as writer:
        for _ in range(5):  # 20000 pixels wide: x264 refuses to open.
            writer.append(np.zeros((16, 20000, 3), np.uint8))
    assert not writer.written
    assert list(tmp_path.iterdir()) == []


def test_only_a_finished_mp4_counts_as_one(tmp_path):
    path = tmp_path / "v.mp4"
    with VideoWriter(path, 5.0) as writer:
        for k in range(6):
            writer.append(np.full((48, 64, 3), 40 * k, np.uint8))
    assert writer.written and finished_mp4(path) and _frames(path) == 6
    data = path.read_bytes()
    cut = tmp_path / "cut.mp4"
    for size in (len(data) - 1, len(data) // 2, 7, 0):  # Cut short: unplayable.
        cut.write_bytes(data[:size])
        assert not finished_mp4(cut), size
