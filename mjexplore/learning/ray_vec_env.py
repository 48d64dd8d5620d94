"""Training envs as Ray actors: SB3's ``VecEnv`` over one machine or a Ray cluster.

Each env lives in its own Ray actor (one CPU each, spread over the cluster's machines) and
steps as a ``SubprocVecEnv`` worker does: an episode that ends stores its last observation
in ``info["terminal_observation"]`` and resets at once. MaskablePPO is unchanged; its masks
come through ``env_method("action_masks")``. With the same seeds and actions the envs give
exactly what ``SubprocVecEnv`` and ``DummyVecEnv`` give.

Every machine of a cluster runs the env code of its own mjexplore checkout, so every one
needs the same revision installed; :class:`RayVecEnv` refuses to start otherwise.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import ray
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnv,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)
from stable_baselines3.common.vec_env.subproc_vec_env import _stack_obs

from mjexplore.errors import UserInputError
from mjexplore.io.provenance import git_revision
from mjexplore.io.ray_cluster import ray_cause

log = logging.getLogger(__name__)

@ray.remote(num_cpus=1)
class _EnvActor:
    """One env; its methods are the commands of SB3's ``SubprocVecEnv`` worker."""

    def __init__(self, env_fn: Callable[[], gym.Env]) -> None:
        self.env = env_fn()
        self.reset_info: dict[str, Any] = {}

    def describe(self) -> tuple[str, str]:
        """(this machine's IP address, the git revision of its mjexplore checkout)."""
        return ray.util.get_node_ip_address(), git_revision()

    def spaces(self) -> tuple[gym.Space, gym.Space]:
        return self.env.observation_space, self.env.action_space

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, dict, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        done = terminated or truncated
        info["TimeLimit.truncated"] = truncated and not terminated
        if done:
            info["terminal_observation"] = obs
            obs, self.reset_info = self.env.reset()
        return obs, reward, done, info, self.reset_info

    def reset(self, seed: int | None, options: dict) -> tuple[Any, dict]:
        obs, self.reset_info = self.env.reset(seed=seed, **({"options": options} if options
                                                            else {}))
        return obs, self.reset_info

    def get_attr(self, name: str) -> Any:
        return self.env.get_wrapper_attr(name)

    def set_attr(self, name: str, value: Any) -> None:
        setattr(self.env, name, value)

    def call(self, name: str, args: tuple, kwargs: dict) -> Any:
        return self.env.get_wrapper_attr(name)(*args, **kwargs)

    def is_wrapped(self, wrapper_class: type[gym.Wrapper]) -> bool:
        return is_wrapped(self.env, wrapper_class)

    def close(self) -> None:
        self.env.close()


class RayVecEnv(VecEnv):
    """SB3 ``VecEnv`` whose envs are Ray actors (see the module docstring).

    Args:
        env_fns: Picklable functions that build one env each (cloudpickle: closures too).
        shutdown_ray: Call ``ray.shutdown()`` on :meth:`close` (when the caller joined Ray
            for these envs alone).

    Raises:
        UserInputError: An actor cannot build its env, or a machine's mjexplore checkout
            is at another revision than this one's.
    """

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]],
                 shutdown_ray: bool = False) -> None:
        self._shutdown_ray = shutdown_ray
        self.closed = False
        self._pending: list[ray.ObjectRef] = []
        # mypy does not apply class decorators: @ray.remote made _EnvActor an ActorClass.
        self.actors = [_EnvActor.options(  # type: ignore[attr-defined]
            scheduling_strategy="SPREAD").remote(fn) for fn in env_fns]
        try:
            placed = ray.get([actor.describe.remote() for actor in self.actors])
        except ray.exceptions.RayActorError as exc:
            self.close()
            raise UserInputError(f"a Ray worker could not build its env ({ray_cause(exc)}): "
                                 "every machine needs the same mjexplore checkout installed "
                                 "(`make demo`).") from None
        mine = git_revision()
        others = {ip: rev for ip, rev in placed if rev != mine}
        if others:
            self.close()
            raise UserInputError("the mjexplore checkouts differ: "
                                 + ", ".join(f"{ip} has {rev}" for ip, rev in others.items())
                                 + f", this machine {mine}: check out and install the same "
                                 "revision on every machine.")
        log.info("env actors per machine: %s",
                 ", ".join(f"{ip}: {n}" for ip, n in Counter(ip for ip, _ in placed).items()))
        observation_space, action_space = ray.get(self.actors[0].spaces.remote())
        super().__init__(len(self.actors), observation_space, action_space)

    def step_async(self, actions: np.ndarray) -> None:
        self._pending = [actor.step.remote(action)
                         for actor, action in zip(self.actors, actions, strict=True)]

    def step_wait(self) -> VecEnvStepReturn:
        results, self._pending = ray.get(self._pending), []
        # Tuples, as SB3's SubprocVecEnv gives them (VecEnv's annotations say lists).
        obs, rews, dones, infos, self.reset_infos = zip(  # type: ignore[assignment]
            *results, strict=True)
        stacked = _stack_obs(obs, self.observation_space)
        return stacked, np.stack(rews), np.stack(dones), infos  # type: ignore[return-value]

    def reset(self) -> VecEnvObs:
        results = ray.get([actor.reset.remote(self._seeds[i], self._options[i])
                           for i, actor in enumerate(self.actors)])
        obs, self.reset_infos = zip(*results, strict=True)  # type: ignore[assignment]
        self._reset_seeds()  # Seeds and options are used once, as in SB3's VecEnvs.
        self._reset_options()
        return _stack_obs(obs, self.observation_space)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            ray.get(self._pending + [actor.close.remote() for actor in self.actors])
        except ray.exceptions.RayError as exc:
            log.warning("closing the env actors: %s", ray_cause(exc))
        for actor in self.actors:
            ray.kill(actor)
        if self._shutdown_ray:
            ray.shutdown()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return ray.get([self.actors[i].get_attr.remote(attr_name)
                        for i in self._get_indices(indices)])

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        ray.get([self.actors[i].set_attr.remote(attr_name, value)
                 for i in self._get_indices(indices)])

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None,
                   **method_kwargs) -> list[Any]:
        return ray.get([self.actors[i].call.remote(method_name, method_args, method_kwargs)
                        for i in self._get_indices(indices)])

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper],
                       indices: VecEnvIndices = None) -> list[bool]:
        return ray.get([self.actors[i].is_wrapped.remote(wrapper_class)
                        for i in self._get_indices(indices)])
