"""tools/research/es_residual.py: evolution strategies on a linear residual of the prior."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mjexplore.envs.observation import BLACKLISTED, PATH, POCKET, UNREACHABLE
from mjexplore.learning.evaluation import NearestNodeRule
from tools.research.es_residual import SCALES, LinearResidualRule

REPO = Path(__file__).resolve().parents[1]

RECIPE = """
kind: gvn
seed: 0
env:
  procedural: {families: [rooms], width: [12.0, 13.0], height: [10.0, 11.0]}
  max_decisions: 40
  observation: {max_nodes: 64, max_neighbours: 4, memory_length: 2, features: v3,
                pockets: training/pockets.safetensors}
  episode:
    max_time: 600.0
    sim: {dynamics: grid}
policy: {hidden: 16, prior_temperature: 1.0, prior_pocket_m: 50.0}
eval:
  procedural: {families: [rooms], width: [12.0, 13.0], height: [10.0, 11.0]}
  layouts: 1
  every: 0
  episode:
    max_time: 600.0
    sim: {dynamics: grid}
"""


def _observation(rng, nodes=12):
    """A v3 observation's node features (every node reachable) and a valid mask."""
    features = rng.uniform(0.0, 1.0, (nodes, 10)).astype(np.float32)
    features[:, UNREACHABLE] = features[:, BLACKLISTED] = 0.0
    features[:, PATH] = rng.uniform(0.0, 30.0, nodes)
    features[:, POCKET] = rng.uniform(0.0, 1.0, nodes)
    mask = rng.random(nodes) < 0.7
    mask[0] = True
    return {"node_features": features.reshape(-1), "node_mask": np.ones(nodes, np.float32)}, mask


def test_zero_weights_are_pocket_nearests_rule_and_weights_move_the_choice():
    rng = np.random.default_rng(0)
    prior = NearestNodeRule(pocket_m=50.0)
    # A residual that prefers likely small pockets (pocket term -5 x 20 m a unit).
    pockets_first = np.zeros(len(SCALES))
    pockets_first[4] = -5.0
    moved = 0
    for _ in range(50):
        obs, mask = _observation(rng)
        expected = prior.predict(obs, action_masks=mask)[0]
        assert LinearResidualRule(np.zeros(len(SCALES))).predict(obs, action_masks=mask)[0] \
            == expected
        choice = LinearResidualRule(pockets_first).predict(obs, action_masks=mask)[0]
        assert mask[choice]
        moved += choice != expected
    assert moved > 0


@pytest.mark.slow
def test_an_iteration_logs_the_centre_against_the_prior_and_resumes(tmp_path):
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(RECIPE)
    out = tmp_path / "es"
    cmd = [sys.executable, "-m", "tools.research.es_residual", "--config", str(recipe),
           "--out", str(out), "--iterations", "1", "--pairs", "1", "--layouts", "1",
           "--fixed", "--workers", "1"]
    subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=True)
    rows = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    step, final = rows
    # Before any step the centre is the prior: the same episode, to the decimal.
    times = np.array(step["times"])
    assert times.shape == (4, 1) and times[2, 0] == times[3, 0]
    assert step["centre_vs_prior"]["ratio"] == 1.0
    state = json.loads((out / "state.json").read_text())
    assert state["iteration"] == 1 and state["prior_times"] == times[3].tolist()
    assert final["validate"] == "final" and final["layouts"] == 1
    assert final["theta"] == pytest.approx(state["theta"])
    assert state["prior_eval_times"]["validation_1"] == final["times"][1]
    # Resumed at its last iteration: no more steps, one more validation, against the prior's
    # kept episodes.
    subprocess.run(cmd + ["--resume"], cwd=REPO, capture_output=True, text=True, check=True)
    rows = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r.get("validate") for r in rows] == [None, "final", "final"]
    assert rows[2]["times"] == rows[1]["times"]
