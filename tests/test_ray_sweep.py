"""Sweeps on Ray: the same run folders as the process pool, resume after Ctrl-C, lost
workers retried or reported, files that travel as data."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import ray

from mjexplore.cli import main
from mjexplore.errors import UserInputError
from mjexplore.io.bundle import pack_folder, unpack, write_files
from mjexplore.io.ray_cluster import map_unordered
from mjexplore.policies.models import MODELS_DIR, WEIGHTS_NAME

SWEEP = ["bench", "--scenes", "train_loop", "--explorers", "nearest,potential", "--seeds", "2",
         "--max-time", "15", "--no-progress"]


def _files(out: Path) -> dict[str, bytes]:
    """Every run folder's files; config.json without the command that made the run (which
    differs: one says --ray)."""
    files = {}
    for path in sorted((out / "runs").rglob("*")):
        if path.is_file():
            data = path.read_bytes()
            if path.name == "config.json":
                config = json.loads(data)
                assert config.pop("command", None) in (None, *[
                    plan["command"] for plan in _history(out)])
                data = json.dumps(config).encode()
            files[path.relative_to(out / "runs").as_posix()] = data
    return files


def _history(out: Path) -> list[dict]:
    sweep = out / "sweep.json"
    return json.loads(sweep.read_text())["history"] if sweep.is_file() else []


@pytest.mark.slow
def test_a_ray_sweep_writes_the_run_folders_the_process_pool_writes(tmp_path):
    mine = tmp_path / "mine"  # Weights given by path travel with the tasks.
    mine.mkdir()
    shutil.copy(MODELS_DIR / "gvn_v3" / WEIGHTS_NAME, mine / WEIGHTS_NAME)
    sweep = SWEEP + ["--explorers", f"nearest,gvn:{mine}"]
    assert main(sweep + ["--workers", "2", "--out", str(tmp_path / "pool")]) == 0
    assert main(sweep + ["--workers", "2", "--ray", "--out", str(tmp_path / "ray")]) == 0
    assert not ray.is_initialized()  # The instance it started is shut down.
    pool, on_ray = _files(tmp_path / "pool"), _files(tmp_path / "ray")
    assert len(pool) == 4 * 8 and sorted(pool) == sorted(on_ray)
    different = [name for name in pool if pool[name] != on_ray[name]]
    assert not different  # Metrics, curves, config (the scene as given), figures.
    for name in ("results.md", "results.csv"):
        assert (tmp_path / "pool" / name).read_text() == (tmp_path / "ray" / name).read_text()


@pytest.mark.slow
def test_a_team_sweep_on_ray_writes_what_the_process_pool_writes(tmp_path):
    team = ["bench", "--scenes", "train_loop", "--robots", "2", "--explorers", "assign_greedy",
            "--seeds", "1", "--max-time", "6", "--no-progress"]
    assert main(team + ["--workers", "1", "--out", str(tmp_path / "pool")]) == 0
    assert main(team + ["--ray", "--out", str(tmp_path / "ray")]) == 0
    pool, on_ray = _files(tmp_path / "pool"), _files(tmp_path / "ray")
    assert "train_loop/drawn/assign_greedy/seed0/metrics.json" in pool
    assert "train_loop/single/nearest/seed0/metrics.json" in pool
    assert pool == on_ray
    assert (tmp_path / "pool" / "results.md").read_text() == \
        (tmp_path / "ray" / "results.md").read_text()


@pytest.mark.slow
def test_a_ray_sweep_stopped_by_ctrl_c_resumes_without_running_finished_episodes(tmp_path):
    out = tmp_path / "sweep"
    argv = [sys.executable, "-m", "mjexplore.cli", *SWEEP, "--seeds", "3", "--max-time", "30",
            "--workers", "1", "--ray", "--out", str(out)]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not list(out.glob("runs/*/*/seed*/metrics.json")) and time.monotonic() < deadline:
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0, err
    first = {p: p.stat().st_mtime_ns for p in out.glob("runs/*/*/seed*/metrics.json")}
    assert 1 <= len(first) < 6, err
    assert main(SWEEP + ["--seeds", "3", "--max-time", "30", "--workers", "1", "--ray", "--out",
                         str(out)]) == 0
    assert {p: p.stat().st_mtime_ns for p in first} == first  # Not run again.
    assert len(list(out.glob("runs/*/*/seed*/metrics.json"))) == 6
    assert not list(out.glob("runs/**/*.failed.json"))


def _dies_once(marker: str, value: int) -> int:
    """Kills its worker process the first time (no marker yet), then returns ``value``."""
    if not os.path.exists(marker):
        Path(marker).touch()
        os._exit(1)
    return value


def _always_dies() -> None:
    os._exit(1)


def _raises(text: str) -> None:
    raise UserInputError(text)


@pytest.fixture
def local_ray():
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # Workers cannot import tests.
    ray.init(address="local", num_cpus=2, include_dashboard=False)
    try:
        yield
    finally:
        ray.shutdown()
        ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def test_tasks_whose_worker_dies_are_retried_then_reported(local_ray, tmp_path):
    calls = [(str(tmp_path / "marker"), 7), (), ("no such scene",)]
    fns = {0: _dies_once, 1: _always_dies, 2: _raises}
    got = {}
    for k, fn in fns.items():
        for _, result, error in map_unordered(fn, calls[k:k + 1], retries=1):
            got[k] = (result, error)
    assert got[0] == (7, None)  # Its worker died once; the retry ran it.
    assert got[1][0] is None and isinstance(got[1][1], ray.exceptions.WorkerCrashedError)
    assert isinstance(got[2][1], UserInputError) and "no such scene" in str(got[2][1])


def _kills_its_worker(job, folder, scene, spec):
    os._exit(1)


def test_a_sweep_episode_whose_worker_keeps_dying_lands_in_failed_json(local_ray, tmp_path):
    from mjexplore.eval.remote import run_remote
    from mjexplore.eval.sweep import Job, episode_failure, file_results

    job = Job("train_loop", "nearest", 0, "nearest")
    [failure] = file_results(tmp_path, run_remote([job], _kills_its_worker, episode_failure,
                                                  "local"))
    assert failure["end_reason"] == "error" and "WorkerCrashedError" in failure["error"]
    record = tmp_path / "runs" / "train_loop" / "nearest" / "seed0.failed.json"
    assert json.loads(record.read_text()) == failure
    assert not (tmp_path / "runs" / "train_loop" / "nearest" / "seed0").exists()


def test_a_result_from_another_revision_is_refused(local_ray, monkeypatch):
    import mjexplore.io.ray_cluster as ray_cluster

    monkeypatch.setattr(ray_cluster, "git_revision", lambda: "this-revision")
    [(_, result, error)] = list(map_unordered(abs, [(-3,)]))
    assert result is None and "same revision on every machine" in str(error)


def test_bundles_travel_a_folder_and_refuse_paths_outside_it(tmp_path):
    src = tmp_path / "office"
    (src / "meshes").mkdir(parents=True)
    (src / "scene.xml").write_text("<mujoco/>")
    (src / "meshes" / "wall.obj").write_bytes(b"v 0 0 0\n")
    files = pack_folder(src)
    assert files == {"meshes/wall.obj": b"v 0 0 0\n", "scene.xml": b"<mujoco/>"}
    copy = unpack(files, "office", root=tmp_path / "tmp")
    assert copy.name == "office" and pack_folder(copy) == files
    assert unpack(files, "office", root=tmp_path / "tmp") == copy  # Written once.
    changed = unpack(files | {"scene.xml": b"<mujoco model='b'/>"}, "office",
                     root=tmp_path / "tmp")
    assert changed != copy and (changed / "scene.xml").read_bytes() == b"<mujoco model='b'/>"
    with pytest.raises(ValueError, match="outside"):
        write_files(tmp_path / "tmp", {"../escape": b""})
    with pytest.raises(UserInputError, match="folder of its own"):
        pack_folder(src, max_bytes=4)


PREDICTOR = ("episodes: 3\nvalidation_every: 2\nrecord_share: 0.5\nexplorers: [nearest]\n"
             "env:\n  procedural: {families: [rooms], width: [12.0, 12.0], "
             "height: [10.0, 10.0]}\n  episode:\n    max_time: 120.0\n"
             "    sim: {dynamics: grid}\n")


def test_predictor_data_recorded_on_ray_equals_the_process_pool_s(tmp_path):
    import numpy as np

    from mjexplore.learning.predictor_training import collect, load_predictor_config

    (tmp_path / "predictor.yaml").write_text(PREDICTOR)
    config = load_predictor_config(tmp_path / "predictor.yaml")
    collect(config, tmp_path / "pool", workers=1)
    collect(config, tmp_path / "ray", workers=2, ray_address="local")
    assert not ray.is_initialized()
    shards = sorted(p.name for p in (tmp_path / "pool").iterdir())
    assert len(shards) == 3 and shards == sorted(p.name for p in (tmp_path / "ray").iterdir())
    for name in shards:
        with np.load(tmp_path / "pool" / name) as a, np.load(tmp_path / "ray" / name) as b:
            assert len(a["inputs"]) > 0
            for key in ("inputs", "truth", "rule"):
                np.testing.assert_array_equal(a[key], b[key])
