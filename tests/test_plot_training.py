"""The learning-curve report of a run folder (mjexplore plot-training:
mjexplore/eval/training_report.py and learning_curve.py): the curve, the cached baselines,
the JSON figures, and how often a residual policy departs from its prior."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import mjexplore.eval.training_report as plot_training
from mjexplore.cli import main as cli_main
from mjexplore.config import from_dict, to_dict
from mjexplore.eval.learning_curve import prior_departures
from mjexplore.learning.evaluation import NearestNodeRule, evaluate_policy_episodes
from mjexplore.learning.policy_network import fresh_policy, network_kwargs
from mjexplore.learning.train_config import TrainConfig
from mjexplore.policies.registry import layout_of
from mjexplore.policies.weights import save_policy_weights


def _plot(argv: list[str]) -> None:
    """``mjexplore plot-training ARGV``, which must succeed."""
    assert cli_main(["plot-training", *argv]) == 0

EPISODE = {"max_time": 300.0, "sim": {"dynamics": "grid"},
           "navigator": {"replan_rate_hz": 0.5, "replan_when_blocked": True}}
LAYOUTS = ["train_loop", "train_office_small"]
CONFIG = from_dict(TrainConfig, {
    "kind": "gvn", "n_envs": 1,
    "env": {"scenes": ["train_loop"], "max_decisions": 6, "episode": EPISODE,
            "observation": {"max_nodes": 64, "max_neighbours": 4, "memory_length": 3,
                            "features": "v2"}},
    "policy": {"hidden": 16, "prior_temperature": 1.0},
    "eval": {"scenes": LAYOUTS, "every": 0, "episode": EPISODE}})
# Per evaluation (decisions trained), per layout: exploration time (s), end reason.
EVALS = {8: [(120.0, "time_limit"), (200.0, "explored")],
         16: [(90.0, "explored"), (150.0, "explored")],
         24: [(100.0, "explored"), (140.0, "explored")]}


def _run(tmp_path: Path, revision: str = "abc123") -> Path:
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True, exist_ok=True)
    (run / "config.yaml").write_text(f"# git revision {revision}\n"
                                     + yaml.safe_dump(to_dict(CONFIG), sort_keys=False))
    lines = ["steps,scene,exploration_time_s,path_length_m,exploration_ratio,end_reason"]
    for steps, results in EVALS.items():
        for scene, (seconds, end) in zip(LAYOUTS, results, strict=True):
            ratio = 0.99 if end == "explored" else 0.8
            lines.append(f"{steps},{scene},{seconds},{seconds / 2},{ratio},{end}")
    (run / "eval.csv").write_text("\n".join(lines) + "\n")
    (run / "checkpoints" / "latest.json").write_text(
        json.dumps({"checkpoint": "step_000000032.pt", "num_timesteps": 32}))
    return run


def _fake_measure(calls: list):
    def make(config_path, workers):
        def measure(config, names):
            calls.append((config.eval.scene_list(), names))
            return {name: figures for name, figures in _FAKE_BASELINES.items() if name in names}
        return measure
    return make


def _layouts(loop: float, office: float, explored: tuple[bool, bool] = (True, True)):
    return [{"layout": name, "exploration_time_s": seconds, "path_length_m": seconds / 2,
             "explored": done}
            for name, seconds, done in zip(LAYOUTS, (loop, office), explored, strict=True)]


_FAKE_BASELINES = {"pocket_nearest": _layouts(100.0, 200.0),
                   "nearest": _layouts(90.0, 300.0),
                   "oracle": _layouts(60.0, 100.0, (True, False))}


def test_curve_json_fields_and_baselines_measured_once(tmp_path, monkeypatch, capsys):
    run = _run(tmp_path)
    calls: list = []
    monkeypatch.setattr(plot_training, "measure_baselines", _fake_measure(calls))
    _plot([str(run), str(tmp_path / "curve.png"), "--workers", "1"])
    figures = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert (tmp_path / "curve.png").read_bytes()[:4] == b"\x89PNG"
    assert [(p["steps"], p["mean_exploration_time_s"], p["explored"]) for p in
            figures["curve"]] == [(8, 160.0, 1), (16, 120.0, 2), (24, 120.0, 2)]
    # Model selection's choice: all explored, then the fastest; the first of equals.
    assert (figures["best"]["steps"], figures["best"]["mean_exploration_time_s"]) == (16, 120.0)
    assert (figures["decisions_trained"], figures["checkpoint"]) == (32, "step_000000032.pt")
    assert figures["revision"] == "abc123"
    assert figures["workers"] == {"n_envs": 1, "torch_threads": 1, "update_threads": 1}
    assert "wall_s" not in figures and "cores" not in figures  # Not recorded: not made up.
    assert "sessions" not in figures
    sessions = [{"host": "h", "cores": 2, "steps_from": 0, "steps_to": 16, "wall_s": 10.0},
                {"host": "h", "cores": 16, "steps_from": 16, "steps_to": 32, "wall_s": 5.5}]
    (run / "sessions.json").write_text(json.dumps({"sessions": sessions}))
    facts = plot_training.run_facts(run)
    assert facts["sessions"] == sessions and facts["sessions_wall_s"] == 15.5
    base = figures["baselines"]
    assert base["pocket_nearest"] == {"mean_exploration_time_s": 150.0, "explored": 2,
                                      "layouts": 2}
    assert base["oracle"]["mean_exploration_time_s"] == 80.0 and base["oracle"]["explored"] == 1
    assert base["cached"] is False and len(calls) == 1
    # Per layout 90 / 100 and 150 / 200: the mean of the ratios, not the ratio of means.
    paired = figures["best_vs_pocket_nearest"]
    assert paired["ratio"] == pytest.approx(0.825) and paired["layouts"] == 2
    assert (paired["faster"], paired["slower"]) == (2, 0)
    assert paired["ci95"][0] <= 0.825 <= paired["ci95"][1]
    assert figures["best_vs_oracle"]["ratio"] == pytest.approx((1.5 + 1.5) / 2)
    assert "departures" not in figures and "shipped" not in figures

    _plot([str(run), str(tmp_path / "curve.png")])  # Cached: not measured.
    again = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert again["baselines"]["cached"] is True and len(calls) == 1
    assert again["best_vs_pocket_nearest"] == paired
    _plot([str(run), str(tmp_path / "curve.png"), "--recompute-baselines"])
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["baselines"]["cached"] is False
    assert len(calls) == 2
    stored = json.loads((run / "baselines.json").read_text())
    [entry] = stored["entries"].values()
    assert entry["key"]["layouts"] == LAYOUTS and entry["key"]["revision"] == "abc123"

    _run(tmp_path, revision="def456")  # Another revision: another key, measured again.
    _plot([str(run), str(tmp_path / "curve.png")])
    capsys.readouterr()
    assert len(calls) == 3
    assert len(json.loads((run / "baselines.json").read_text())["entries"]) == 2
    assert not list(run.glob("*.tmp*")) and not list(run.glob(".*"))  # Written atomically.

    _plot([str(run), str(tmp_path / "curve.png"), "--no-baselines"])
    plain = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert "baselines" not in plain and len(calls) == 3


def test_a_baseline_missing_from_the_cache_is_measured_alone(tmp_path, monkeypatch, capsys):
    run = _run(tmp_path)
    calls: list = []
    monkeypatch.setattr(plot_training, "measure_baselines", _fake_measure(calls))
    _plot([str(run), str(tmp_path / "curve.png"), "--workers", "1"])
    capsys.readouterr()
    path = run / "baselines.json"
    stored = json.loads(path.read_text())
    [entry] = stored["entries"].values()
    del entry["nearest"]  # As an older file kept it: no nearest, one revision for all.
    entry["measured_at"] = "0ld"
    path.write_text(json.dumps(stored))
    _plot([str(run), str(tmp_path / "curve.png"), "--workers", "1"])
    figures = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert [names for _, names in calls] == [["pocket_nearest", "nearest", "oracle"],
                                             ["nearest"]]
    assert figures["baselines"]["cached"] is False
    assert figures["baselines"]["nearest"]["mean_exploration_time_s"] == 195.0
    measured_at = figures["baselines"]["measured_at"]
    assert measured_at["pocket_nearest"] == measured_at["oracle"] == "0ld"
    assert measured_at["nearest"] != "0ld"


def test_collected_run_shows_in_the_report_paired_against_the_prior(tmp_path, monkeypatch,
                                                                    capsys):
    from mjexplore.cli import main as cli
    from mjexplore.eval.report import build_report

    run = _run(tmp_path)
    monkeypatch.setattr(plot_training, "measure_baselines", _fake_measure([]))
    _plot([str(run), str(tmp_path / "curve.png"), "--workers", "1"])
    (run / "sessions.json").write_text(json.dumps({"sessions": [
        {"host": "h", "cores": 2, "device": "cpu", "revision": "aaaaaaa1", "steps_from": 0,
         "steps_to": 16, "wall_s": 5400.0},
        {"host": "h", "cores": 16, "device": "cuda", "revision": "bbbbbbb2",
         "steps_from": 16, "steps_to": 32, "wall_s": 1800.0}]}))
    data = tmp_path / "data"
    # No evaluations yet: nothing to keep.
    assert cli(["collect-training", str(tmp_path), "--data", str(data)]) == 2
    assert "eval.csv" in capsys.readouterr().err and not data.exists()
    assert cli(["collect-training", str(run), "--data", str(data), "--name", "long"]) == 0
    record = data / "training" / "long"
    assert sorted(p.name for p in record.iterdir()) == ["baselines.json", "config.yaml",
                                                        "eval.csv", "facts.json"]
    report = build_report(data, tmp_path / "out" / "results.md").read_text()
    section = report[report.index("## Training runs"):]
    assert "Started at revision `aaaaaaa`; 32 decisions trained so far" in section
    assert "2.0 h of wall time on 2 or 16 cores (cpu, cuda)" in section
    # Per evaluation, paired per layout against pocket_nearest's 100 and 200 s.
    assert "| 8 | 1/2 | 160.0 | 1.100 (" in section  # (120 / 100 + 200 / 200) / 2
    assert "| 16 (kept) | 2/2 | 120.0 | 0.825 (" in section
    assert "| 2 / 0 | 0.50 | 0.750 (" in section  # Beside: (90 / 90 + 150 / 300) / 2.
    assert ("pocket_nearest 150.0 s (2/2 explored); nearest 195.0 s (2/2 explored); oracle "
            "80.0 s (1/2 explored)") in section
    assert (tmp_path / "out" / "results" / "training_long.png").read_bytes()[:4] == b"\x89PNG"


def test_baselines_are_the_prior_and_the_oracle_on_the_validation_layouts(tmp_path):
    run = _run(tmp_path)
    config = from_dict(TrainConfig, {**to_dict(CONFIG), "eval": {
        **to_dict(CONFIG.eval), "scenes": ["train_loop"]}})
    names = plot_training.applicable_baselines(config)
    assert names == ["pocket_nearest", "nearest", "oracle"]
    v1 = dataclasses.replace(
        config, policy=dataclasses.replace(config.policy, prior_temperature=None),
        env=dataclasses.replace(config.env, observation=dataclasses.replace(
            config.env.observation, features="v1")))
    assert plot_training.applicable_baselines(v1) == ["nearest", "oracle"]  # No path feature.
    measured = plot_training.measure_baselines(run / "config.yaml", workers=1)(config, names)
    assert set(measured) == set(names)
    # The prior alone, with the settings the held-out evaluation (eval.csv) runs.
    [rule] = evaluate_policy_episodes(NearestNodeRule(CONFIG.policy.prior_pocket_m), config)
    [mine] = measured["pocket_nearest"]
    assert mine["layout"] == "train_loop"
    assert mine["exploration_time_s"] == rule["exploration_time_s"]
    assert mine["path_length_m"] == rule["path_length_m"]
    [oracle] = measured["oracle"]
    assert oracle["layout"] == "train_loop" and oracle["exploration_time_s"] > 0
    [nearest] = measured["nearest"]  # The classic explorer on the same episode.
    assert nearest["layout"] == "train_loop" and nearest["exploration_time_s"] > 0


def test_departures_from_the_prior_none_without_a_residual_some_with_a_large_one(
        tmp_path, capsys):
    torch.manual_seed(0)
    policy = fresh_policy(CONFIG)
    last = policy.mlp_extractor.actor[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    run = _run(tmp_path)
    save_policy_weights(run / "best.safetensors", policy, CONFIG.kind, network_kwargs(CONFIG),
                        layout_of(CONFIG.kind, CONFIG.env),
                        {"config": to_dict(CONFIG), "num_timesteps": 16})
    _plot([str(run), str(tmp_path / "curve.png"), "--no-baselines", "--departures"])
    figures = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert figures["shipped"] == {"weights": "best.safetensors", "decisions": 16}
    counted = figures["departures"]
    assert counted["weights"].endswith("best.safetensors") and counted["trained"] == 16
    assert json.loads((run / "departures.json").read_text()) == counted  # For the report.
    assert counted["decisions"] > 0 and counted["choices"] > 0
    assert counted["departures"] == 0 and counted["share"] == 0.0
    assert [r["layout"] for r in counted["per_layout"]] == LAYOUTS

    with torch.no_grad():
        last.weight.copy_(100.0 * torch.as_tensor(
            np.random.default_rng(0).normal(size=tuple(last.weight.shape)), dtype=torch.float32))
    large = prior_departures(policy, CONFIG, scenes=["train_loop"])
    assert large["departures"] > 0
    assert 0 < large["share"] <= large["share_of_choices"] <= 1


def test_wall_times_are_what_tensorboard_recorded(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    for part, (first, second) in enumerate(((1.5, 0.5), (2.0, 1.0))):  # A run and a resume.
        writer = SummaryWriter(str(tmp_path / "tb" / f"ppo_{part}"))
        writer.add_scalar("time/collect_s", first, 8, walltime=100.0 + 50 * part)
        writer.add_scalar("time/update_s", second, 8, walltime=101.0 + 50 * part)
        writer.add_scalar("time/collect_s", first, 16, walltime=110.0 + 50 * part)
        writer.close()
    assert plot_training.wall_times(tmp_path) == {"collect": 7.0, "update": 1.5, "span": 20.0}
    assert plot_training.wall_times(tmp_path / "none") == {}
