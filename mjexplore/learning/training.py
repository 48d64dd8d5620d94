"""Policy training with sb3-contrib's MaskablePPO: config, checkpoints, resume, evaluation.

A run folder holds ``config.yaml`` (the resolved config and git revision), ``checkpoints/``
(``step_<n>.pt``: policy and optimizer state dicts plus metadata, loaded with
``torch.load(weights_only=True)``; ``latest.json`` names the newest), ``tb/`` (TensorBoard),
``eval.csv`` (held-out evaluations), ``policy.safetensors`` (the final weights),
``best.safetensors`` (the best evaluation so far) and ``sessions.json`` (what each start or
resume of the run cost: host, cores, device, revision, the steps it took the run from and
to, wall and learner CPU seconds, the warm start included; updated at every checkpoint).

Checkpoints are written between PPO updates, atomically, so a run killed at any moment
(``kill -9`` included) resumes with ``--resume`` from its last checkpoint and loses only
the steps collected since. A resume is repeatable but not bit-identical to the run it
continues: episodes in progress start afresh and every random stream is re-seeded from
``seed + steps done``.
"""

from __future__ import annotations

import contextlib
import copy
import csv
import dataclasses
import functools
import io
import json
import logging
import multiprocessing
import os
import platform
import random
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from mjexplore.config import from_dict, load_yaml_config, to_dict
from mjexplore.envs.exploration import (
    TEST_SEED_BASE,
    EnvConfig,
    ExplorationEnv,
    ProceduralScenes,
    heldout_scenes,
)
from mjexplore.envs.observation import POSED
from mjexplore.episode import EpisodeConfig
from mjexplore.episode.workers import (
    init_episode_worker,
    reuse_freed_memory,
    single_thread_children,
    thread_counts,
)
from mjexplore.errors import UserInputError
from mjexplore.io.atomic import refuse_foreign_files, write_bytes_atomic, write_text_atomic
from mjexplore.io.provenance import git_revision
from mjexplore.learning.imitation import ImitationConfig
from mjexplore.policies.registry import layout_of
from mjexplore.policies.weights import build_policy, read_policy_weights, save_policy_weights

log = logging.getLogger(__name__)

