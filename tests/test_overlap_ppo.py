"""MaskablePPO with each update overlapped with the next rollout (``ppo.overlap``): the same
update as MaskablePPO's, rollouts collected by the weights before the update in flight,
checkpoints between updates, resume."""

from __future__ import annotations

import copy
import json
import threading

import pytest
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from test_learning import TINY

from mjexplore.learning import overlap_ppo
from mjexplore.learning.checkpoints import load_checkpoint
from mjexplore.learning.overlap_ppo import OverlapMaskablePPO
from mjexplore.learning.train_config import load_train_config
from mjexplore.learning.training import make_model, train
from mjexplore.learning.vec_envs import make_vec_env

# Three rollouts of 8 decisions of one env (in this process); a learning rate that moves
# the policy visibly in one update; minibatches of runs of 4 decisions.
ROLLOUTS = 3


class Recorder(BaseCallback):
    """Copies what a test compares: the weights at the start and at each rollout's start,
    and each collected rollout."""

    def _on_training_start(self) -> None:
        self.start = (copy.deepcopy(self.model.policy.state_dict()),
                      copy.deepcopy(self.model.policy.optimizer.state_dict()))
        self.starts, self.rollouts = [], []

    def _on_rollout_start(self) -> None:
        self.starts.append({"n_updates": self.model._n_updates,
                            "num_timesteps": self.model.num_timesteps,
                            "callback_timesteps": self.num_timesteps,
                            "weights": copy.deepcopy(self.model.policy.state_dict())})

    def _on_rollout_end(self) -> None:
        self.rollouts.append(copy.deepcopy(self.locals["rollout_buffer"]))

    def _on_step(self) -> bool:
        return True


@pytest.fixture(scope="module")
def overlapped(tmp_path_factory):
    cfg = tmp_path_factory.mktemp("overlap") / "tiny.yaml"
    cfg.write_text(TINY.format(total=8 * ROLLOUTS, n_envs=1).replace(
        "n_epochs: 1}", "n_epochs: 2, learning_rate: 0.01, minibatch_block: 4, "
        "overlap: true}"))
    config = load_train_config(cfg)
    torch.manual_seed(0)
    venv = make_vec_env(config, seed=0)
    try:
        model = make_model(config, venv, seed=0)
        assert isinstance(model, OverlapMaskablePPO)
        recorder = Recorder()
        model.learn(config.total_steps, callback=recorder)
        yield config, venv, model, recorder
    finally:
        venv.close()


def _log_probs(policy, state, buffer) -> tuple[torch.Tensor, torch.Tensor]:
    """The log-probabilities ``policy`` with weights ``state`` gives the actions of the
    rollout ``buffer``, and those stored there."""
    policy.load_state_dict(state)
    policy.set_training_mode(False)
    sample = next(copy.deepcopy(buffer).get())
    with torch.no_grad():
        _, log_prob, _ = policy.evaluate_actions(sample.observations,
                                                 sample.actions.long().flatten(),
                                                 action_masks=sample.action_masks)
    return log_prob, sample.old_log_prob


def _baseline(config, venv):
    """MaskablePPO of the same config, with a logger of its own."""
    import dataclasses

    plain = make_model(dataclasses.replace(config, ppo=dataclasses.replace(
        config.ppo, overlap=False)), venv, seed=0)
    assert not isinstance(plain, OverlapMaskablePPO)
    plain.set_logger(configure(None, []))
    return plain


def test_the_overlapped_update_is_maskableppos_own(overlapped):
    config, venv, model, recorder = overlapped
    plain = _baseline(config, venv)
    weights, optimizer = recorder.start
    plain.policy.load_state_dict(weights)
    plain.policy.optimizer.load_state_dict(optimizer)
    plain.rollout_buffer = copy.deepcopy(recorder.rollouts[0])  # Its run order included.
    plain._update_current_progress_remaining(8, config.total_steps)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.torch_threads)  # As many as the update thread ran.
    try:
        plain.train()
    finally:
        torch.set_num_threads(threads)
    # The update of rollout 0 ran in the update thread while rollout 1 was collected.
    after_first = next(s for s in recorder.starts if s["n_updates"] == config.ppo.n_epochs)
    for name, tensor in plain.policy.state_dict().items():
        assert torch.equal(tensor, after_first["weights"][name]), name
    assert model._n_updates == ROLLOUTS * config.ppo.n_epochs
    assert model.num_timesteps == config.total_steps


