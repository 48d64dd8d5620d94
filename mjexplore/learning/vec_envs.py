"""The vectorised training envs: each env in a worker process of its own (SB3's
``SubprocVecEnv``) or a Ray actor, and the messages of workers that cannot build their envs
(:class:`WorkerReports`)."""

from __future__ import annotations

import functools
import shutil
import tempfile
from pathlib import Path
from typing import Any

from mjexplore.envs.exploration import EnvConfig, ExplorationEnv
from mjexplore.envs.team_gvn import TeamDecisionEnv
from mjexplore.episode.workers import init_episode_worker, single_thread_children, thread_counts
from mjexplore.errors import UserInputError
from mjexplore.learning.train_config import TrainConfig


def training_env(config: EnvConfig) -> ExplorationEnv | TeamDecisionEnv:
    """A training env of ``config``: one robot's (:class:`ExplorationEnv`), or with
    ``robots`` > 1 a team's decisions one at a time (:class:`TeamDecisionEnv`)."""
    return ExplorationEnv(config) if config.robots == 1 else TeamDecisionEnv(config)


def worker_env(config: EnvConfig, report: str | None = None) -> ExplorationEnv | TeamDecisionEnv:
    """An env in a worker process of its own (a subprocess or a Ray actor): the worker runs
    one thread per library (:func:`~mjexplore.episode.workers.init_episode_worker`) and the
    env records them in ``worker_threads``.

    Args:
        config: The env's settings.
        report: A file where a worker that cannot build its env (a missing or damaged
            input: :class:`UserInputError`) writes the message before it exits, quietly,
            for the parent to raise (:class:`WorkerReports`); None: the error propagates.
    """
    init_episode_worker()
    try:
        env = training_env(config)
    except UserInputError as exc:
        if report is None:
            raise
        Path(report).write_text(str(exc))
        raise SystemExit(2) from None  # No traceback: the parent tells the user.
    env.worker_threads = thread_counts()
    return env


class WorkerReports:
    """A temporary folder where env worker processes leave the message of a
    :class:`UserInputError` they met (see :func:`worker_env`), and the parent's check of it:
    a worker that dies leaves the parent a broken pipe, not the message."""

    def __init__(self) -> None:
        self.folder = Path(tempfile.mkdtemp(prefix="mjexplore-workers."))

    def path(self, index: int) -> str:
        return str(self.folder / f"env{index}.txt")

    def raise_reported(self) -> None:
        """Raises the first reported message as a UserInputError, if a worker left one."""
        for report in sorted(self.folder.glob("env*.txt")):
            message = report.read_text().strip()
            if message:
                raise UserInputError(message)

    def remove(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


# A worker process that died shows in the parent as one of these.
WORKER_DIED = (EOFError, ConnectionError, BrokenPipeError)


def env_maker(config: EnvConfig, own_process: bool, report: str | None = None):
    """A callable that makes one training env of ``config``: in this process, or (with
    ``own_process``) in a worker of its own (:func:`worker_env`, ``report`` its message
    file)."""
    # Partials of module-level callables: plain pickle sends them to any worker or machine.
    if not own_process:
        return functools.partial(training_env, config)
    return functools.partial(worker_env, config, report)


def make_vec_env(config: TrainConfig, seed: int, ray_address: str | None = None):
    """The training envs: ``n_envs`` of them, seeded from ``seed`` and wrapped in SB3's
    ``VecMonitor``.

    Args:
        config: The run's settings.
        seed: Seed of the first env (the others: ``seed + 1``, ...).
        ray_address: None: each env in a worker process when more than one
            (``SubprocVecEnv``). Otherwise each env in a Ray actor
            (:mod:`mjexplore.learning.ray_vec_env`): 'local' on a Ray instance started on this
            machine, 'auto' or 'HOST:PORT' on a running cluster. Ray is shut down when the
            envs are closed if this call initialised it.

    The worker processes' failures to build their envs are raised here with their own
    message (see :class:`WorkerReports`); the returned envs' ``worker_reports`` (None without
    worker processes) holds those of failures that come later, removed by ``close()``.

    Raises:
        UserInputError: No Ray cluster at ``ray_address``, or one that cannot run the envs,
            or a worker that cannot build its env (a missing or damaged input).
    """
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecMonitor

    own_process = ray_address is not None or config.n_envs > 1
    reports = WorkerReports() if ray_address is None and config.n_envs > 1 else None
    makers = [env_maker(config.env, own_process,
                        reports.path(i) if reports is not None else None)
              for i in range(config.n_envs)]
    venv: VecEnv
    if ray_address is not None:
        from mjexplore.io.ray_cluster import connect
        from mjexplore.learning.ray_vec_env import RayVecEnv

        venv = RayVecEnv(makers, shutdown_ray=connect(ray_address, config.n_envs, what="envs",
                                                      fewer="--n-envs"))
    elif reports is not None:
        try:
            with single_thread_children():  # The workers (and a forkserver) start here.
                venv = SubprocVecEnv(makers, start_method="forkserver")
        except WORKER_DIED:
            try:
                reports.raise_reported()
            finally:
                reports.remove()
            raise
    else:
        venv = DummyVecEnv(makers)
    venv.seed(seed)
    monitored = VecMonitor(venv)
    extended: Any = monitored  # SB3's VecMonitor, with an attribute and a close() of ours.
    extended.worker_reports = reports
    if reports is not None:
        close = monitored.close

        def close_and_remove() -> None:
            try:
                close()
            finally:
                reports.remove()

        extended.close = close_and_remove
    return monitored
