"""DAgger that spans sessions (``mjexplore imitate``): rounds on disk, resumed as if never
stopped."""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mjexplore.errors import UserInputError
from mjexplore.learning.dagger_run import imitate, read_round
from mjexplore.learning.imitation import warm_start
from mjexplore.learning.policy_network import fresh_policy
from mjexplore.learning.train_config import load_train_config
from mjexplore.learning.training import seed_everything
from mjexplore.policies.weights import read_policy_weights

RECIPE = """
kind: gvn
seed: 3
env:
  scenes: [train_loop]
  max_decisions: 5
  observation: {max_nodes: 64, max_neighbours: 4, memory_length: 3, features: v2}
  episode:
    sim: {dynamics: grid}
policy: {hidden: 16}
eval: {every: 0}
imitation: {episodes: 1, epochs: 2, batch_size: 8, seed: 11, dagger_iterations: 2}
"""


@pytest.fixture
def recipe(tmp_path):
    path = tmp_path / "dagger.yaml"
    path.write_text(RECIPE)
    return path


def _rounds(config, n):
    return dataclasses.replace(config, imitation=dataclasses.replace(
        config.imitation, dagger_iterations=n - 1))


def _distance(a, b) -> float:
    """Euclidean distance between two sets of weights (b's names)."""
    return float(sum(((a[k].double() - b[k].double()) ** 2).sum() for k in b)) ** 0.5


def test_a_resumed_run_ends_as_the_run_that_never_stopped(recipe, tmp_path):
    config = load_train_config(recipe)
    whole = imitate(config, tmp_path / "whole")
    assert [r["iteration"] for r in whole["rounds"]] == [0, 1, 2]
    # Stopped after round 0, then resumed twice (rounds may grow on --resume).
    imitate(_rounds(config, 1), tmp_path / "parts")
    imitate(_rounds(config, 2), tmp_path / "parts", resume=True)
    parts = imitate(config, tmp_path / "parts", resume=True)
    assert [r["iteration"] for r in parts["rounds"]] == [0, 1, 2]
    assert parts["decisions"] == whole["decisions"] == sum(r["decisions"] for r in
                                                           whole["rounds"])
    mine, _ = read_policy_weights(tmp_path / "parts" / "policy.safetensors")
    theirs, meta = read_policy_weights(tmp_path / "whole" / "policy.safetensors")
    untrained, _ = read_policy_weights(tmp_path / "whole" / "policy_untrained.safetensors")
    # The refits agree to rounding (the refit is not bit-reproducible: Adam turns
    # rounding-sized gradients into whole steps): far nearer each other than to the start.
    assert _distance(mine, theirs) < 0.1 * _distance(theirs, untrained)
    assert meta["provenance"]["imitation"] == {"rounds": 3, "decisions": whole["decisions"]}
    for i in range(3):
        a = read_round(tmp_path / "parts" / "rounds" / f"round_{i:03d}.npz")
        b = read_round(tmp_path / "whole" / "rounds" / f"round_{i:03d}.npz")
        assert all(np.array_equal(x, y) for x, y in zip(a[1:], b[1:], strict=True))
        assert a[0].keys() == b[0].keys() and all(np.array_equal(a[0][k], b[0][k])
                                                  for k in a[0])
    # ...and as the warm start in memory does, which training runs before PPO.
    seed_everything(config.seed)
    policy = fresh_policy(config)
    report = warm_start(policy, config.env, config.imitation, config.seed)
    assert report["decisions"] == whole["decisions"]
    assert _distance(policy.state_dict(), theirs) < 0.1 * _distance(theirs, untrained)
    assert sorted(p.name for p in (tmp_path / "parts" / "weights").iterdir()) == [
        f"round_{i:03d}.safetensors" for i in range(3)]
    obs, masks, labels, taken = read_round(tmp_path / "whole" / "rounds" / "round_001.npz")
    assert len(labels) == len(taken) == len(masks) == whole["rounds"][1]["decisions"]
    assert masks[np.arange(len(labels)), labels].all() and obs["node_features"].dtype == \
        np.float32


