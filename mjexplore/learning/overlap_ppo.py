"""MaskablePPO whose update runs while the next rollout is collected (``ppo.overlap``).

sb3-contrib's MaskablePPO alternates: collect a rollout, then update on it while every env
worker waits. :class:`OverlapMaskablePPO` runs the update of rollout k in a thread while the
main thread collects rollout k+1 with a *behaviour policy*: a copy of the policy as it was
before that update. Rollout k+1 is then one update stale when it is trained on (a one-update
policy lag). PPO's ratio and clipping are taken against the log-probabilities stored with
each decision, those of the behaviour policy that chose it (whose critic also gave the
values behind the rollout's advantages and returns), as APPO (IMPALA-style
asynchronous PPO) and "PPO with stale data" do; the loss is MaskablePPO's own
:meth:`~sb3_contrib.MaskablePPO.train`, unchanged. Nothing here bounds how far the learner
has moved from the behaviour policy beyond that one update: the clipping sees ratios that
start away from 1 (``train/clip_fraction`` shows how much).

The pipeline, for rollouts 0 .. n-1 (``total_timesteps`` of them)::

    collect 0
    update 0 (thread)  |  collect 1 (behaviour = weights before update 0)
    update 1 (thread)  |  collect 2 (behaviour = weights before update 1)
    ...
    update n-1 (the last rollout's, alone)

torch releases the GIL inside its operations and the envs step in their own processes, so
the two overlap on separate cores.

What callbacks see: ``on_rollout_start`` comes between updates, when no update runs, with
the learner's weights after the last completed update, and ``num_timesteps`` counts the
decisions handed to the learner, so that a checkpoint taken there (weights, optimizer,
``num_timesteps``, ``_n_updates``) is what MaskablePPO's would be: every counted decision
trained on. The decisions of the rollout being collected are counted when it is handed to
the learner. ``on_step`` and ``on_rollout_end`` come while an update may run: a callback
must not save or evaluate the policy there. ``time/update_thread_s`` is the update's own
wall time; a callback that times from ``on_rollout_end`` to ``on_rollout_start`` measures
only the wait for the update beyond the collection.

Threads: torch's intra-op thread count belongs to each OS thread once it has run a parallel
operation (OpenMP's per-thread ``nthreads``; ``torch.set_num_threads`` also sets the default
of threads that have not). The update thread sets ``update_threads`` at each update's start,
and ``torch.set_num_threads`` called on the main thread (as
:func:`~mjexplore.learning.training.set_phase_threads` does from the training callback)
sets only the collection's count and that of the last update, which runs on the main thread.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, cast

import torch
from sb3_contrib import MaskablePPO
from sb3_contrib.common.maskable.buffers import MaskableRolloutBuffer
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.type_aliases import MaybeCallback


class _Actor:
    """The model as ``collect_rollouts`` sees it while an update runs: the behaviour policy
    and a decision count of its own; every other attribute is the model's."""

    _OWN = ("policy", "num_timesteps")

    def __init__(self, model: MaskablePPO, policy) -> None:
        object.__setattr__(self, "_model", model)
        object.__setattr__(self, "policy", policy)
        object.__setattr__(self, "num_timesteps", 0)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._model, name)

    def __setattr__(self, name: str, value: Any) -> None:
        if name in self._OWN:
            object.__setattr__(self, name, value)
        else:
            setattr(self._model, name, value)


class _Announced:
    """A callback whose ``on_rollout_start`` was already called (between updates)."""

    def __init__(self, callback) -> None:
        self._callback = callback

    def on_rollout_start(self) -> None:
        pass

    def __getattr__(self, name: str) -> Any:
        return getattr(self._callback, name)