def test_each_rollout_is_collected_by_the_weights_before_the_update_in_flight(overlapped):
    config, venv, model, recorder = overlapped
    policy = _baseline(config, venv).policy
    initial = recorder.start[0]
    after_first = next(s["weights"] for s in recorder.starts if s["n_updates"])
    assert len(recorder.rollouts) == ROLLOUTS
    # Rollout 0 by the initial weights; rollout k + 1 by the weights before update k (those
    # after update k - 1).
    for rollout, behaviour in zip(recorder.rollouts, (initial, initial, after_first),
                                  strict=True):
        log_prob, stored = _log_probs(policy, behaviour, rollout)
        torch.testing.assert_close(log_prob, stored, rtol=0, atol=1e-5)
    # Rollout 1 was collected while update 0 ran: not by the weights after it.
    log_prob, stored = _log_probs(policy, after_first, recorder.rollouts[1])
    assert (log_prob - stored).abs().max() > 1e-3


def test_rollouts_start_between_updates_with_every_counted_decision_trained(overlapped):
    config, _, _, recorder = overlapped
    epochs = config.ppo.n_epochs
    # A start before each rollout; the first two before any update (the second while
    # rollout 0 waits for its update), then one after each update.
    assert [(s["n_updates"], s["num_timesteps"], s["callback_timesteps"])
            for s in recorder.starts] == [(0, 0, 0), (0, 0, 0), (epochs, 8, 8)]


def test_training_with_overlap_checkpoints_resumes_and_sets_threads(tmp_path, monkeypatch):
    threads = []
    update, collect = OverlapMaskablePPO.train, OverlapMaskablePPO._collect

    def counted_update(self):
        threads.append(("update", threading.current_thread().name, torch.get_num_threads()))
        return update(self)

    def counted_collect(self, *args):
        threads.append(("collect", threading.current_thread().name, torch.get_num_threads()))
        return collect(self, *args)

    monkeypatch.setattr(overlap_ppo.OverlapMaskablePPO, "train", counted_update)
    monkeypatch.setattr(overlap_ppo.OverlapMaskablePPO, "_collect", counted_collect)
    cfg = tmp_path / "tiny.yaml"
    tiny = TINY.replace("n_epochs: 1}", "n_epochs: 1, overlap: true}") + "update_threads: 2\n"
    cfg.write_text(tiny.format(total=48, n_envs=2))
    out = tmp_path / "run"
    result = train(load_train_config(cfg), out, progress=False)
    assert result["num_timesteps"] == 48
    # Rollouts of 16: a checkpoint after the first update (16 decisions trained on), then
    # the final one after the last update.
    assert result["checkpoints"] == ["step_000000016.pt", "step_000000048.pt"]
    state = load_checkpoint(out / "checkpoints" / "step_000000016.pt")
    assert (state["num_timesteps"], state["n_updates"]) == (16, 1)
    main = threading.main_thread().name
    # Three rollouts, two updates in the update thread beside the collection, the last one
    # alone on the main thread.
    assert sorted(threads) == sorted([("collect", main, 1)] * 3 + [
        ("update", "ppo-update_0", 2)] * 2 + [("update", main, 2)])
    assert torch.get_num_threads() == 1
    cfg.write_text(tiny.format(total=64, n_envs=2))
    again = train(load_train_config(cfg), out, resume=True, progress=False)
    assert (again["resumed_from"], again["num_timesteps"]) == (48, 64)
    sessions = json.loads((out / "sessions.json").read_text())["sessions"]
    assert [(s["steps_from"], s["steps_to"]) for s in sessions] == [(0, 48), (48, 64)]
