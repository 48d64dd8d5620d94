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
import os
import socket
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

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

log = logging.getLogger(__name__)

LOCAL = "local"  # A fresh Ray instance on this machine.
AUTO = "auto"  # The cluster this machine belongs to (the last `ray start` here).
HOW_TO_START = ("start one with `ray start --head --port=6379` on the head machine and "
                "`ray start --address=HEAD_IP:6379` on each other machine, then train on the "
                "head with --ray auto (see the README, 'Training on more than one machine')")
TOKEN_HELP = ("if the head uses token authentication (`ray start --head` says so), export "
              "RAY_AUTH_MODE=token and RAY_AUTH_TOKEN=<what `ray get-auth-token` prints on the "
              "head> here")
CONNECT_TIMEOUT_S = 5.0  # Ray itself retries an unreachable address for minutes.


def connect(address: str, n_envs: int) -> bool:
    """Joins the Ray cluster at ``address`` or starts a local instance, for ``n_envs`` actors.

    Args:
        address: 'local' (a fresh instance on this machine, with at least ``n_envs`` CPUs
            so that every env gets a worker, as ``SubprocVecEnv`` does), 'auto' (the cluster
            this machine joined with ``ray start``) or a head's 'HOST:PORT'.
        n_envs: Env actors to place (one CPU each).

    Returns:
        Whether this call initialised Ray (its caller then calls ``ray.shutdown()``); False
        when this process had already joined a Ray instance, which is then used as it is.

    Raises:
        UserInputError: No cluster at ``address``, or too few CPUs in it.
    """
    if ray.is_initialized():
        log.info("using the Ray instance this process already joined")
        joined = False
    elif address == LOCAL:
        cpus = os.cpu_count() or 1
        if n_envs > cpus:
            log.warning("%d envs on %d CPUs: the envs share the cores", n_envs, cpus)
        ray.init(address=LOCAL, num_cpus=max(cpus, n_envs), include_dashboard=False)
        joined = True
    else:
        if address != AUTO:
            _check_reachable(address)
        try:
            ray.init(address=address)
        except (ConnectionError, ValueError, ray.exceptions.AuthenticationError) as exc:
            raise UserInputError(f"--ray {address}: Ray could not join a cluster there "
                                 f"({_cause(exc)}); {TOKEN_HELP}; without a cluster, "
                                 f"{HOW_TO_START}.") from None
        joined = True
    resources = ray.cluster_resources()
    nodes = [n for n in ray.nodes() if n["Alive"]]
    cpus = resources.get("CPU", 0.0)
    log.info("Ray: %d node(s) (%s), %g CPUs, %.1f GiB memory", len(nodes),
             ", ".join(n["NodeManagerAddress"] for n in nodes), cpus,
             resources.get("memory", 0.0) / 2**30)
    if cpus < n_envs:
        if joined:
            ray.shutdown()
        raise UserInputError(f"the Ray cluster has {cpus:g} CPUs and {n_envs} envs need one "
                             "each: lower --n-envs, or add machines with `ray start "
                             "--address=HEAD_IP:6379` on each.")
    return joined


def _check_reachable(address: str) -> None:
    """Raises UserInputError unless something listens at ``address`` ('HOST:PORT')."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise UserInputError(f"--ray {address!r} is not a Ray address: give the head's "
                             "HOST:PORT (e.g. 10.0.0.1:6379), auto, or nothing for a local "
                             f"instance. To make a cluster, {HOW_TO_START}.")
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise UserInputError(f"--ray {address}: no Ray cluster answers there "
                             f"({exc.strerror or exc}); {HOW_TO_START}.") from None


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

    def step(self, action: Any) -> tuple[Any, float, bool, dict, dict]:
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
        self.actors = [_EnvActor.options(scheduling_strategy="SPREAD").remote(fn)
                       for fn in env_fns]
        try:
            placed = ray.get([actor.describe.remote() for actor in self.actors])
        except ray.exceptions.RayActorError as exc:
            self.close()
            raise UserInputError(f"a Ray worker could not build its env ({_cause(exc)}): every "
                                 "machine needs the same mjexplore checkout installed "
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
        obs, rews, dones, infos, self.reset_infos = zip(*results, strict=True)
        return _stack_obs(obs, self.observation_space), np.stack(rews), np.stack(dones), infos

    def reset(self) -> VecEnvObs:
        results = ray.get([actor.reset.remote(self._seeds[i], self._options[i])
                           for i, actor in enumerate(self.actors)])
        obs, self.reset_infos = zip(*results, strict=True)
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
            log.warning("closing the env actors: %s", _cause(exc))
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


def _cause(exc: Exception) -> str:
    """The last line of a Ray error (the remote exception), for one-paragraph messages."""
    lines = [line for line in str(exc).splitlines() if line.strip()]
    return lines[-1].strip() if lines else type(exc).__name__
