"""Interruptions, physics faults and failing episodes: work is never lost or corrupted."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.errors import UserInputError
from mjexplore.explorers import make_explorer
from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.scenes.canonical import resolve_scene


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "mjexplore.cli", *args]


def _wait_for(predicate, proc, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        assert proc.poll() is None, "the process ended before it could be interrupted"
        time.sleep(0.2)
    raise AssertionError("timed out waiting for the process")


def test_nan_state_ends_the_episode_with_a_reason():
    episode = Episode(resolve_scene("train_loop"), make_explorer("nearest"), 0,
                      EpisodeConfig(max_time=30.0))
    for _ in range(20):
        episode.step()
    episode.sim.data.qvel[0] = np.nan  # A solver blow-up.
    result = episode.run()
    assert result.metrics["end_reason"] == "physics_fault"
    assert result.metrics["exploration_time_s"] < 30.0
    assert np.isfinite(result.ratio_curve).all()


def test_tipped_robot_ends_the_episode_with_a_reason():
    episode = Episode(resolve_scene("train_loop"), make_explorer("nearest"), 0,
                      EpisodeConfig(max_time=30.0))
    episode.step()
    d = episode.sim.data
    d.qpos[3:7] = (np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0)  # Rolled onto its side.
    d.qpos[2] = 0.3
    result = episode.run()
    assert result.metrics["end_reason"] == "tipped_over"


@pytest.mark.slow
def test_sigint_during_explore_leaves_a_complete_readable_run(tmp_path):
    pytest.importorskip("mcap")
    from mcap.reader import make_reader

    from mjexplore.render.gl import check_rendering

    out = tmp_path / "run"
    args = ["explore", "--scene", "office", "--explorer", "nearest", "--out", str(out),
            "--max-time", "900"]
    try:
        check_rendering()
        args += ["--video", str(out / "video.mp4"), "--video-size", "160x120"]
        video = True
    except Exception:  # noqa: BLE001 - without GL the MCAP part still runs
        video = False
    proc = subprocess.Popen(_cli(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    tmp_runs = lambda: [p for p in tmp_path.iterdir() if p.name.startswith(".run.")]  # noqa: E731
    _wait_for(lambda: any((d / "episode.mcap").exists() or list(d.glob(".episode*"))
                          for d in tmp_runs()), proc, 120)
    time.sleep(4.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["end_reason"] == "interrupted"
    assert 0 < metrics["exploration_time_s"] < 900
    assert (out / "ter.png").stat().st_size > 0  # The stills of the run so far too.
    with open(out / "episode.mcap", "rb") as f:
        messages = sum(1 for _ in make_reader(f).iter_messages())
    assert messages > 10
    if video:
        import imageio.v2 as imageio

        assert len([f for f in imageio.get_reader(out / "video.mp4")]) >= 1
    assert not tmp_runs()


@pytest.mark.slow
def test_bench_killed_mid_sweep_resumes_and_skips_finished_episodes(tmp_path):
    out = tmp_path / "bench"
    args = _cli("bench", "--scenes", "train_loop", "--explorers", "nearest", "--seeds", "3",
                "--workers", "1", "--max-time", "20", "--out", str(out))
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    runs = out / "runs" / "train_loop" / "nearest"
    _wait_for(lambda: (runs / "seed0" / "metrics.json").is_file(), proc, 180)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    first = runs / "seed0" / "metrics.json"
    stamp = first.stat().st_mtime_ns
    assert not (out / "results.md").exists()
    r = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert first.stat().st_mtime_ns == stamp  # Not run again.
    assert all((runs / f"seed{i}" / "metrics.json").is_file() for i in range(3))
    assert "| train_loop | nearest | 3 |" in (out / "results.md").read_text()


def test_a_failing_episode_does_not_end_the_sweep(tmp_path, monkeypatch):
    from mjexplore.eval import sweep

    real = sweep.write_run

    def flaky(folder, scene, explorer, seed, config, mcap, **kwargs):
        if seed == 1:
            raise FloatingPointError("solver diverged")
        return real(folder, scene, explorer, seed, config, mcap, **kwargs)

    monkeypatch.setattr(sweep, "write_run", flaky)
    results = sweep.run_sweep(["train_loop"], ["nearest"], [0, 1], tmp_path,
                              EpisodeConfig(max_time=5.0), workers=1, progress=False)
    reasons = sorted(r["end_reason"] for r in results)
    assert reasons[0] == "error" and len(results) == 2
    table = (tmp_path / "results.md").read_text()
    assert "| train_loop | nearest | 1 |" in table and "train_loop/nearest/seed1" in table
    failure = json.loads((tmp_path / "runs" / "train_loop" / "nearest" /
                          "seed1.failed.json").read_text())
    assert "solver diverged" in failure["error"]


def test_a_resumed_sweep_reruns_interrupted_episodes_and_refuses_other_settings(tmp_path):
    from mjexplore.eval import sweep

    config = EpisodeConfig(max_time=5.0)
    sweep.run_sweep(["train_loop"], ["nearest"], [0, 1], tmp_path, config, workers=1,
                    progress=False)
    cut = tmp_path / "runs" / "train_loop" / "nearest" / "seed1" / "metrics.json"
    whole = json.loads(cut.read_text())
    cut.write_text(json.dumps({**whole, "end_reason": "interrupted",
                               "exploration_time_s": 1.0}))  # As Ctrl-C leaves it.
    results = sweep.run_sweep(["train_loop"], ["nearest"], [0, 1], tmp_path, config,
                              workers=1, progress=False)
    assert json.loads(cut.read_text()) == whole  # Run again, to its end.
    assert "interrupted" not in {r["end_reason"] for r in results}
    with pytest.raises(UserInputError, match="other episode settings"):
        sweep.run_sweep(["train_loop"], ["nearest"], [0], tmp_path,
                        EpisodeConfig(max_time=4.0), workers=1, progress=False)


def test_scenes_that_would_share_run_folders_are_refused(tmp_path):
    from mjexplore.eval.sweep import run_sweep, scene_label

    xml = str(resolve_scene("train_loop").xml)
    assert scene_label(xml) == "train_loop" and scene_label("maze") == "maze"
    with pytest.raises(UserInputError, match="share the run folders"):
        run_sweep([xml, "train_loop"], ["nearest"], [0], tmp_path / "o",
                  EpisodeConfig(max_time=1.0), workers=1, progress=False)
    assert not (tmp_path / "o").exists()


@settings(max_examples=15, deadline=None)
@given(width=st.floats(3.0, 8.0), height=st.floats(3.0, 8.0), seed=st.integers(0, 2**31 - 1),
       resolution=st.sampled_from([0.05, 0.1]))
def test_any_map_with_a_room_imports_as_a_valid_scene(tmp_path_factory, width, height, seed,
                                                      resolution):
    import mujoco

    from mjexplore.scenes.importer import scene_from_map_yaml
    from mjexplore.scenes.map_server import write_map
    from mjexplore.scenes.scene import build_spec, check_start

    rng = np.random.default_rng(seed)
    rows, cols = int(height / resolution), int(width / resolution)
    data = np.full((rows, cols), OCCUPIED, np.int8)
    m = int(round(0.2 / resolution))
    data[m:rows - m, m:cols - m] = FREE
    for _ in range(int(rng.integers(0, 4))):  # Furniture: blocks up to 0.6 m.
        r, c = rng.integers(0, rows), rng.integers(0, cols)
        h, w = rng.integers(1, int(0.6 / resolution) + 1, 2)
        data[r:r + h, c:c + w] = OCCUPIED
    data[rng.random(data.shape) < 0.02] = -1  # Unknown pixels in the image.
    folder = tmp_path_factory.mktemp("map")
    write_map(folder / "m.yaml", GridMap(data, resolution, (rng.uniform(-5, 5),
                                                            rng.uniform(-5, 5), 0.0)))
    scene = scene_from_map_yaml(folder / "m.yaml", seed=seed)
    check_start(scene.ground_truth, scene.start)  # A start where the robot fits.
    model = build_spec(scene).compile()
    assert model.ngeom > 1 and isinstance(model, mujoco.MjModel)
    gt = scene.ground_truth
    assert gt.shape == data.shape and gt.free.any()
    # Walls of the map stay walls; free space the robot reaches stays free.
    assert (gt.data[data == OCCUPIED] == OCCUPIED).all()




@pytest.mark.parametrize("setting", ["bound_heap_growth", "reuse_freed_memory"])
def test_malloc_settings_decide_whether_a_freed_block_is_faulted_in_again(setting):
    import platform
    import subprocess
    import sys

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("glibc's mallopt only")
    # A 1 MB block allocated and freed 100 times: from the heap, its pages are there after
    # the first time; mapped afresh each time, its 256 pages fault every time.
    script = f"""
import resource, numpy as np
from mjexplore.episode.workers import {setting}
assert {setting}()
np.ones(1 << 18, np.float32)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(100):
    np.ones(1 << 18, np.float32)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    faults = int(run.stdout)
    if setting == "reuse_freed_memory":
        assert faults < 1000
    else:
        assert faults > 20000


def test_bench_exits_non_zero_when_an_episode_failed(tmp_path, monkeypatch):
    from mjexplore.cli import main
    from mjexplore.eval import sweep

    def broken(folder, scene, explorer, seed, config, mcap):
        raise FloatingPointError("solver diverged")

    monkeypatch.setattr(sweep, "write_run", broken)
    assert main(["bench", "--scenes", "train_loop", "--explorers", "nearest", "--seeds", "1",
                 "--workers", "1", "--max-time", "5", "--out", str(tmp_path / "b")]) == 1
