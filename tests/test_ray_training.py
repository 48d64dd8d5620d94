"""Training envs as Ray actors: the same steps as SubprocVecEnv, training and resume."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import ray
import yaml
from stable_baselines3.common.vec_env import SubprocVecEnv
from test_learning import TINY

from mjexplore.config import from_dict
from mjexplore.envs import EnvConfig
from mjexplore.errors import UserInputError
from mjexplore.io.ray_cluster import connect
from mjexplore.learning.checkpoints import load_checkpoint
from mjexplore.learning.train_config import load_train_config
from mjexplore.learning.training import train
from mjexplore.learning.vec_envs import env_maker

# Episodes of 3 decisions: 5 steps cross an episode end and the automatic reset.
ENV = from_dict(EnvConfig, yaml.safe_load(TINY.format(total=8, n_envs=2))["env"]
                | {"max_decisions": 3})


@pytest.fixture
def local_ray():
    ray.init(address="local", num_cpus=2, include_dashboard=False)
    try:
        yield
    finally:
        ray.shutdown()


def _rollout(venv, steps: int) -> list:
    """The first observation, then each step's results and reset infos, acting on the
    first valid action."""
    venv.seed(7)
    out = [venv.reset(), venv.reset_infos]
    for _ in range(steps):
        action = np.stack(venv.env_method("action_masks")).argmax(axis=1)
        out += [venv.step(action), venv.reset_infos]
    return out


def test_ray_envs_step_exactly_as_subprocess_envs(local_ray, monkeypatch):
    import mjexplore.learning.ray_vec_env as ray_vec_env

    makers = [env_maker(ENV, own_process=True) for _ in range(2)]
    reference = SubprocVecEnv(makers, start_method="forkserver")
    try:
        expected = _rollout(reference, 5)
    finally:
        reference.close()
    venv = ray_vec_env.RayVecEnv(makers)
    try:
        got = _rollout(venv, 5)
        assert venv.get_attr("config") == [ENV, ENV]
        assert venv.env_is_wrapped(gym.wrappers.TimeLimit) == [False, False]
    finally:
        venv.close()
    assert ray.is_initialized()  # Not its Ray to shut down.
    dones = np.stack([step[2] for step in expected[2::2]])
    assert dones.any(), "no episode ended: the automatic reset went untested"
    for step in expected[2::2]:
        for done, info in zip(step[2], step[3]):
            assert ("terminal_observation" in info) == done
    np.testing.assert_equal(got, expected)

    with pytest.raises(UserInputError, match="has 2 CPUs and 3 envs"):
        connect("local", 3, what="envs", fewer="--n-envs")
    monkeypatch.setattr(ray_vec_env, "git_revision", lambda: "another-revision")
    with pytest.raises(UserInputError, match="checkouts differ"):
        ray_vec_env.RayVecEnv(makers[:1])


@pytest.mark.parametrize("address, message", [("127.0.0.1:1", "no Ray cluster answers"),
                                              ("head-without-port", "not a Ray address")])
def test_train_refuses_a_ray_address_without_a_cluster(tmp_path, capsys, address, message):
    from mjexplore.cli import main

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=8, n_envs=2))
    out = tmp_path / "run"
    assert main(["train", "--config", str(cfg), "--out", str(out), "--ray", address]) == 2
    err = capsys.readouterr().err
    assert message in err and "ray start --head" in err
    assert not out.exists() and not ray.is_initialized()


@pytest.mark.slow
def test_training_on_ray_actors_checkpoints_and_resumes(tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=16, n_envs=2))
    out = tmp_path / "run"
    summary = train(load_train_config(cfg), out, progress=False, ray_address="local")
    assert summary["num_timesteps"] == 16 and summary["resumed_from"] == 0
    assert not ray.is_initialized()  # The Ray instance it started is shut down.
    assert json.loads((out / "checkpoints" / "latest.json").read_text())["num_timesteps"] == 16
    first = load_checkpoint(out / "checkpoints" / "step_000000016.pt")

    summary = train(load_train_config(cfg, total_steps=32), out, resume=True, progress=False,
                    ray_address="local")
    assert summary["resumed_from"] == 16 and summary["num_timesteps"] == 32
    last = load_checkpoint(out / "checkpoints" / "step_000000032.pt")
    assert last["n_updates"] > first["n_updates"]
    assert (out / "policy.safetensors").is_file() and not ray.is_initialized()
