"""pocket_nearest: gvn_v3's hand-set prior without its network.

At every decision of a real episode (the small canonical loop, driven by pocket_nearest),
pocket_nearest must pick the goal that the shipped gvn_v3 picks once its actor's logit layer
is zeroed (its logits are then the prior's alone), on the same state; and it must part from
nearest-frontier somewhere, passing over a frontier whose pocket is likely small.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.explorers import make_explorer
from mjexplore.explorers.pocket_nearest import (
    GVN_V3_MAX_NEIGHBOURS,
    GVN_V3_MAX_NODES,
    GVN_V3_PATH_RADIUS,
    GVN_V3_POCKET_M,
    GVN_V3_POCKETS,
    GVN_V3_POCKETS_SHA256,
    GVN_V3_TOPOLOGY,
    PocketNearest,
)
from mjexplore.policies.gvn_explorer import GvnExplorer
from mjexplore.policies.models import resolve_policy, trained_masking
from mjexplore.policies.weights import load_policy
from mjexplore.scenes.canonical import resolve_scene

SCENE = "train_loop"


def _same(a: np.ndarray | None, b: np.ndarray | None, tolerance: float = 0.0) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.all(np.abs(np.asarray(a) - np.asarray(b)) <= tolerance))


class _Compare:
    """Drives with pocket_nearest and asks, at each decision and on the same state, gvn_v3
    with its network zeroed and nearest-frontier what they would choose."""

    name = "compare"

    def __init__(self) -> None:
        self.pocket = PocketNearest()
        self.prior = GvnExplorer("gvn_v3")
        logit_layer = self.prior.policy.mlp_extractor.actor[-1]
        with torch.no_grad():
            logit_layer.weight.zero_()
            logit_layer.bias.zero_()
        self.nearest = NearestFrontier()
        self.rows: list[dict] = []

    def reset(self, rng: np.random.Generator) -> None:
        for explorer in (self.pocket, self.prior, self.nearest):
            explorer.reset(rng)

    def select_goal(self, state):
        nearest = self.nearest.select_goal(state)
        prior = self.prior.select_goal(state)
        goal = self.pocket.select_goal(state)
        row = {"pocket": goal, "prior": prior, "nearest": nearest, "passed_over": None}
        p = self.pocket
        if goal is not None and nearest is not None:
            frontiers = state.extras["tracker"].frontiers(state.grid)
            probability = p.pockets.node_probability(p.padded, state.grid, frontiers)
            at = np.flatnonzero(p.mask & np.all(np.abs(p.padded.node_positions - nearest)
                                                <= 1e-3, axis=1))
            if len(at):
                row["passed_over"] = float(probability[at[0]])
        self.rows.append(row)
        return goal


@pytest.fixture(scope="module")
def decisions() -> list[dict]:
    explorer = _Compare()
    result = Episode(resolve_scene(SCENE), explorer, 0, EpisodeConfig()).run()
    assert result.metrics["end_reason"] == "explored"
    assert len(explorer.rows) >= 5
    return explorer.rows


def test_defaults_are_gvn_v3s_stored_settings():
    _, path = resolve_policy("gvn_v3", "gvn")
    policy, meta = load_policy(path, expected_kind="gvn")
    observation, topology = meta["decisions"].config, meta["decisions"].topology
    extractor = policy.features_extractor
    assert extractor.prior_pocket_m == GVN_V3_POCKET_M
    assert extractor.prior_temperature == 1.0  # The argmax is the least cost's, no rounding.
    assert observation.features == "v3"
    assert trained_masking(meta["provenance"]) == "iam"  # Runs masked: frontier nodes only.
    assert (observation.pockets, observation.pockets_sha256) == (GVN_V3_POCKETS,
                                                                 GVN_V3_POCKETS_SHA256)
    assert observation.path_radius == GVN_V3_PATH_RADIUS
    assert (observation.max_nodes, observation.max_neighbours) == (GVN_V3_MAX_NODES,
                                                                   GVN_V3_MAX_NEIGHBOURS)
    assert topology == GVN_V3_TOPOLOGY
    explorer = make_explorer("pocket_nearest")
    assert isinstance(explorer, PocketNearest) and explorer.name == "pocket_nearest"
    assert explorer.ter_config == meta["decisions"].ter_config


def test_picks_what_gvn_v3_with_its_network_zeroed_picks(decisions):
    assert any(row["pocket"] is not None for row in decisions)
    for i, row in enumerate(decisions):
        assert _same(row["pocket"], row["prior"]), (i, row)


def test_passes_over_a_likely_small_pocket_that_nearest_takes(decisions):
    differ = [row for row in decisions
              if not _same(row["pocket"], row["nearest"], 1e-3)]
    assert differ, "pocket_nearest chose as nearest-frontier at every decision"
    assert any(row["passed_over"] is not None and row["passed_over"] > 0.5
               for row in differ), differ


def test_explore_cli_runs_pocket_nearest(tmp_path):
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "mjexplore.cli", "explore", "--scene", SCENE,
                           "--explorer", "pocket_nearest", "--max-time", "60", "--no-mcap",
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (out / "metrics.json").exists()
