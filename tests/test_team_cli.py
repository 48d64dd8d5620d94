"""``mjexplore explore --robots N``: the team's run folder, its MCAP's namespaced topics,
and the checks on --robots and --starts."""

from __future__ import annotations

import json
from collections import Counter

import pytest
from conftest import shared_data

from mjexplore.cli import main
from mjexplore.errors import UserInputError
from mjexplore.eval.methods import team_explorers
from mjexplore.eval.placements import team_starts
from mjexplore.io.mcap_log import robot_topics
from mjexplore.scenes.canonical import resolve_scene


def test_explore_with_a_team_writes_its_run_folder(tmp_path):
    from mcap.reader import make_reader

    out = tmp_path / "team"
    assert main(["explore", "--scene", "train_loop", "--robots", "2", "--explorer",
                 "assign_greedy", "--max-time", "12", "--seed", "1", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["robots"] == 2 and metrics["explorer"] == "assign_greedy"
    for key in ("exploration_ratio", "t80_s", "t90_s", "t985_s", "path_length_m",
                "overlap_ratio", "robot_collisions", "collisions", "end_reason"):
        assert key in metrics
    assert [r["robot"] for r in metrics["per_robot"]] == ["robot_0", "robot_1"]
    config = json.loads((out / "config.json").read_text())
    assert config["robots"] == 2 and len(config["starts"]) == 2 and config["git_revision"]
    for name in ("ratio.csv", "ratio.png", "map.png", "episode.mcap",
                 "robot_0/kinematics.csv", "robot_1/coverage.csv"):
        assert (out / name).stat().st_size > 100
    with open(out / "episode.mcap", "rb") as f:
        reader = make_reader(f)
        counts = Counter(channel.topic for _s, channel, _m in reader.iter_messages())
    for name in ("robot_0", "robot_1"):
        for topic in robot_topics(name):
            assert counts[topic] > 0, topic
        assert counts[f"/{name}/scan"] == 12 * 10 + 1  # 10 Hz from time 0.
    assert counts["/tf"] == 2 * (12 * 10 + 1)
    assert counts["/map"] >= 12


def test_naive_teams_and_labels():
    explorers, label = team_explorers("nearest", 3)
    assert label == "naive_nearest" and len({id(e) for e in explorers}) == 3
    assert team_explorers("mmpf", 2)[1] == "mmpf"
    with pytest.raises(UserInputError, match="unknown explorer"):
        team_explorers("magic", 2)


def test_team_starts_from_text_and_placements():
    office = resolve_scene("office")
    assert team_starts(office, None, 2) is None
    assert team_starts(office, "13,17.8,0;14,16,1", 2) == [(13.0, 17.8, 0.0), (14.0, 16.0, 1.0)]
    with pytest.raises(UserInputError, match="one per robot"):
        team_starts(office, "13,17.8,0", 2)
    with pytest.raises(UserInputError, match="not one of its maps"):
        team_starts(office, "close", 2)
    room = resolve_scene(shared_data("explore_bench", "room.yaml"))
    assert team_starts(room, "far", 2) == [(8.0, 7.5, 1.57), (-7.5, -8.0, 1.57)]
    with pytest.raises(UserInputError, match="--robots 2"):
        team_starts(room, "close", 3)


@pytest.mark.parametrize("args, message", [
    (["--robots", "2", "--localization", "odometry", "--unknown-starts"], "ground_truth"),
    (["--robots", "2", "--mcap-profile", "ros2"], "Foxglove messages"),
    (["--explorer", "assign_greedy"], "--robots 2"),
    (["--robots", "2", "--starts", "1,2"], "one per robot"),
    (["--robots", "2", "--explorer", "nope"], "unknown explorer"),
    (["--unknown-starts"], "--robots 2"),
])
def test_team_explore_refuses_what_it_cannot_do(tmp_path, capsys, args, message):
    assert main(["explore", "--scene", "train_loop", "--out", str(tmp_path / "r"), *args]) == 2
    assert message in capsys.readouterr().err


def test_bench_with_a_team_puts_the_single_robot_beside(tmp_path):
    out = tmp_path / "bench"
    args = ["bench", "--scenes", "train_loop", "--robots", "2", "--explorers",
            "assign_greedy", "--seeds", "1", "--workers", "1", "--max-time", "6",
            "--out", str(out)]
    assert main(args) == 0
    table = (out / "results.md").read_text()
    assert "| train_loop | - | single nearest | 1 | 1 |" in table
    assert "| train_loop | drawn | assign_greedy | 2 | 1 |" in table
    for folder in ("single/nearest/seed0", "drawn/assign_greedy/seed0"):
        assert (out / "runs" / "train_loop" / folder / "metrics.json").is_file()
    done = out / "runs" / "train_loop" / "drawn" / "assign_greedy" / "seed0" / "metrics.json"
    stamp = done.stat().st_mtime_ns
    assert main(args) == 0  # Finished episodes are kept.
    assert done.stat().st_mtime_ns == stamp
    assert main([*args[:-2], "--starts", "close", "--out", str(tmp_path / "b2")]) == 2


def test_explore_with_unknown_starts_reports_its_merges(tmp_path):
    out = tmp_path / "team"
    assert main(["explore", "--scene", "train_loop", "--robots", "2", "--unknown-starts",
                 "--explorer", "assign_greedy", "--max-time", "12", "--seed", "1", "--no-mcap",
                 "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["unknown_starts"] and metrics["merge_attempts"] >= 1
    for key in ("merged", "merge_time_s", "merge_error_m", "merge_error_deg", "merges",
                "team_map_ratio"):
        assert key in metrics
    assert json.loads((out / "config.json").read_text())["team"]["unknown_starts"]
    assert main(["bench", "--scenes", "train_loop", "--unknown-starts", "--seeds", "1",
                 "--out", str(tmp_path / "b")]) == 2


def test_a_team_sweep_files_failures_and_refuses_to_resume_with_other_settings(
        tmp_path, monkeypatch, capsys):
    import json

    import mjexplore.eval.sweep as sweep

    real = sweep.write_run

    def flaky(folder, scene, method, seed, *args, **kwargs):
        if seed == 1 and kwargs.get("robots", 1) > 1:
            raise FloatingPointError("solver diverged")
        return real(folder, scene, method, seed, *args, **kwargs)

    monkeypatch.setattr(sweep, "write_run", flaky)
    out = tmp_path / "bench"
    args = ["bench", "--scenes", "train_loop", "--robots", "2", "--explorers", "assign_greedy",
            "--seeds", "2", "--workers", "1", "--max-time", "6", "--no-progress", "--out",
            str(out)]
    assert main(args) == 1  # One episode failed: listed, and the status says so.
    failed = out / "runs" / "train_loop" / "drawn" / "assign_greedy" / "seed1.failed.json"
    assert "FloatingPointError: solver diverged" in json.loads(failed.read_text())["error"]
    assert "train_loop/drawn/assign_greedy/seed1" in (out / "results.md").read_text()
    sweep = json.loads((out / "sweep.json").read_text())
    assert sweep["kind"] == "team" and sweep["robots"] == 2 and len(sweep["history"]) == 1
    capsys.readouterr()
    assert main(args[:-2] + ["--max-time", "7", "--out", str(out)]) == 2
    assert "other episode settings" in capsys.readouterr().err