CHECKPOINT_FORMAT = "mjexplore-checkpoint-v1"
# Settings a resumed run may change (dotted: inside a section): how long it trains, on how
# many envs and threads, the checkpoints it keeps, and whether updates overlap collection.
RESUMABLE_CHANGES = ("total_steps", "n_envs", "torch_threads", "update_threads",
                     "keep_checkpoints", "ppo.overlap")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PpoConfig:
    """MaskablePPO hyperparameters (SB3 names; steps are decisions per env).

    ``overlap`` runs each update in a thread while the next rollout is collected with the
    policy as it was before that update (:mod:`mjexplore.learning.overlap_ppo`): the env
    workers no longer wait for the update, at the cost of a one-update policy lag (PPO's
    ratio and clipping use the stored log-probabilities of the policy that collected, as
    APPO does; the loss is MaskablePPO's own). The update thread runs ``update_threads``
    torch threads (None: ``torch_threads``); checkpoints and evaluations still see the
    weights after a completed update, with every decision they count trained on. Checkpoints
    are therefore the same in both modes, and a resumed run may switch ``overlap``.

    ``prior_kl`` (GVN with a prior) puts ``prior_kl * KL(policy || prior)`` in the loss in
    place of the entropy bonus (:class:`~mjexplore.policies.sb3.GvnPolicy`'s
    ``entropy_reference: prior``; ``train/entropy_loss`` then logs the mean KL, nats):
    a residual policy departs from its prior only where the advantages keep asking for it,
    not by the drift of noisy updates. ``target_kl`` stops an update's epochs once the
    approximate KL from the collecting policy passes 1.5 times it (SB3's ``target_kl``).
    """

    n_steps: int = 256
    batch_size: int = 128
    n_epochs: int = 4
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    # Minibatches of runs of this many consecutive decisions of one env, not single ones
    # (mjexplore/learning/rollout_blocks.py: the GVN then encodes about a third of the TERs).
    minibatch_block: int = 1
    overlap: bool = False
    prior_kl: float = 0.0
    target_kl: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.overlap, bool):
            raise ValueError("ppo.overlap must be true or false")
        if self.prior_kl < 0 or (self.prior_kl and self.ent_coef):
            raise ValueError("ppo.prior_kl must be >= 0, and with it ppo.ent_coef 0 (the KL "
                             "to the prior takes the entropy bonus's place)")
        if self.target_kl is not None and not self.target_kl > 0:
            raise ValueError("ppo.target_kl must be > 0 (or absent: no early stop)")
        for name in ("n_steps", "batch_size", "n_epochs", "minibatch_block"):
            if getattr(self, name) < 1:
                raise ValueError(f"ppo.{name} must be >= 1")
        if self.n_steps % self.minibatch_block or self.batch_size % self.minibatch_block:
            raise ValueError(f"ppo.minibatch_block ({self.minibatch_block}) must divide "
                             f"ppo.n_steps ({self.n_steps}) and ppo.batch_size "
                             f"({self.batch_size})")
        if not 0 < self.gamma <= 1 or not 0 <= self.gae_lambda <= 1:
            raise ValueError("ppo.gamma must be in (0, 1] and ppo.gae_lambda in [0, 1]")
        if self.learning_rate <= 0:
            raise ValueError("ppo.learning_rate must be positive")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PolicyConfig:
    """Policy network and masking (see :mod:`mjexplore.policies.sb3`; ``features`` is the
    CNN baseline's encoder width, the others are GVN sizes). ``share_features_extractor``
    False gives the critic an encoder of its own: with one shared encoder the value loss's
    gradient, about 500 times the policy gradient's at the start, trains it for the critic.
    ``prior_temperature`` (metres per nat, GVN with v2 or v3 observations) adds the
    nearest-node rule's logits to the actor's: the network learns a residual on
    nearest-frontier. ``prior_pocket_m`` (v3) makes that rule count each node this many
    metres farther per unit of its pocket probability (the predictor's). ``residual_scale``
    multiplies the network's logits before the prior's are added (nats per unit of its
    output)."""

    masking: str = "iam"
    share_features_extractor: bool = True
    features: int = 256
    hidden: int = 64
    gcn_layers: int = 3
    tcn_kernel: int = 3
    tcn_dilations: tuple[int, ...] = (1, 2, 4)
    prior_temperature: float | None = None
    prior_pocket_m: float = 0.0
    residual_scale: float = 1.0

    def __post_init__(self) -> None:
        from mjexplore.policies.sb3 import MASKING_MODES

        if self.masking not in MASKING_MODES:
            raise ValueError(f"policy.masking must be one of {', '.join(MASKING_MODES)}")
        if self.hidden < 1 or self.gcn_layers < 1 or self.tcn_kernel < 1:
            raise ValueError("policy sizes must be >= 1")
        if self.prior_temperature is not None and not self.prior_temperature > 0:
            raise ValueError("policy.prior_temperature must be > 0 (metres per nat) or null")
        if self.prior_pocket_m < 0 or (self.prior_pocket_m and self.prior_temperature is None):
            raise ValueError("policy.prior_pocket_m must be >= 0 and needs prior_temperature")
        if not self.residual_scale > 0:
            raise ValueError("policy.residual_scale must be > 0 (nats per unit of the "
                             "network's output)")


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvalConfig:
    """Periodic evaluation on held-out scenes (deterministic policy, in as many processes as
    the run has envs); the best evaluated weights are kept (model selection).

    Select on held-out generated layouts (``procedural``), never on a scene results are
    reported on (the paper's evaluation scenes, the lobby, Explore-Bench, ARiADNE): a
    warning says so when ``scenes`` names one.

    Attributes:
        scenes: Held-out scenes (never trained on), used when ``procedural`` is None.
        procedural: If set, ``layouts`` generated layouts of these families and sizes whose
            generator seeds training never draws (see :func:`heldout_scenes`), the same
            at every evaluation.
        layouts: How many held-out layouts.
        every: Evaluate every this many decision steps (0: never).
        episode: Episode settings of the evaluation (full physics by default).
        seed: Seed of the evaluation episodes and of the held-out layouts' draw.
    """

    scenes: tuple[str, ...] = ("loop_with_corridor",)
    procedural: ProceduralScenes | None = None
    layouts: int = 8
    every: int = 4096
    episode: EpisodeConfig = dataclasses.field(default_factory=EpisodeConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        if self.layouts < 1:
            raise ValueError("eval.layouts must be >= 1")
        if self.procedural is None and self.every:
            from mjexplore.scenes.canonical import canonical_names

            reported = set(canonical_names("eval")) | set(canonical_names("real"))
            named = [s for s in self.scenes if s in reported or any(
                t in str(s).lower() for t in ("explore_bench", "ariadne"))]
            if named:
                log.warning("model selection on %s, where results are reported, biases them: "
                            "set eval.procedural to select on held-out generated layouts",
                            ", ".join(named))

    def scene_list(self) -> tuple[str, ...]:
        """The scenes evaluated: ``scenes``, or the held-out layouts' folders."""
        if self.procedural is None:
            return self.scenes
        return heldout_scenes(self.procedural, self.layouts, self.seed)

    def unseen_scenes(self, count: int) -> tuple[str, ...]:
        """``count`` generated layouts after the model-selection ones (the same draw, seen
        by neither training nor model selection): where a selected policy is tested.

        Raises:
            ValueError: No ``procedural`` layouts to draw them from.
        """
        if self.procedural is None:
            raise ValueError("unseen layouts need eval.procedural")
        return heldout_scenes(self.procedural, self.layouts + count, self.seed)[self.layouts:]

    def test_scenes(self, count: int) -> tuple[str, ...]:
        """``count`` generated layouts for final figures, with generator seeds from
        :data:`~mjexplore.envs.exploration.TEST_SEED_BASE`: neither training, model selection
        nor any tuning on :meth:`scene_list` or :meth:`unseen_scenes` draws them.

        Raises:
            ValueError: No ``procedural`` layouts to draw them from.
        """
        if self.procedural is None:
            raise ValueError("test layouts need eval.procedural")
        return heldout_scenes(self.procedural, count, self.seed, base=TEST_SEED_BASE)


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """A training run.

    Attributes:
        kind: Policy kind: 'gvn' (needs ``env.decisions: ter``) or 'cnn' (``grid``).
        env: Training env settings.
        policy: Network and masking.
        ppo: PPO hyperparameters.
        eval: Held-out evaluation.
        imitation: Behaviour cloning of the ground-truth oracle before PPO (a fresh run's
            warm start; see :mod:`mjexplore.learning.imitation`).
        total_steps: Decision steps to train for (all envs together).
        n_envs: Environments, each in its own worker process when more than one.
        checkpoint_every: Checkpoint after at least this many steps since the last one.
        keep_checkpoints: Keep only this many newest checkpoints (each 3.5 MB for the v3
            GVN, one per update by default: 7 GB over 10^6 decisions); 0 keeps all.
        seed: Seed of torch, numpy and the envs.
        torch_threads: torch intra-op threads in the learner (1 is fastest on 2 cores).
        update_threads: torch intra-op threads during PPO updates, while the env workers
            wait (None: ``torch_threads``).
    """

    kind: str = "gvn"
    env: EnvConfig = dataclasses.field(
        default_factory=lambda: EnvConfig(scenes=("train_loop",)))
    policy: PolicyConfig = dataclasses.field(default_factory=PolicyConfig)
    ppo: PpoConfig = dataclasses.field(default_factory=PpoConfig)
    eval: EvalConfig = dataclasses.field(default_factory=EvalConfig)
    imitation: ImitationConfig = dataclasses.field(default_factory=ImitationConfig)
    total_steps: int = 20000
    n_envs: int = 2
    checkpoint_every: int = 512
    keep_checkpoints: int = 0
    seed: int = 0
    torch_threads: int = 1
    update_threads: int | None = None

    def __post_init__(self) -> None:
        from mjexplore.policies.registry import KINDS

        if self.kind not in KINDS:
            raise ValueError(f"kind {self.kind!r} is unknown: use one of {', '.join(KINDS)}")
        wanted = "ter" if self.kind == "gvn" else "grid"
        if self.env.decisions != wanted:
            raise ValueError(f"kind {self.kind!r} needs env.decisions: {wanted}")
        if self.kind == "cnn" and self.policy.masking != "iam":
            raise ValueError("the cnn kind supports policy.masking: iam only")
        if self.policy.prior_temperature is not None and (
                self.kind != "gvn" or self.env.observation.features not in POSED):
            raise ValueError("policy.prior_temperature needs kind gvn with "
                             "env.observation.features: v2 or v3 (the path feature)")
        if self.policy.prior_pocket_m and self.env.observation.features != "v3":
            raise ValueError("policy.prior_pocket_m needs env.observation.features: v3 (the "
                             "pocket feature)")
        if (self.policy.masking == "none") != (self.env.valid_actions == "all_nodes"):
            raise ValueError("policy.masking: none (training without a mask) goes with "
                             "env.valid_actions: all_nodes, and all_nodes only with none")
        if self.total_steps < 1 or self.n_envs < 1 or self.checkpoint_every < 1:
            raise ValueError("total_steps, n_envs and checkpoint_every must be >= 1")
        if self.keep_checkpoints < 0:
            raise ValueError("keep_checkpoints must be >= 0 (0 keeps all)")
        if self.torch_threads < 1 or (self.update_threads or 1) < 1:
            raise ValueError("torch_threads and update_threads must be >= 1")
        if self.ppo.minibatch_block > 1 and self.kind != "gvn":
            raise ValueError("ppo.minibatch_block > 1 is for kind gvn (its TER memory)")
        if self.ppo.prior_kl and self.policy.prior_temperature is None:
            raise ValueError("ppo.prior_kl needs policy.prior_temperature (the prior it pulls "
                             "toward)")


def load_train_config(path: str | Path, total_steps: int | None = None,
                      n_envs: int | None = None, seed: int | None = None) -> TrainConfig:
    """Reads a training YAML (see training/gvn.yaml); ``total_steps``, ``n_envs`` and
    ``seed``, when given, replace the file's values."""
    config = load_yaml_config(TrainConfig, path)
    overrides = {k: v for k, v in (("total_steps", total_steps), ("n_envs", n_envs),
                                   ("seed", seed)) if v is not None}
    return dataclasses.replace(config, **overrides) if overrides else config


def worker_env(config: EnvConfig, report: str | None = None) -> ExplorationEnv:
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
        env = ExplorationEnv(config)
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


def _make_env(config: EnvConfig, own_process: bool, report: str | None = None):
    # Partials of module-level callables: plain pickle sends them to any worker or machine.
    if not own_process:
        return functools.partial(ExplorationEnv, config)
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
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    own_process = ray_address is not None or config.n_envs > 1
    reports = WorkerReports() if ray_address is None and config.n_envs > 1 else None
    makers = [_make_env(config.env, own_process, reports and reports.path(i))
              for i in range(config.n_envs)]
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
    monitored.worker_reports = reports
    if reports is not None:
        close = monitored.close

        def close_and_remove() -> None:
            try:
                close()
            finally:
                reports.remove()

        monitored.close = close_and_remove
    return monitored


def make_model(config: TrainConfig, venv, seed: int, tensorboard_log: str | None = None,
               device: str = "auto"):
    """The MaskablePPO learner of ``config`` on the envs ``venv``, on torch ``device``
    (:class:`~mjexplore.learning.overlap_ppo.OverlapMaskablePPO` with ``ppo.overlap``)."""
    from sb3_contrib import MaskablePPO

    from mjexplore.learning.overlap_ppo import OverlapMaskablePPO
    from mjexplore.policies.registry import policy_class

    ppo = config.ppo
    buffer: dict[str, Any] = {}
    # The update's setting only: weights files keep _policy_kwargs, the network's.
    policy_kwargs = {**_policy_kwargs(config),
                     **({"entropy_reference": "prior"} if ppo.prior_kl else {})}
    if ppo.overlap:
        learner = functools.partial(OverlapMaskablePPO, update_threads=(
            config.update_threads or config.torch_threads))
    else:
        learner = MaskablePPO
    if ppo.minibatch_block > 1:
        from mjexplore.learning.rollout_blocks import BlockDictRolloutBuffer

        buffer = {"rollout_buffer_class": BlockDictRolloutBuffer,
                  "rollout_buffer_kwargs": {"block": ppo.minibatch_block, "seed": seed}}
    return learner(policy_class(config.kind), venv, n_steps=ppo.n_steps,
                   batch_size=ppo.batch_size, n_epochs=ppo.n_epochs,
                   learning_rate=ppo.learning_rate, gamma=ppo.gamma, gae_lambda=ppo.gae_lambda,
                   clip_range=ppo.clip_range, ent_coef=ppo.prior_kl or ppo.ent_coef,
                   vf_coef=ppo.vf_coef, max_grad_norm=ppo.max_grad_norm,
                   target_kl=ppo.target_kl, policy_kwargs=policy_kwargs,
                   tensorboard_log=tensorboard_log, seed=seed, verbose=0, device=device,
                   **buffer)


def set_phase_threads(config: TrainConfig, updating: bool) -> None:
    """torch's intra-op threads for a PPO update (``update_threads``) or a rollout."""
    torch.set_num_threads((config.update_threads or config.torch_threads) if updating
                          else config.torch_threads)


def ppo_round(config: TrainConfig, seed: int | None = None, model_setup=None,
              device: str = "auto") -> dict[str, float]:
    """One rollout and one PPO update of ``config``, as :func:`train` runs them (torch
    threads included), timed: wall seconds of each, the update's CPU seconds (all its
    threads: what it costs on a machine others share) and the decisions collected.

    Args:
        config: The recipe.
        seed: Seed of the model and envs (default: the config's).
        model_setup: Called with the fresh model before the round (to load weights).
        device: The learner's torch device.
    """
    from stable_baselines3.common.callbacks import BaseCallback

    seed = config.seed if seed is None else seed
    marks: dict[str, float] = {}

    class Clock(BaseCallback):
        def _on_rollout_start(self) -> None:
            set_phase_threads(config, updating=False)
            marks["start"] = time.perf_counter()

        def _on_rollout_end(self) -> None:
            set_phase_threads(config, updating=True)
            marks["collected"] = time.perf_counter()
            marks["collected_cpu"] = time.process_time()

        def _on_step(self) -> bool:
            return True

    _seed_everything(seed)
    venv = make_vec_env(config, seed)
    try:
        model = make_model(config, venv, seed, device=device)
        if model_setup is not None:
            model_setup(model)
        decisions = config.ppo.n_steps * config.n_envs
        model.learn(decisions, callback=Clock())  # One rollout, then one update.
        end, end_cpu = time.perf_counter(), time.process_time()
    finally:
        set_phase_threads(config, updating=False)
        venv.close()
    return {"decisions": decisions, "rollout_s": marks["collected"] - marks["start"],
            "update_s": end - marks["collected"],
            "update_cpu_s": end_cpu - marks["collected_cpu"]}


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 - third-party code may draw from the global state
    torch.manual_seed(seed)


class _Checkpointer:
    """Writes and finds checkpoints of a run folder."""

    def __init__(self, out: Path, config: TrainConfig) -> None:
        self.dir = out / "checkpoints"
        self.config = config
        # The code that runs is the code imported at the start, whatever the checkout
        # becomes while training runs.
        self.revision = git_revision()
        self.ledger = out / "sessions.json"
        self.session = {"started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                        "host": platform.node(), "cores": len(os.sched_getaffinity(0)),
                        "revision": self.revision, "n_envs": config.n_envs,
                        "steps_from": None}
        self._clock = (time.perf_counter(), time.process_time())

    def latest(self) -> Path | None:
        marker = self.dir / "latest.json"
        if not marker.is_file():
            return None
        try:
            name = json.loads(marker.read_text())["checkpoint"]
        except (ValueError, KeyError):
            raise UserInputError(f"{str(marker)!r} is damaged: delete it to resume from the "
                                 "newest step_*.pt by hand, or start a new run.") from None
        return self.dir / name

    def save(self, model, steps: int) -> Path:
        self.dir.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        torch.save({"format": CHECKPOINT_FORMAT, "num_timesteps": int(steps),
                    "n_updates": int(model._n_updates),
                    "policy": model.policy.state_dict(),
                    "optimizer": model.policy.optimizer.state_dict(),
                    "config": json.dumps(to_dict(self.config)),
                    "git_revision": self.revision}, buf)
        path = self.dir / f"step_{steps:09d}.pt"
        write_bytes_atomic(path, buf.getvalue())
        write_text_atomic(self.dir / "latest.json", json.dumps({"checkpoint": path.name,
                                                                "num_timesteps": steps}) + "\n")
        self.record(steps, str(model.device))
        if self.config.keep_checkpoints:  # Older ones go only once latest.json is written.
            for old in sorted(self.dir.glob("step_*.pt"))[:-self.config.keep_checkpoints]:
                old.unlink(missing_ok=True)
        return path

    def record(self, steps: int, device: str) -> None:
        """Writes this session's entry of ``sessions.json`` (the run's steps now)."""
        wall, cpu = self._clock
        self.session.update(device=device, steps_to=int(steps),
                            wall_s=round(time.perf_counter() - wall, 1),
                            learner_cpu_s=round(time.process_time() - cpu, 1))
        earlier = []
        if self.ledger.is_file():
            with contextlib.suppress(ValueError, KeyError, TypeError):
                earlier = [e for e in json.loads(self.ledger.read_text())["sessions"]
                           if e.get("started_utc") != self.session["started_utc"]]
        write_text_atomic(self.ledger, json.dumps({"sessions": [*earlier, self.session]},
                                                  indent=1) + "\n")


def load_checkpoint(path: Path) -> dict[str, Any]:
    """A checkpoint's contents (``weights_only``: tensors and plain data only).

    Raises:
        UserInputError: unreadable, truncated or foreign file.
    """
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds for damaged files.
        raise UserInputError(f"checkpoint {str(path)!r} cannot be read ({type(exc).__name__}: "
                             f"{str(exc).splitlines()[0] if str(exc) else ''}); it is damaged or "
                             "not an mjexplore checkpoint: resume from an older step_*.pt by "
                             "editing latest.json, or start a new run.") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise UserInputError(f"{str(path)!r} is not an mjexplore checkpoint.")
    return state


def _policy_kwargs(config: TrainConfig) -> dict[str, Any]:
    p = config.policy
    if config.kind == "cnn":
        return dict(masking=p.masking, features=p.features)
    kwargs = dict(masking=p.masking, hidden=p.hidden, gcn_layers=p.gcn_layers,
                  tcn_kernel=p.tcn_kernel, tcn_dilations=list(p.tcn_dilations))
    if not p.share_features_extractor:  # Stored with the weights only when it differs.
        kwargs["share_features_extractor"] = False
    if p.prior_temperature is not None:
        kwargs["prior_temperature"] = p.prior_temperature
    if p.prior_pocket_m:
        kwargs["prior_pocket_m"] = p.prior_pocket_m
    if p.residual_scale != 1.0:
        kwargs["residual_scale"] = p.residual_scale
    return kwargs


def _fresh_policy(config: TrainConfig):
    """A new policy network of ``config`` for inference."""
    from mjexplore.policies.registry import decisions_for

    decisions = decisions_for(config.kind, layout_of(config.kind, config.env))
    return build_policy(config.kind, decisions.observation_space, decisions.action_space,
                        _policy_kwargs(config))


def _warm_start(policy, config: TrainConfig, out: Path) -> None:
    """Imitates the oracle into ``policy`` (a fresh run only: cloning, then DAgger rounds if
    the config asks for them); the figures go to ``imitation.json``."""
    from mjexplore.learning.imitation import warm_start

    stats = warm_start(policy, config.env, config.imitation, seed=config.seed)
    log.info("warm start: %d decisions, agreement %.3f", stats["decisions"],
             stats["agreement"])
    write_text_atomic(out / "imitation.json", json.dumps(stats, indent=2) + "\n")


def heldout_env(config: TrainConfig, scene: str) -> ExplorationEnv:
    """The training env on one held-out scene (of ``config.eval.scene_list()``) with the
    evaluation's episode settings; reset it with ``seed=config.eval.seed``."""
    return ExplorationEnv(dataclasses.replace(config.env, scenes=(scene,), procedural=None,
                                              episode=config.eval.episode))


def evaluate_policy_episodes(policy, config: TrainConfig, scenes: tuple[str, ...] | None = None,
                             workers: int = 1) -> list[dict[str, Any]]:
    """Runs the policy deterministically on the held-out scenes (or ``scenes``, with the
    evaluation's episode settings); their episode metrics, in the scenes' order.

    Args:
        policy: An SB3 policy of ``config`` (on any device) or any object with SB3's
            ``predict(obs, deterministic, action_masks)``.
        config: The run's settings.
        scenes: Scenes to evaluate instead of the held-out ones.
        workers: Processes that run the episodes (one scene each at a time); a network
            runs there on the CPU with one thread, so the results equal one process's.
    """
    scenes = config.eval.scene_list() if scenes is None else tuple(scenes)
    if workers <= 1 or len(scenes) <= 1:
        return [heldout_episode(policy, config, scene) for scene in scenes]
    if isinstance(policy, torch.nn.Module):  # Its weights: rebuilt on the CPU there.
        portable = {k: v.detach().cpu() for k, v in policy.state_dict().items()}
    else:
        portable = policy
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(min(workers, len(scenes)), initializer=_eval_worker_init,
                  initargs=(config, portable)) as pool:
        return pool.map(_eval_worker_episode, scenes, chunksize=1)


def heldout_episode(policy, config: TrainConfig, scene: str,
                    env: ExplorationEnv | None = None) -> dict[str, Any]:
    """One episode of ``policy`` (SB3's ``predict``, deterministic, with the action mask) on
    a held-out ``scene`` with the evaluation's settings, in this process: the scene and the
    episode's metrics (simulated time). ``env``: ``heldout_env(config, scene)`` made already
    (default: made here), for a policy that reads more of the episode than its observation."""
    env = heldout_env(config, scene) if env is None else env
    obs, _ = env.reset(seed=config.eval.seed)
    while True:
        action, _ = policy.predict(obs, deterministic=True, action_masks=env.action_masks())
        obs, _, terminated, truncated, info = env.step(int(action))
        if terminated or truncated:
            return {"scene": scene, **info["episode_metrics"]}


_EVAL_WORKER: dict[str, Any] = {}


def _eval_worker_init(config: TrainConfig, portable) -> None:
    # A pool whose initializer raises starts new workers for ever: a failure here is kept
    # and raised by each task instead, and so reaches the parent with its message.
    try:
        init_episode_worker()
        policy = portable
        if isinstance(portable, dict):
            policy = _fresh_policy(config)
            policy.load_state_dict(portable)
            policy.set_training_mode(False)
    except Exception as exc:  # noqa: BLE001 - re-raised by _eval_worker_episode
        _EVAL_WORKER.update(error=exc)
        return
    _EVAL_WORKER.update(config=config, policy=policy)


def _eval_worker_episode(scene: str) -> dict[str, Any]:
    if "error" in _EVAL_WORKER:
        raise _EVAL_WORKER["error"]
    return heldout_episode(_EVAL_WORKER["policy"], _EVAL_WORKER["config"], scene)


class NearestNodeRule:
    """The nearest-node rule as a policy for :func:`evaluate_policy_episodes`: the valid
    node nearest along the known map (the greedy choice of
    :func:`~mjexplore.policies.gvn.path_prior`; v2 or v3 observations), the baseline a
    learned GVN has to beat on the held-out layouts.

    Args:
        pocket_m: v3: count each node this many metres farther per unit of its pocket
            probability (a v3 actor's prior without the network's residual); 0: the plain
            nearest-node rule.
    """

    def __init__(self, pocket_m: float = 0.0) -> None:
        self.pocket_m = pocket_m

    def predict(self, obs: dict[str, np.ndarray], deterministic: bool = True,
                action_masks: np.ndarray | None = None) -> tuple[int, None]:
        from mjexplore.policies.gvn import path_prior

        features = torch.as_tensor(obs["node_features"]).reshape(len(obs["node_mask"]), -1)
        logits = path_prior(features, 1.0, self.pocket_m).numpy()
        if action_masks is not None:
            logits = np.where(action_masks, logits, -np.inf)
        return int(np.argmax(logits)), None


def eval_score(results: list[dict[str, Any]]) -> float:
    """How good a held-out evaluation is: mean coverage first, then mean speed. An explored
    episode counts as full coverage: what it saw past the target ratio (the last scan's
    overshoot) says nothing of the policy."""
    coverage = [1.0 if r["end_reason"] == "explored" else r["exploration_ratio"]
                for r in results]
    return (float(np.mean(coverage)) * 1e4
            - float(np.mean([r["exploration_time_s"] for r in results])))


def _best_score(path: Path) -> float | None:
    """The evaluation score of the weights kept as best so far (None if there are none)."""
    if not path.is_file():
        return None
    try:
        return eval_score(read_policy_weights(path)[1]["provenance"]["eval"])
    except (UserInputError, KeyError, TypeError):
        return None  # Unreadable: the next evaluation replaces it.


def train(config: TrainConfig, out: str | Path, resume: bool = False,
          progress: bool = True, ray_address: str | None = None,
          device: str = "auto", recipe: str | None = None,
          init_weights: str | Path | None = None) -> dict[str, Any]:
    """Trains a policy into the run folder ``out`` (see the module docstring).

    ``ray_address`` runs the envs as Ray actors (see :func:`make_vec_env`) and ``device``
    is the learner's torch device ('auto': a GPU when there is one); neither is part of
    the config, so a run may resume with or without Ray, on any cluster or device. The process's
    malloc keeps freed memory for reuse from then on (:func:`reuse_freed_memory`).

    PPO collects whole rollouts (``ppo.n_steps`` decisions of each env), so a run trains
    ``total_steps`` rounded up to a whole number of them: a line on stderr says so when
    that differs. ``progress`` shows the decisions trained and the phase (collecting,
    updating, evaluating): a bar on a terminal, a line every 30 s elsewhere
    (:class:`~mjexplore.io.progress.Progress`). TensorBoard (``tb/``) gets PPO's losses,
    KL, entropy, explained variance and clip fraction after every update, the held-out
    evaluations' figures, and each phase's wall time.

    Args:
        recipe: The name of the config the run was made from (its file's name), kept in the
            weights' provenance.
        init_weights: A fresh run starts from these weights (a policy file of this config's
            network, e.g. a warm start made by ``python -m tools.research.dagger_probe``)
            instead of the config's own warm start; ``init.json`` records the file, its
            tensors' sha256 and its provenance.

    Returns:
        Summary: steps, checkpoints written, final weights path.

    Raises:
        UserInputError: ``out`` already holds a run and ``resume`` is not set, or
            ``resume`` is set and there is nothing to resume, or no Ray cluster at
            ``ray_address``, or an env worker cannot build its env (its message), or
            ``init_weights`` with ``resume``, or weights of another network.
    """
    out = Path(out)
    if init_weights is not None and resume:
        raise UserInputError("--init-weights starts a fresh run; a resumed run continues from "
                             "its checkpoint: drop one of them.")
    ckpt = _Checkpointer(out, config)
    latest = ckpt.latest()
    if latest is not None and not resume:
        raise UserInputError(f"{str(out)!r} already holds a training run: pass --resume to "
                             "continue it, or choose another --out.")
    if resume and latest is None:
        raise UserInputError(f"nothing to resume in {str(out)!r}: it has no checkpoint yet; run "
                             "without --resume to start.")
    if latest is None:  # A fresh run: into a new folder, or one an earlier start abandoned.
        refuse_foreign_files(out, ABANDONED_START, "an earlier start of 'mjexplore train' that "
                             "made no checkpoint")
    state = load_checkpoint(latest) if latest is not None else None
    if state is not None:
        # Settings added since the run started read as their defaults (which keep the
        # behaviour the run had; a changed default is named explicitly in the configs).
        saved = to_dict(from_dict(TrainConfig, json.loads(state["config"]), "saved config"))
        if _fixed_settings(saved) != _fixed_settings(to_dict(config)):
            raise UserInputError(f"the config differs from the one {str(out)!r} was trained with "
                                 f"(only {', '.join(RESUMABLE_CHANGES)} may change): resume "
                                 f"with {str(out / 'config.yaml')!r}.")
    done = int(state["num_timesteps"]) if state else 0
    reuse_freed_memory()  # The learner's tensors: see mjexplore/episode/workers.py.
    _seed_everything(config.seed + done)
    torch.set_num_threads(config.torch_threads)
    init = _initial_weights(config, init_weights) if init_weights is not None else None
    venv = make_vec_env(config, config.seed + done, ray_address)  # Before writing: may refuse.
    if latest is None:
        _clear_abandoned_start(out)
    return _train(config, out, ckpt, state, latest, venv, progress, device, recipe, init)


# What a start of `train` writes before its first checkpoint (shell patterns).
ABANDONED_START = ("config.yaml", "tb", "checkpoints", "sessions.json", "eval.csv", "init.json",
                   "imitation.json", ".*.tmp")


def _clear_abandoned_start(out: Path) -> None:
    """Removes what an earlier start that made no checkpoint left in ``out`` (its TensorBoard
    events would mix with the new run's in ``tb/``); :func:`train` checked there is no
    other file."""
    left = sorted(out.iterdir()) if out.is_dir() else []
    if left:
        log.warning("removing what an earlier start left in %s without a checkpoint: %s", out,
                    ", ".join(p.name for p in left))
    for path in left:
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()


def _fixed_settings(config: dict[str, Any]) -> dict[str, Any]:
    """A config dict without the settings a resumed run may change (``RESUMABLE_CHANGES``)."""
    out = copy.deepcopy(config)
    for name in RESUMABLE_CHANGES:
        *sections, key = name.split(".")
        part = out
        for section in sections:
            part = part.get(section) or {}
        part.pop(key, None)
    return out


def _initial_weights(config: TrainConfig, path: str | Path) -> dict[str, Any]:
    """The tensors of ``path`` and what ``init.json`` records of them, checked against the
    network ``config`` builds.

    Raises:
        UserInputError: unreadable file, or weights of another network.
    """
    from mjexplore.policies.weights import load_policy, tensors_sha256

    policy, meta = load_policy(path)
    wanted = json.loads(json.dumps({"kind": config.kind, "policy_kwargs": _policy_kwargs(config),
                                    "layout": layout_of(config.kind, config.env)}))
    if any(json.loads(json.dumps(meta.get(k))) != v for k, v in wanted.items()):
        raise UserInputError(f"--init-weights {str(path)!r} holds another network than "
                             f"{config.kind} with this config's policy and observation "
                             "settings: use weights made from the same config.")
    return {"tensors": policy.state_dict(), "record": {
        "weights": str(Path(path).resolve()),
        "tensors_sha256": tensors_sha256(read_policy_weights(path)[0]),
        "policy_kwargs": meta.get("policy_kwargs"), "provenance": meta.get("provenance")}}


def _last_evaluation(out: Path) -> int | None:
    """The decisions at the run's last held-out evaluation (``eval.csv``), None before any."""
    path = out / "eval.csv"
    if not path.is_file():
        return None
    with open(path) as f:
        steps = [int(row["steps"]) for row in csv.DictReader(f)]
    return max(steps, default=None)


def _next_evaluation(every: int, last: int | None) -> int:
    """The decisions at which the next held-out evaluation is due: the first multiple of
    ``every`` past the last evaluation (``last``; None: none yet), so that a run evaluates at
    the same counts however often it is resumed; one a resume skipped is due at once."""
    if every <= 0:
        return 0
    return ((last or 0) // every + 1) * every


def planned_steps(config: TrainConfig, done: int) -> int:
    """The steps a run that has ``done`` trains to: ``total_steps`` rounded up to whole
    rollouts of ``ppo.n_steps`` decisions of each of the ``n_envs`` envs."""
    rollout = config.ppo.n_steps * config.n_envs
    remaining = config.total_steps - done
    return done + -(-remaining // rollout) * rollout if remaining > 0 else done


def _train(config: TrainConfig, out: Path, ckpt: _Checkpointer, state: dict | None,
           latest: Path | None, venv, progress: bool, device: str,
           recipe: str | None, init: dict[str, Any] | None = None) -> dict[str, Any]:
    """:func:`train` once its envs run (they are closed when it returns or raises)."""
    from stable_baselines3.common.callbacks import BaseCallback

    from mjexplore.io.progress import Progress

    done = int(state["num_timesteps"]) if state else 0
    ckpt.session["steps_from"] = done
    failed = True
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "config.yaml", f"# git revision {ckpt.revision}\n" +
                          yaml.safe_dump(to_dict(config), sort_keys=False))
        model = make_model(config, venv, config.seed + done, tensorboard_log=str(out / "tb"),
                           device=device)
        if state is not None:
            model.policy.load_state_dict(state["policy"])
            model.policy.optimizer.load_state_dict(state["optimizer"])
            model.num_timesteps = done
            model._n_updates = int(state["n_updates"])
            log.info("resumed from %s at %d steps", latest, done)
        elif init is not None:
            model.policy.load_state_dict(init["tensors"])
            write_text_atomic(out / "init.json", json.dumps(init["record"], indent=2) + "\n")
        elif config.imitation.episodes > 0:
            _warm_start(model.policy, config, out)

        layout = layout_of(config.kind, config.env)
        provenance = {"git_revision": ckpt.revision, "config": to_dict(config)}
        if recipe is not None:
            provenance["recipe"] = recipe
        written: list[str] = []
        best = {"score": _best_score(out / "best.safetensors") if state is not None else None}
        target = planned_steps(config, done)
        shown = Progress(target, "train", "decisions", enabled=progress, initial=done)
        if target != max(config.total_steps, done):
            rollout = config.ppo.n_steps * config.n_envs
            shown.note(f"train: {config.total_steps - done} more decision steps asked, "
                       f"{target - done} trained: PPO collects whole rollouts of "
                       f"{config.ppo.n_steps} decisions x {config.n_envs} envs = {rollout}, so "
                       f"the run ends at {target} steps.", always=True)

        def export(name: str, steps: int, extra: dict | None = None) -> Path:
            path = out / name
            save_policy_weights(path, model.policy, config.kind, _policy_kwargs(config),
                                layout, {**provenance, "num_timesteps": steps, **(extra or {})})
            return path

        class Callback(BaseCallback):
            def _on_training_start(self) -> None:
                self.last_ckpt = self.num_timesteps
                self.next_eval = _next_evaluation(config.eval.every, _last_evaluation(out))
                self.evaluations = 0
                self.mark = time.perf_counter()
                shown.phase("collecting")

            def _on_rollout_end(self) -> None:
                set_phase_threads(config, updating=True)
                now = time.perf_counter()
                self.logger.record("time/collect_s", now - self.mark)
                self.mark = now
                shown.phase("updating")

            def _on_rollout_start(self) -> None:
                set_phase_threads(config, updating=False)
                # Between updates: the policy and optimizer are consistent with num_timesteps.
                n = self.num_timesteps
                if n > done:  # After an update: its losses, KL, entropy ... go out now.
                    self.logger.record("time/update_s", time.perf_counter() - self.mark)
                if n - self.last_ckpt >= config.checkpoint_every:
                    shown.phase("checkpointing")
                    written.append(ckpt.save(self.model, n).name)
                    self.last_ckpt = n
                if config.eval.every and n >= self.next_eval:
                    self.next_eval = _next_evaluation(config.eval.every, n)
                    shown.phase("evaluating")
                    self._evaluate(n)
                if n > done:
                    self.logger.dump(step=n)
                self.mark = time.perf_counter()
                shown.phase("collecting")

            def _evaluate(self, n: int) -> None:
                # The env workers wait meanwhile: the evaluation takes as many processes.
                results = evaluate_policy_episodes(self.model.policy, config,
                                                   workers=config.n_envs)
                self.evaluations += 1
                for key in ("exploration_time_s", "exploration_ratio", "path_length_m"):
                    self.logger.record(f"eval/{key}", float(np.mean([r[key] for r in results])))
                self.logger.record("eval/explored", float(np.mean(
                    [r["end_reason"] == "explored" for r in results])))
                score = eval_score(results)
                self.logger.record("eval/score", score)
                header = not (out / "eval.csv").exists()
                with open(out / "eval.csv", "a") as f:
                    if header:
                        f.write("steps,scene,exploration_time_s,path_length_m,"
                                "exploration_ratio,end_reason\n")
                    for r in results:
                        f.write(f"{n},{r['scene']},{r['exploration_time_s']},"
                                f"{r['path_length_m']},{r['exploration_ratio']},"
                                f"{r['end_reason']}\n")
                shown.detail(f"held-out {np.mean([r['exploration_time_s'] for r in results]):.0f}"
                             " s")
                if best["score"] is None or score > best["score"]:
                    best["score"] = score
                    export("best.safetensors", n, {"eval": results})

            def _on_step(self) -> bool:
                shown.update(self.training_env.num_envs)
                return True

            def _on_training_end(self) -> None:
                # The last update's figures (SB3 writes them at the next rollout's end).
                self.logger.record("time/update_s", time.perf_counter() - self.mark)
                self.logger.dump(step=self.num_timesteps)

        callback = Callback()
        callback.evaluations = 0
        try:
            if target > done:
                model.learn(target - done, callback=callback, reset_num_timesteps=False,
                            tb_log_name="ppo")
            shown.phase("saving")
            written.append(ckpt.save(model, model.num_timesteps).name)
            final = export("policy.safetensors", model.num_timesteps)
            shown.phase("done")
        finally:
            shown.close()
        if config.eval.every and not callback.evaluations and not (out / "eval.csv").exists():
            shown.note(f"train: no held-out evaluation ran (one every eval.every = "
                       f"{config.eval.every} steps, and the run trained "
                       f"{model.num_timesteps - done}): eval.csv and best.safetensors are "
                       "written from the first evaluation on.", always=True)
        failed = False
    except WORKER_DIED:
        reports = getattr(venv, "worker_reports", None)
        if reports is not None:
            reports.raise_reported()  # A worker's own message, not the broken pipe.
        raise
    finally:
        set_phase_threads(config, updating=False)
        if failed:
            with contextlib.suppress(*WORKER_DIED):
                venv.close()  # Workers that died cannot be told to close.
        else:
            venv.close()
    return {"num_timesteps": int(model.num_timesteps), "checkpoints": written,
            "weights": str(final), "resumed_from": done}


def export_checkpoint(checkpoint: str | Path, out: str | Path,
                      git_revision_override: str | None = None) -> dict[str, Any]:
    """Writes the policy weights of a checkpoint as a safetensors file; returns its
    provenance. ``git_revision_override`` corrects the recorded revision of checkpoints
    written before it was fixed at the start of training."""
    from mjexplore.config import from_dict
    state = load_checkpoint(Path(checkpoint))
    config = from_dict(TrainConfig, json.loads(state["config"]))
    policy = _fresh_policy(config)
    policy.load_state_dict(state["policy"])
    provenance = {"git_revision": git_revision_override or state["git_revision"],
                  "config": to_dict(config),
                  "num_timesteps": int(state["num_timesteps"]),
                  "checkpoint": Path(checkpoint).name}
    save_policy_weights(out, policy, config.kind, _policy_kwargs(config),
                        layout_of(config.kind, config.env), provenance)
    return provenance
