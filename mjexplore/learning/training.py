"""Policy training with sb3-contrib's MaskablePPO: the learner, the training loop, resume.

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

The parts the loop runs live beside it: the config (:mod:`~mjexplore.learning.train_config`),
the envs (:mod:`~mjexplore.learning.vec_envs`), the checkpoints
(:mod:`~mjexplore.learning.checkpoints`) and the held-out evaluation
(:mod:`~mjexplore.learning.evaluation`).
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import random
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from mjexplore.config import from_dict, to_dict
from mjexplore.episode.workers import reuse_freed_memory
from mjexplore.errors import UserInputError
from mjexplore.io.atomic import refuse_foreign_files, write_text_atomic
from mjexplore.learning import evaluation
from mjexplore.learning.checkpoints import Checkpointer, load_checkpoint
from mjexplore.learning.policy_network import network_kwargs
from mjexplore.learning.train_config import RESUMABLE_CHANGES, TrainConfig, fixed_settings
from mjexplore.learning.vec_envs import WORKER_DIED, make_vec_env
from mjexplore.policies.registry import layout_of
from mjexplore.policies.weights import read_policy_weights, save_policy_weights

log = logging.getLogger(__name__)


def make_model(config: TrainConfig, venv, seed: int, tensorboard_log: str | None = None,
               device: str = "auto"):
    """The MaskablePPO learner of ``config`` on the envs ``venv``, on torch ``device``
    (:class:`~mjexplore.learning.overlap_ppo.OverlapMaskablePPO` with ``ppo.overlap``)."""
    from sb3_contrib import MaskablePPO

    from mjexplore.learning.overlap_ppo import OverlapMaskablePPO
    from mjexplore.policies.registry import policy_class

    ppo = config.ppo
    buffer: dict[str, Any] = {}
    # The update's setting only: weights files keep network_kwargs, the network's.
    policy_kwargs = {**network_kwargs(config),
                     **({"entropy_reference": "prior"} if ppo.prior_kl else {})}
    learner: Callable[..., MaskablePPO]
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

    seed_everything(seed)
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


def seed_everything(seed: int) -> None:
    """Seeds the random streams of ``random``, numpy's global state and torch."""
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 - third-party code may draw from the global state
    torch.manual_seed(seed)


def train(config: TrainConfig, out: str | Path, resume: bool = False,
          progress: bool = True, ray_address: str | None = None,
          device: str = "auto", recipe: str | None = None,
          init_weights: str | Path | None = None) -> dict[str, Any]:
    """Trains a policy into the run folder ``out`` (see the module docstring).

    ``ray_address`` runs the envs as Ray actors (see
    :func:`~mjexplore.learning.vec_envs.make_vec_env`) and ``device`` is the learner's torch
    device ('auto': a GPU when there is one); neither is part of the config, so a run may
    resume with or without Ray, on any cluster or device. The process's malloc keeps freed
    memory for reuse from then on (:func:`reuse_freed_memory`).

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
    ckpt = Checkpointer(out, config)
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
        if fixed_settings(saved) != fixed_settings(to_dict(config)):
            raise UserInputError(f"the config differs from the one {str(out)!r} was trained with "
                                 f"(only {', '.join(RESUMABLE_CHANGES)} may change): resume "
                                 f"with {str(out / 'config.yaml')!r}.")
    done = int(state["num_timesteps"]) if state else 0
    reuse_freed_memory()  # The learner's tensors: see mjexplore/episode/workers.py.
    seed_everything(config.seed + done)
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


def _initial_weights(config: TrainConfig, path: str | Path) -> dict[str, Any]:
    """The tensors of ``path`` and what ``init.json`` records of them, checked against the
    network ``config`` builds.

    Raises:
        UserInputError: unreadable file, or weights of another network.
    """
    from mjexplore.policies.weights import load_policy, tensors_sha256

    policy, meta = load_policy(path)
    wanted = json.loads(json.dumps({"kind": config.kind, "policy_kwargs": network_kwargs(config),
                                    "layout": layout_of(config.kind, config.env)}))
    if any(json.loads(json.dumps(meta.get(k))) != v for k, v in wanted.items()):
        raise UserInputError(f"--init-weights {str(path)!r} holds another network than "
                             f"{config.kind} with this config's policy and observation "
                             "settings: use weights made from the same config.")
    return {"tensors": policy.state_dict(), "record": {
        "weights": str(Path(path).resolve()),
        "tensors_sha256": tensors_sha256(read_policy_weights(path)[0]),
        "policy_kwargs": meta.get("policy_kwargs"), "provenance": meta.get("provenance")}}


def planned_steps(config: TrainConfig, done: int) -> int:
    """The steps a run that has ``done`` trains to: ``total_steps`` rounded up to whole
    rollouts of ``ppo.n_steps`` decisions of each of the ``n_envs`` envs."""
    rollout = config.ppo.n_steps * config.n_envs
    remaining = config.total_steps - done
    return done + -(-remaining // rollout) * rollout if remaining > 0 else done


def _train(config: TrainConfig, out: Path, ckpt: Checkpointer, state: dict | None,
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
        best = {"score": (evaluation.best_score(out / "best.safetensors") if state is not None
                          else None)}
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
            save_policy_weights(path, model.policy, config.kind, network_kwargs(config),
                                layout, {**provenance, "num_timesteps": steps, **(extra or {})})
            return path

        class Callback(BaseCallback):
            def _on_training_start(self) -> None:
                self.last_ckpt = self.num_timesteps
                self.next_eval = evaluation.next_evaluation(config.eval.every,
                                                            evaluation.last_evaluation(out))
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
                    self.next_eval = evaluation.next_evaluation(config.eval.every, n)
                    shown.phase("evaluating")
                    self._evaluate(n)
                if n > done:
                    self.logger.dump(step=n)
                self.mark = time.perf_counter()
                shown.phase("collecting")

            def _evaluate(self, n: int) -> None:
                # The env workers wait meanwhile: the evaluation takes as many processes.
                results = evaluation.evaluate_policy_episodes(self.model.policy, config,
                                                              workers=config.n_envs)
                self.evaluations += 1
                for key in ("exploration_time_s", "exploration_ratio", "path_length_m"):
                    self.logger.record(f"eval/{key}", float(np.mean([r[key] for r in results])))
                self.logger.record("eval/explored", float(np.mean(
                    [r["end_reason"] == "explored" for r in results])))
                score = evaluation.eval_score(results)
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


def _warm_start(policy, config: TrainConfig, out: Path) -> None:
    """Imitates the oracle into ``policy`` (a fresh run only: cloning, then DAgger rounds if
    the config asks for them); the figures go to ``imitation.json``."""
    from mjexplore.learning.imitation import warm_start

    stats = warm_start(policy, config.env, config.imitation, seed=config.seed)
    log.info("warm start: %d decisions, agreement %.3f", stats["decisions"],
             stats["agreement"])
    write_text_atomic(out / "imitation.json", json.dumps(stats, indent=2) + "\n")