def test_a_run_refuses_what_it_cannot_do(recipe, tmp_path):
    config = _rounds(load_train_config(recipe), 1)
    with pytest.raises(UserInputError, match="nothing to resume"):
        imitate(config, tmp_path / "run", resume=True)
    imitate(config, tmp_path / "run")
    with pytest.raises(UserInputError, match="--resume"):
        imitate(config, tmp_path / "run")
    other = dataclasses.replace(config, imitation=dataclasses.replace(config.imitation,
                                                                      keep_prior_m=0.0,
                                                                      epochs=3))
    with pytest.raises(UserInputError, match="recipe differs"):
        imitate(other, tmp_path / "run", resume=True)
    with pytest.raises(UserInputError, match="imitation episodes"):
        imitate(dataclasses.replace(config, imitation=dataclasses.replace(
            config.imitation, episodes=0, dagger_iterations=0)), tmp_path / "none")
    (tmp_path / "run" / "rounds" / "round_000.npz").write_bytes(b"not a round")
    with pytest.raises(UserInputError, match="cannot read the DAgger round"):
        imitate(_rounds(config, 2), tmp_path / "run", resume=True)


def test_the_cli_imitates_and_says_where_the_weights_are(recipe, tmp_path):
    out = tmp_path / "cli"
    cmd = [sys.executable, "-m", "mjexplore.cli", "imitate", "--config", str(recipe),
           "--out", str(out), "--rounds", "1"]
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["rounds"] == 1 and summary["decisions"] > 0
    assert (out / "policy.safetensors").is_file() and (out / "config.yaml").is_file()
    again = subprocess.run(cmd, capture_output=True, text=True)
    assert again.returncode == 2 and "--resume" in again.stderr


def test_dagger_fit_holds_out_whole_episodes_and_reports_departures(recipe, tmp_path):
    config = _rounds(load_train_config(recipe), 1)
    config = dataclasses.replace(config, imitation=dataclasses.replace(config.imitation,
                                                                       episodes=2))
    record = imitate(config, tmp_path / "run")
    done = subprocess.run([sys.executable, "-m", "tools.research.dagger_fit",
                           str(tmp_path / "run"), "--holdout", "0.5", "--epochs", "1"],
                          cwd=Path(__file__).resolve().parents[1], capture_output=True,
                          text=True, check=True)
    report = json.loads(done.stdout)
    assert report["episodes"] == 2 and report["held_out_episodes"] == 1
    sizes = [report["fitted"][s]["decisions"] for s in ("fitted", "held_out")]
    assert sum(sizes) == record["decisions"] and min(sizes) > 0
    assert report["fit"]["epochs"] == 1 and report["fit"]["loss"] == config.imitation.loss
    # The untrained network is near uniform here (no prior): no departures to count, and
    # its agreement is a share.
    assert 0.0 <= report["untrained"]["held_out"]["agreement"] <= 1.0


def test_episodes_start_where_the_memory_is_empty():
    from tools.research.dagger_fit import episode_ids

    mask = np.array([[0, 0], [0, 1], [1, 1], [0, 0], [0, 1], [0, 0]], np.float32)
    assert episode_ids(mask).tolist() == [0, 0, 0, 1, 1, 2]


def test_the_linear_models_terms_measure_each_node_against_the_cheapest_valid_one():
    import torch

    from mjexplore.envs.observation import PATH, POCKET
    from mjexplore.policies.gvn import path_prior
    from tools.research.v3_prior import node_terms

    features = np.zeros((1, 4, 10), np.float32)
    features[0, :, PATH] = [3.0, 8.0, 20.0, 1.0]
    features[0, :, POCKET] = [0.0, 0.0, 0.0, 0.5]
    valid = np.array([[True, True, True, False]])  # The nearest node is not valid.
    terms, prior = node_terms(features, valid)
    torch.testing.assert_close(prior, path_prior(torch.as_tensor(features), 1.0, 50.0))
    beyond = terms[0, :3, 5] * 10  # Metres beyond the cheapest valid node (3 m away).
    torch.testing.assert_close(beyond, torch.tensor([0.0, 5.0, 17.0]))
    assert terms[0, :3, 7].tolist() == [1.0, 0.0, 0.0] and terms[0, :3, 8].tolist() == [1.0,
                                                                                    1.0, 0.0]