class OverlapMaskablePPO(MaskablePPO):
    """MaskablePPO with each update overlapped with the next rollout's collection (see the
    module docstring).

    Args:
        *args: As for :class:`~sb3_contrib.MaskablePPO`.
        update_threads: torch intra-op threads of the update thread.
        **kwargs: As for :class:`~sb3_contrib.MaskablePPO`.

    Attributes:
        behaviour: The policy that collects: a copy of ``policy`` (same class and
            constructor parameters), loaded with the learner's weights before each update.
    """

    def __init__(self, *args, update_threads: int = 1, **kwargs) -> None:
        self.update_threads = update_threads
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        # Outside the seeded random stream: the run samples what MaskablePPO's would.
        with torch.random.fork_rng(devices=[]):
            self.behaviour = self.policy_class(self.observation_space, self.action_space,
                                               self.lr_schedule, **self.policy_kwargs)
        self.behaviour = self.behaviour.to(self.device)
        # The class MaskablePPO._setup_model chose, as rollout_buffer's (typed as there).
        buffer_class = cast(type[MaskableRolloutBuffer], self.rollout_buffer_class)
        # One filled by the collection while the update reads the other.
        self._buffers = (self.rollout_buffer, buffer_class(
            self.n_steps, self.observation_space, self.action_space, self.device,
            gamma=self.gamma, gae_lambda=self.gae_lambda, n_envs=self.n_envs,
            **self.rollout_buffer_kwargs))

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "behaviour", "_buffers"]  # Rebuilt.

    def _collect(self, callback, buffer: RolloutBuffer, use_masking: bool) -> tuple[int, bool]:
        """Fills ``buffer`` with the behaviour policy: the decisions it took and whether the
        rollout is complete (False: a callback stopped it)."""
        assert self.env is not None  # Checked by learn().
        actor = _Actor(self, self.behaviour)
        # The stand-in takes the model's place: every attribute but its own two is the model's.
        complete = MaskablePPO.collect_rollouts(cast(MaskablePPO, actor), self.env, callback,
                                                buffer, self.n_steps, use_masking)
        return actor.num_timesteps, complete

    def _update(self) -> float:
        """MaskablePPO's update on ``rollout_buffer`` (in the update thread): its wall
        seconds."""
        torch.set_num_threads(self.update_threads)
        start = time.perf_counter()
        self.train()
        return time.perf_counter() - start

    # As MaskablePPO.learn (ignored there too): use_masking comes before progress_bar.
    def learn(self, total_timesteps: int,  # type: ignore[override]
              callback: MaybeCallback = None, log_interval: int = 1,
              tb_log_name: str = "MaskablePPO", reset_num_timesteps: bool = True,
              use_masking: bool = True, progress_bar: bool = False) -> OverlapMaskablePPO:
        """Trains as :meth:`MaskablePPO.learn` does, each update overlapped with the next
        rollout's collection (see the module docstring)."""
        total_timesteps, callback = self._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        callback.on_training_start(locals(), globals())
        assert self.env is not None
        buffers = self._buffers
        iteration = 0
        self.behaviour.load_state_dict(self.policy.state_dict())
        steps, complete = self._collect(callback, buffers[0], use_masking)
        with ThreadPoolExecutor(1, thread_name_prefix="ppo-update") as pool:
            while complete:
                last = self.num_timesteps + steps >= total_timesteps
                if not last:  # Between updates, as MaskablePPO's rollouts start.
                    self.policy.set_training_mode(False)
                    callback.on_rollout_start()
                self.num_timesteps += steps  # Handed to the learner.
                iteration += 1
                self._update_current_progress_remaining(self.num_timesteps, total_timesteps)
                if log_interval is not None and iteration % log_interval == 0:
                    self.dump_logs(iteration)
                self.rollout_buffer = buffers[(iteration - 1) % 2]
                collecting = buffers[iteration % 2]
                if last:
                    self.train()
                    break
                self.behaviour.load_state_dict(self.policy.state_dict())
                update = pool.submit(self._update)
                steps, complete = self._collect(_Announced(callback), collecting, use_masking)
                self.logger.record("time/update_thread_s", update.result())
        if not complete:  # A callback stopped the collection: counted as MaskablePPO does.
            self.num_timesteps += steps
        callback.on_training_end()
        return self
