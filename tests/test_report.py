"""The results report: sweep summaries (collect) and the report made from them."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mjexplore.episode import EpisodeConfig
from mjexplore.errors import UserInputError
from mjexplore.eval.report import build_report
from mjexplore.eval.report_sections import claims_table, masking_verdict, target_verdict
from mjexplore.eval.summaries import (
    RATIO_DT,
    collect_sweep,
    ratio_curve,
    read_summary,
    write_summary,
)

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    from mjexplore.eval.sweep import run_sweep

    out = tmp_path_factory.mktemp("sweep")
    run_sweep(["train_loop"], ["nearest", "potential"], [0, 1], out,
              EpisodeConfig(max_time=12.0), workers=1, progress=False,
              command="mjexplore bench --scenes train_loop ...")
    return out


def test_collect_keeps_each_runs_metrics_curve_and_kinematics(sweep, tmp_path):
    summary = collect_sweep(sweep, "lobby_real", kinematics_series=True, stills="nearest",
                            media_dir=tmp_path / "figs")
    assert summary["command"] == "mjexplore bench --scenes train_loop ..."
    assert sorted((r["method"], r["seed"]) for r in summary["runs"]) == [
        ("nearest", 0), ("nearest", 1), ("potential", 0), ("potential", 1)]
    for run in summary["runs"]:
        metrics = json.loads((sweep / "runs" / "train_loop" / run["method"] /
                              f"seed{run['seed']}" / "metrics.json").read_text())
        assert run["metrics"]["path_length_m"] == metrics["path_length_m"]
        curve = ratio_curve(run)
        assert curve[1, 0] == RATIO_DT and np.all(np.diff(curve[:, 1]) >= -1e-9)
        assert curve[-1, 1] == pytest.approx(metrics["exploration_ratio"], abs=2e-3)
        series = run["kinematics"]["series"]
        assert max(series["linear_velocity"]) <= 0.55 and len(series["linear_velocity"]) >= 10
        assert run["kinematics"]["stats"]["linear_acceleration_rms"] > 0
    assert summary["stills"] == {"train_loop": "lobby_real_train_loop_nearest.png"}
    assert (tmp_path / "figs" / "lobby_real_train_loop_nearest.png").stat().st_size > 1000
    path = write_summary(summary, tmp_path / "data" / "lobby_real.json")
    assert read_summary(path) == json.loads(json.dumps(summary))


def test_collect_records_the_weights_of_the_spec_each_label_ran(sweep, tmp_path):
    from mjexplore.policies.weights import weights_sha256

    copy = tmp_path / "sweep"
    shutil.copytree(sweep, copy)
    (copy / "runs" / "train_loop" / "nearest").rename(copy / "runs" / "train_loop" / "gvn")
    info = json.loads((copy / "sweep.json").read_text())
    (copy / "sweep.json").write_text(json.dumps({**info, "explorers": ["gvn", "potential"],
                                                 "specs": ["gvn:gvn_paper", "potential"]}))
    summary = collect_sweep(copy, "lobby_real")
    # The label gvn ran the paper's model, not the one --explorer gvn defaults to today.
    paper = REPO / "models" / "gvn_paper" / "policy.safetensors"
    assert summary["policies"]["gvn"]["sha256"] == weights_sha256(paper)
    assert set(summary["policies"]) == {"gvn"}


def test_report_has_the_tables_and_figures_of_collected_sweeps(sweep, tmp_path):
    data = tmp_path / "data"
    write_summary(collect_sweep(sweep, "lobby_real", kinematics_series=True), data /
                  "lobby_real.json")
    report = build_report(data, tmp_path / "results.md")
    text = report.read_text()
    assert "| train_loop | nearest | 2 |" in text and "| train_loop | potential | 2 |" in text
    assert "mjexplore bench --scenes train_loop ..." in text
    figures = sorted(p.name for p in (tmp_path / "results").glob("*.png"))
    assert figures == ["lobby_real_kinematics_train_loop.png", "lobby_real_ratio_train_loop.png"]
    # The experiments not collected are listed with the sweep that would make them, and so
    # are the methods a collected sweep lacks (gvn and gvn_v3 here).
    assert "## Not yet run" in text and "--out runs/table1" in text
    assert ("Not in this sweep yet: gvn, gvn_v3. Add them with `mjexplore bench --scenes "
            "lobby --explorers gvn:gvn_paper,gvn:gvn_v3 --profile real") in text
    assert "runs/lobby_real; mjexplore collect runs/lobby_real --experiment lobby_real --merge`" \
        in text


def _realistic_section(sweep, tmp_path, companion: str) -> tuple[str, str, dict]:
    """The report of the sweep collected as ``realistic`` and as ``companion``: its text,
    the realistic section and the realistic summary."""
    data = tmp_path / "data"
    summary = collect_sweep(sweep, "realistic")
    write_summary(summary, data / "realistic.json")
    write_summary(collect_sweep(sweep, companion), data / f"{companion}.json")
    text = build_report(data, tmp_path / "results.md").read_text()
    return text, text[text.index("## Sensing and localisation as on the real robot"):], summary


def test_the_realistic_setting_shows_pose_errors_beside_the_ideal_one(sweep, tmp_path):
    _, section, summary = _realistic_section(sweep, tmp_path, "table1")
    assert ("| scene | method | runs | pose RMSE (m) | pose max (m) | pose RMSE aligned (m) |"
            in section)
    assert "| train_loop | nearest | 2 | 0.000 +- 0.000 | 0.000 +- 0.000 | 0.000 +- 0.000 |" \
        in section
    # Runs from before the aligned error existed: no such column.
    for run in summary["runs"]:
        del run["metrics"]["pose_error_aligned_rmse_m"]
    write_summary(summary, tmp_path / "data" / "realistic.json")
    text = build_report(tmp_path / "data", tmp_path / "results.md").read_text()
    assert "| scene | method | runs | pose RMSE (m) | pose max (m) |\n" in text
    assert "aligned" not in text
    beside = section[section.index("Beside the ideal setting"):]
    assert "| train_loop | potential |" in beside and beside.count("| train_loop |") == 2
    assert "by where the robot believes it is" not in section  # No companion sweep yet.


def test_the_realistic_setting_shows_nearest_under_each_localization(sweep, tmp_path):
    text, section, summary = _realistic_section(sweep, tmp_path, "realistic_odometry")
    table = section[section.index("by where the robot believes it is"):]
    assert ("| scene | localisation | explored | ET (s) | IoU | pose RMSE (m) | "
            "pose RMSE aligned (m) |") in table
    nearest = [r for r in summary["runs"] if r["method"] == "nearest"]
    explored = sum(r["metrics"]["end_reason"] == "explored" for r in nearest)
    assert f"| train_loop | scan matching | {explored}/{len(nearest)} |" in table
    assert "| train_loop | odometry |" in table and "ground truth" not in table.split("##")[0]
    assert "## Realistic sensing with odometry alone" in text
    assert "--localization ground_truth" in text  # realistic_truth: listed as not yet run.


def test_collect_refuses_a_sweep_that_mixes_settings(sweep, tmp_path):
    mixed = tmp_path / "mixed"
    shutil.copytree(sweep, mixed)
    path = mixed / "runs" / "train_loop" / "potential" / "seed1" / "config.json"
    config = json.loads(path.read_text())
    config["episode"]["target_ratio"] = 0.9
    path.write_text(json.dumps(config))
    with pytest.raises(UserInputError, match="target_ratio"):
        collect_sweep(mixed, "table1")


def _runs(method: str, t80: list[float | None], t985: list[float | None]) -> list[dict]:
    return [{"metrics": {"t80_s": a, "t985_s": b}} for a, b in zip(t80, t985)]


def test_claims_compare_gvn_with_the_potential_field_as_the_paper_does():
    groups = {"loop": {"gvn": _runs("gvn", [90.0, 90.0], [100.0, None]),
                       "potential": _runs("potential", [100.0, 100.0], [90.0, 110.0])}}
    text, faster = claims_table(groups)
    assert "| loop | 80 % | 90.0 | 100.0 | +10.0 % | 7.0-11.1 % | yes |" in text
    # To 98.5 %: one gvn run of two got there, in 100 s, against 100 s: not faster.
    assert "| loop | 98.5 % | 100.0 (1/2) | 100.0 | +0.0 % | 4.0-16.2 % | no |" in text
    assert faster == [True, False]


def _ends(times: list[float], explored: int | None = None) -> list[dict]:
    explored = len(times) if explored is None else explored
    return [{"metrics": {"exploration_time_s": t,
                         "end_reason": "explored" if i < explored else "lingering"}}
            for i, t in enumerate(times)]


def test_the_masking_ablation_says_plainly_whether_iam_is_best():
    groups = {"loop": {"gvn_v2_naive": _ends([100.0, 102.0]),
                       "gvn_v2": _ends([90.0, 92.0])},
              # IAM faster, but one of its runs stopped short: naive masking is best.
              "maze": {"gvn_v2_naive": _ends([300.0, 300.0]),
                       "gvn_v2": _ends([200.0, 200.0], explored=1)}}
    text = masking_verdict(groups, "gvn_v2")
    assert text.startswith("Is IAM best? IAM is best on 1 of 2 scenes")
    assert "on loop IAM is best: 91.0 s against naive masking's 101.0 s;" in text
    assert "on maze IAM is not best: naive masking is (300.0 s against IAM's 200.0 s, " \
           "ranked 2 of 2)." in text
    # A lead within the runs' spread is no verdict to trust.
    close = {"loop": {"gvn_none": _ends([100.0, 120.0]), "gvn": _ends([105.0, 106.0])}}
    assert "(within the runs' spread: not conclusive)" in masking_verdict(close, "gvn")
    assert masking_verdict(close, "gvn").startswith("Is IAM best? IAM is best on every scene")


def test_the_table1_target_verdict_reads_the_better_classic_planner_per_scene():
    groups = {"loop": {"nearest": _ends([100.0]), "potential": _ends([110.0]),
                       "gvn_v3": _ends([85.0])},
              "maze": {"nearest": _ends([300.0]), "potential": _ends([250.0]),
                       "gvn_v3": _ends([225.0])}}
    text = target_verdict(groups, "gvn_v3")
    # 0.85 x nearest on the loop, 0.90 x potential on the maze: mean 0.875.
    assert "below both nearest-frontier's and the potential field's on 2 of 2 scenes" in text
    assert "0.875 x the better of the two" in text and text.endswith(": met.")
    groups["maze"]["gvn_v3"] = _ends([260.0])  # Slower than potential on the maze.
    assert target_verdict(groups, "gvn_v3").endswith(": not met.")
    groups["maze"]["gvn_v3"] = _ends([200.0, 200.0], explored=1)  # A run stopped short.
    assert "explored 2 of 3 runs" in target_verdict(groups, "gvn_v3")
    assert target_verdict(groups, "gvn_v3").endswith(": not met.")


def test_damaged_or_foreign_summaries_are_refused(tmp_path):
    bad = tmp_path / "table1.json"
    bad.write_text("{not json")
    with pytest.raises(UserInputError, match="mjexplore collect"):
        read_summary(bad)
    bad.write_text(json.dumps({"format": "something-else", "runs": []}))
    with pytest.raises(UserInputError, match="not a version-1"):
        read_summary(bad)
    with pytest.raises(UserInputError, match="no finished episode"):
        collect_sweep(tmp_path, "table1")


def test_the_committed_report_regenerates_from_the_committed_summaries(tmp_path):
    """docs/results.md is exactly what `mjexplore report` makes of docs/results/data."""
    data = DOCS / "results" / "data"
    assert sorted(p.stem for p in data.glob("*.json")), "no committed sweep summaries"
    r = subprocess.run([sys.executable, "-m", "mjexplore.cli", "report", "--data", str(data),
                        "--out", str(tmp_path / "results.md"), "--figures",
                        str(tmp_path / "results")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr

    def body(path: Path) -> list[str]:  # All but the line naming the data folder.
        return [line for line in path.read_text().splitlines()
                if not line.startswith("Generated by")]

    assert body(tmp_path / "results.md") == body(DOCS / "results.md")


def test_bench_refuses_a_repeated_scene_or_explorer(tmp_path):
    from mjexplore.cli import main

    for flag in (["--scenes", "train_loop,train_loop", "--explorers", "nearest"],
                 ["--scenes", "train_loop", "--explorers", "nearest,rrt,nearest"]):
        assert main(["bench", *flag, "--seeds", "1", "--out", str(tmp_path / "b")]) == 2
    assert not (tmp_path / "b").exists()


def test_the_report_says_what_lingering_meant_for_the_runs_it_shows():
    from mjexplore.eval.report_sections import _other_ends

    groups = {"maze": {"nearest": [{"metrics": {"end_reason": "lingering"}}]}}
    nav = {"linger_time": 60.0, "linger_radius": 0.5}
    old = _other_ends(groups, episode={"navigator": nav})
    new = _other_ends(groups, episode={"navigator": nav, "linger_strikes": 3})
    assert "lingering: 60 s within 0.5 m;" in old
    assert "lingering: 3 goals in a row given up after 60 s within 0.5 m each;" in new


def test_collect_and_report_name_the_planned_episodes_that_left_no_metrics(sweep, tmp_path):
    from mjexplore.eval.report_sections import _unfinished_note

    partial = tmp_path / "partial"
    shutil.copytree(sweep, partial)
    runs = partial / "runs" / "train_loop"
    shutil.rmtree(runs / "potential" / "seed1")  # Stopped before it ran.
    shutil.rmtree(runs / "nearest" / "seed1")  # Crashed:
    (runs / "nearest" / "seed1.failed.json").write_text(json.dumps(
        {"error": "RuntimeError: boom"}))
    summary = collect_sweep(partial, "table1")
    assert summary["unfinished"] == {
        "failed": [{"scene": "train_loop", "method": "nearest", "seed": 1,
                    "error": "RuntimeError: boom"}],
        "not_run": [{"scene": "train_loop", "method": "potential", "seed": 1}]}
    note = _unfinished_note(summary)
    assert "1 failed (an error): train_loop / nearest / seed 1" in note
    assert "1 not run (the sweep was stopped first): train_loop / potential / seed 1" in note
    assert _unfinished_note(collect_sweep(sweep, "table1")) is None


def test_the_report_names_each_experiments_revision_and_checks_runs_repeated_at_another():
    from mjexplore.eval.report import revisions_section

    def run(seed, time, method="nearest"):
        return {"scene": "maze", "method": method, "seed": seed, "resolution": 0.05,
                "metrics": {"exploration_time_s": time, "end_reason": "explored"}}

    settings = {"max_time": 1800.0}
    summaries = {
        "table1": {"run_revisions": ["a" * 40], "episode": settings,
                   "runs": [run(0, 300.0), run(1, 310.0), run(0, 200.0, "rrt")]},
        "gvn_v3": {"run_revisions": ["b" * 40], "episode": settings,
                   "runs": [run(0, 300.0), run(1, 311.0)]},
        # Other settings: not the same episodes, whatever the seeds.
        "realistic": {"run_revisions": ["c" * 40], "episode": {"max_time": 3600.0},
                      "runs": [run(0, 300.0)]},
    }
    text = "\n".join(revisions_section(summaries))
    assert "| table1 | 3 | `aaaaaaa` |" in text and "| realistic | 1 | `ccccccc` |" in text
    assert "table1 (`aaaaaaa`) and gvn_v3 (`bbbbbbb`) share 2 runs: 1 of them identical" in text
    assert "realistic (" not in text


def test_the_ladder_reads_each_method_against_pocket_nearest_per_seed():
    from mjexplore.eval.experiments import EXPERIMENTS
    from mjexplore.eval.report_sections import ladder_lines

    def runs(times):
        return [{"seed": k, "metrics": {"exploration_time_s": t}} for k, t in enumerate(times)]

    groups = {"maze": {"pocket_nearest": runs([100, 200]), "oracle": runs([50, 100])},
              "office": {"pocket_nearest": runs([400, 400]), "oracle": runs([300, 500]),
                         "oracle_5m": runs([400])}}
    text = "\n".join(ladder_lines(groups))
    oracle = next(line for line in text.splitlines() if line.startswith("| oracle ("))
    # maze 0.5, office (0.75 + 1.25) / 2 = 1.0; their mean 0.75; faster on 3 of 4 seeds.
    assert "| 0.500 | 1.000 | 2 | 0.750 |" in oracle and "| 3 / 1 |" in oracle
    partial = next(line for line in text.splitlines() if line.startswith("| oracle_5m |"))
    assert "| - | 1.000 | 1 | 1.000 |" in partial  # It ran on the office alone.
    from mjexplore.eval.report_sections import ladder

    assert any(e.name == "ladder" and ladder in e.parts for e in EXPERIMENTS)


def test_collect_leaves_out_an_episode_cut_off_by_ctrl_c(sweep, tmp_path):
    partial = tmp_path / "partial"
    shutil.copytree(sweep, partial)
    metrics = partial / "runs" / "train_loop" / "potential" / "seed1" / "metrics.json"
    data = json.loads(metrics.read_text())
    metrics.write_text(json.dumps({**data, "end_reason": "interrupted"}))
    summary = collect_sweep(partial, "table1")
    assert ("potential", 1) not in {(r["method"], r["seed"]) for r in summary["runs"]}
    assert len(summary["runs"]) == 3
    assert summary["unfinished"]["not_run"] == [
        {"scene": "train_loop", "method": "potential", "seed": 1}]


class _Launched(Exception):
    """Raised by the stand-in sweeps: the command got past every check before episodes."""


def _suggested_commands() -> list[str]:
    """Every command the report can suggest: each experiment's sweep and collect, and the
    sweep that adds one of its methods."""
    from mjexplore.eval.experiments import EXPERIMENTS

    texts = []
    for exp in EXPERIMENTS:
        texts.append(exp.with_collect)
        if "{explorers}" in exp.sweep:
            texts.append(dataclasses.replace(exp, methods=exp.methods[-1:]).with_collect)
    commands = []
    for text in texts:
        for part in text.split(";"):
            part = part.split("#")[0].strip()
            # ARiADNE's scenes come from a shell loop over its maps, outside this checkout.
            if part.startswith("mjexplore") and "$" not in part:
                commands.append(part)
    return commands


def test_every_command_the_report_suggests_runs_as_printed(tmp_path, monkeypatch):
    """Each suggested bench command passes every check bench makes before its first
    episode (methods, specs and weights, settings, repeated labels); each collect names an
    experiment the report knows and reads the sweep folder the bench wrote."""
    import shlex

    import mjexplore.eval.sweep as sweep
    import mjexplore.eval.team_sweep as team_sweep
    from mjexplore.cli import main
    from mjexplore.scenes.canonical import resolve_scene

    def launched(scenes, *args, **kwargs):
        for scene in scenes:
            if not scene.startswith("../shared"):  # Present where the shared data are.
                resolve_scene(scene)
        raise _Launched

    monkeypatch.setattr(sweep, "run_sweep", launched)
    monkeypatch.setattr(team_sweep, "run_team_sweep", launched)
    monkeypatch.chdir(tmp_path)
    commands = _suggested_commands()
    assert sum(c.startswith("mjexplore bench") for c in commands) >= 2 * 15
    for command in commands:
        argv = shlex.split(command)[1:]
        if argv[0] == "bench":
            with pytest.raises(_Launched):
                main(argv)
        else:
            assert argv[0] == "collect", command
            folder = tmp_path / argv[1]
            assert main(argv) == 2  # No runs in it here: a clean refusal, nothing else.
            assert not folder.exists()
