"""tools/research/rollout_advantage.py: the exact effect of departing from the prior, by forked
rollouts, and a fit of it on what the actor observes."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_es_residual import RECIPE, _observation

from mjexplore.learning.evaluation import NearestNodeRule
from tools.research.rollout_advantage import (
    CONTEXT,
    PAIRWISE,
    PRIVILEGED,
    PredictedDepartureRule,
    _ridge,
    _tour,
)

REPO = Path(__file__).resolve().parents[1]


def test_a_fit_predicting_no_gain_is_the_prior_and_one_predicting_gain_departs():
    rng = np.random.default_rng(1)
    prior = NearestNodeRule(pocket_m=50.0)
    zero = PredictedDepartureRule(np.zeros(12), margin=0.0)
    # Predicted d = 0.01 x logit gap - 0.5 x pocket term: likely pockets gain.
    weights = np.zeros(12)
    weights[4], weights[10] = -0.5, 0.01
    pockets = PredictedDepartureRule(weights, margin=0.0)
    moved = 0
    for _ in range(50):
        obs, mask = _observation(rng)
        expected = prior.predict(obs, action_masks=mask)[0]
        assert zero.predict(obs, action_masks=mask)[0] == expected
        choice = pockets.predict(obs, action_masks=mask)[0]
        assert mask[choice]
        moved += choice != expected
    assert moved > 0


def test_ridge_recovers_a_linear_effect():
    rng = np.random.default_rng(2)
    x = rng.normal(3.0, 2.0, (400, 3))
    y = x @ np.array([0.5, -1.0, 0.0]) + 0.2 + rng.normal(0.0, 0.01, 400)
    np.testing.assert_allclose(_ridge(x, y, ridge=1e-6), [0.5, -1.0, 0.0, 0.2], atol=0.01)


def test_a_tour_of_the_valid_nodes_starts_at_the_given_one():
    rng = np.random.default_rng(3)
    x = rng.permutation(np.r_[0.0, 1.0, 2.5, 4.0, 7.0, 9.0])  # Nodes on a line, metres.
    costs = np.abs(x[:, None] - x[None, :])
    nodes = np.arange(len(x))
    assert _tour(int(np.argmin(x)), costs, nodes) == pytest.approx(9.0)  # From an end.
    # From 4 m the shortest goes down to 0 m and back up to 9 m: 4 + 9.
    assert _tour(int(np.flatnonzero(x == 4.0)[0]), costs, nodes) == pytest.approx(13.0)
    # Only the nodes given count: without those at 0 and 1 m, from 4 m it is 1.5 + 6.5.
    assert _tour(int(np.flatnonzero(x == 4.0)[0]), costs,
                 np.flatnonzero(x >= 2.5)) == pytest.approx(8.0)


@pytest.mark.slow
def test_forked_departures_are_measured_and_fitted(tmp_path):
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(RECIPE)
    out = tmp_path / "rollouts"
    tool = [sys.executable, "-m", "tools.research.rollout_advantage", "--config",
            str(recipe), "--out", str(out)]
    # Two in five of the decisions forked: 7 and 9 departures on these two layouts.
    subprocess.run(tool + ["--layouts", "2", "--share", "0.4", "--alternatives", "1",
                           "--nudge", "0.001", "--workers", "1"], cwd=REPO,
                   capture_output=True, text=True, check=True)
    rows = [json.loads(line) for line in (out / "rows.jsonl").read_text().splitlines()]
    nudged = [r for r in rows if r["rank"] == -1]  # The prior's node, the robot 1 mm away.
    assert nudged and all(abs(np.hypot(*r["nudge"]) - 0.001) < 1e-9 for r in nudged)
    rows = [r for r in rows if r["rank"] >= 0]
    for scene in {r["scene"] for r in rows}:
        mine = [r for r in rows if r["scene"] == scene]
        # The prior's own node in a fork runs the prior's episode (the tool's own check).
        assert mine[0]["rank"] == 0 and mine[0]["t"] == mine[0]["t_prior"]
        assert all(r["rank"] == 1 and r["logit_gap"] >= 0 for r in mine[1:])
        assert len(mine) > 2
    assert any(r["d"] != 0 for r in rows)
    session, = [json.loads(line) for line in (out / "sessions.jsonl").read_text().splitlines()]
    assert session["revision"] and session["args"]["share"] == "0.4"
    fit = subprocess.run(tool + ["--fit", "--folds", "2"], cwd=REPO, capture_output=True,
                         text=True, check=True)
    result = json.loads(fit.stdout.strip().splitlines()[-1])
    assert result["layouts"] == 2 and result["departures"] == len(rows) - 2
    assert len(result["weights"]) == 12
    # Each departure's map context, measured in the collection, is measured again by
    # replaying the prior's episode (--observe, for rows collected without it): the same.
    width = len(CONTEXT) + len(PAIRWISE)
    assert all(len(r["context"]) == width and len(r["privileged"]) == len(PRIVILEGED)
               for r in rows if r["rank"])
    assert any(r["privileged"][-1] > 0 for r in rows if r["rank"])  # Unseen area is left.
    (out / "rows.jsonl").write_text("".join(json.dumps(
        {k: v for k, v in r.items() if k not in ("context", "privileged")}) + "\n"
        for r in rows))
    subprocess.run(tool + ["--observe", "--workers", "1"], cwd=REPO, capture_output=True,
                   text=True, check=True)
    replayed = {(c["scene"], c["decision"], c["rank"]): (c["context"], c["privileged"])
                for c in map(json.loads, (out / "context.jsonl").read_text().splitlines())}
    assert replayed == {(r["scene"], r["decision"], r["rank"]): (r["context"], r["privileged"])
                        for r in rows if r["rank"]}
    fit = subprocess.run(tool + ["--fit", "--context", "--privileged", "--folds", "2"],
                         cwd=REPO, capture_output=True, text=True, check=True)
    assert len(json.loads(fit.stdout)["weights"]) == 12 + width + len(PRIVILEGED)
    fit = subprocess.run(tool + ["--fit", "--context", "--folds", "2", "--validate",
                                 "--workers", "1"], cwd=REPO, capture_output=True, text=True,
                         check=True)
    result, validation = map(json.loads, fit.stdout.strip().splitlines()[-2:])
    assert len(result["weights"]) == 12 + width
    # The fitted rule, its context measured at each decision, and the prior on the layout.
    assert validation["validate"] == 1 and np.isfinite(validation["times"]).all()


@pytest.mark.parametrize("tool", ["rollout_advantage", "es_residual"])
def test_a_recipe_without_the_v3_prior_is_refused(tool, tmp_path):
    result = subprocess.run([sys.executable, "-m", f"tools.research.{tool}", "--config",
                             str(REPO / "training" / "gvn.yaml"), "--out", str(tmp_path / "o")],
                            cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 2
    assert "needs generated training layouts" in result.stderr
    assert not (tmp_path / "o").exists()
