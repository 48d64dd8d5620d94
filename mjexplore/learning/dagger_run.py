"""DAgger that spans sessions (``mjexplore imitate``): every round's labelled decisions and
the refitted weights go to a run folder as the round ends.

:func:`~mjexplore.learning.imitation.warm_start` runs a warm start in memory, in one go,
before PPO. A DAgger of thousands of layouts takes hours of a few cores and holds gigabytes of
observations: :func:`imitate` runs the same rounds
(:func:`~mjexplore.learning.imitation.dagger_rounds`) and keeps each one on disk, so that a run
stops between rounds and resumes where it stopped, and its labelled decisions stay to be
fitted again. A resumed run labels the same decisions as one that never stopped, and its
weights agree with that run's as closely as two runs that never stopped agree with each
other: the refit is not bit-reproducible (Adam turns rounding-sized differences of the
gradients into whole steps), so the weights differ by up to about 2e-4 in the tests.

Run folder::

    config.yaml                    the recipe (and the git revision that started the run)
    rounds/round_000.npz           one round's decisions: observations per key (float32),
                                   masks, expert labels, actions taken (compressed)
    imitation.json                 each round's figures (as warm_start's ``rounds``, with
                                   :func:`~mjexplore.learning.imitation.departures` on its
                                   new states before the refit), with the revision and host
                                   that ran it
    policy_untrained.safetensors   the network before round 0
    weights/round_NNN.safetensors  the weights after each round's refit (a learning curve)
    policy.safetensors             the weights after the last finished round's refit: start
                                   PPO from it with ``mjexplore train --init-weights``

A resumed run must have the same recipe, except ``imitation.dagger_iterations`` (run more
rounds) and ``imitation.workers``.
"""

from __future__ import annotations

import copy
import io
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from mjexplore.config import from_dict, to_dict
from mjexplore.errors import UserInputError
from mjexplore.io.atomic import refuse_foreign_files, write_bytes_atomic, write_text_atomic
from mjexplore.io.provenance import git_revision
from mjexplore.learning.imitation import Aggregate, dagger_rounds
from mjexplore.learning.policy_network import fresh_policy, network_kwargs
from mjexplore.learning.train_config import TrainConfig
from mjexplore.learning.training import seed_everything
from mjexplore.policies.registry import layout_of
from mjexplore.policies.weights import load_policy, save_policy_weights

# Settings a resumed DAgger run may change (inside ``imitation``).
RESUMABLE_CHANGES = ("dagger_iterations", "workers")
ROUND_KEYS = ("masks", "labels", "taken")  # Beside the observations (``obs/<key>``).


def imitate(config: TrainConfig, out: str | Path, resume: bool = False) -> dict[str, Any]:
    """Runs DAgger's rounds of ``config.imitation`` (1 + ``dagger_iterations``) into ``out``
    (see the module docstring), one torch thread.

    Args:
        config: The recipe: its env, policy, seed and ``imitation`` settings.
        out: The run folder.
        resume: Continue the run in ``out`` after its last finished round.

    Returns:
        The run's figures (``imitation.json``'s content).

    Raises:
        UserInputError: ``out`` already holds a run and ``resume`` is not set, nothing to
            resume, a recipe that differs from the run's, a recipe without imitation
            episodes, or a damaged round file.
    """
    out = Path(out)
    ledger = out / "imitation.json"
    if not config.imitation.episodes:
        raise UserInputError("the recipe has no imitation episodes: set imitation.episodes "
                             "(per round) and imitation.dagger_iterations (rounds after the "
                             "first), as training/gvn_dagger_lookahead.yaml does.")
    if ledger.is_file() and not resume:
        raise UserInputError(f"{str(out)!r} already holds a DAgger run: pass --resume to "
                             "continue it, or choose another --out.")
    if resume and not ledger.is_file():
        raise UserInputError(f"nothing to resume in {str(out)!r}: it has no finished round; "
                             "run without --resume to start.")
    refuse_foreign_files(out, ("imitation.json", "config.yaml", "policy.safetensors",
                               "policy_untrained.safetensors", "weights", "rounds", ".*.tmp"),
                         "an imitation run")
    torch.set_num_threads(1)
    seed_everything(config.seed)
    policy = fresh_policy(config)
    weights = (config.kind, network_kwargs(config), layout_of(config.kind, config.env))
    revision = git_revision()
    if resume:
        record = json.loads(ledger.read_text())
        saved = to_dict(from_dict(TrainConfig, record["config"], "the run's config"))
        if _fixed(saved) != _fixed(to_dict(config)):
            raise UserInputError(f"the recipe differs from the one {str(out)!r} was run with "
                                 f"(only imitation.{' and imitation.'.join(RESUMABLE_CHANGES)} "
                                 f"may change): resume with {str(out / 'config.yaml')!r}.")
        policy.load_state_dict(load_policy(out / "policy.safetensors")[0].state_dict())
        aggregate = _read_rounds(out, len(record["rounds"]))
    else:
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "config.yaml", f"# git revision {revision}\n" +
                          yaml.safe_dump(to_dict(config), sort_keys=False))
        record = {"config": to_dict(config), "rounds": []}
        save_policy_weights(out / "policy_untrained.safetensors", policy, *weights,
                            _provenance(config, revision, 0))
        aggregate = None
    session = {"revision": revision, "host": platform.node()}
    rounds = 1 + config.imitation.dagger_iterations
    tick = time.perf_counter()
    for done in dagger_rounds(policy, config.env, config.imitation, config.seed, rounds,
                              start=len(record["rounds"]), aggregate=aggregate):
        _write_round(out, done)
        provenance = _provenance(config, revision, done.stats["aggregate"], done.iteration + 1)
        (out / "weights").mkdir(exist_ok=True)
        save_policy_weights(out / "weights" / f"round_{done.iteration:03d}.safetensors",
                            policy, *weights, provenance)
        save_policy_weights(out / "policy.safetensors", policy, *weights, provenance)
        record["rounds"].append({**done.stats, **session,
                                 "wall_s": round(time.perf_counter() - tick, 1)})
        record["decisions"] = done.stats["aggregate"]
        write_text_atomic(ledger, json.dumps(record, indent=1) + "\n")
        tick = time.perf_counter()
    return record


def _fixed(config: dict[str, Any]) -> dict[str, Any]:
    """What a resumed run must keep: everything but ``RESUMABLE_CHANGES`` and the PPO
    settings (DAgger does not read them)."""
    out = copy.deepcopy(config)
    out.pop("ppo", None)
    out.pop("total_steps", None)
    for key in RESUMABLE_CHANGES:
        out.get("imitation", {}).pop(key, None)
    return out


def _provenance(config: TrainConfig, revision: str, decisions: int,
                rounds: int = 0) -> dict[str, Any]:
    return {"config": to_dict(config), "git_revision": revision, "num_timesteps": 0,
            "imitation": {"rounds": rounds, "decisions": decisions}}


def _write_round(out: Path, done) -> None:
    """``rounds/round_NNN.npz`` of a finished round, atomically."""
    arrays = {f"obs/{k}": v for k, v in done.observations.items()}
    arrays.update(masks=done.masks, labels=done.labels, taken=done.taken)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    (out / "rounds").mkdir(exist_ok=True)
    write_bytes_atomic(out / "rounds" / f"round_{done.iteration:03d}.npz", buffer.getvalue())


def read_round(path: str | Path) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray,
                                          np.ndarray]:
    """One round's (observations per key, masks, labels, actions taken) from its ``.npz``.

    Raises:
        UserInputError: a missing, truncated or foreign file.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            observations = {k[4:]: data[k] for k in data.files if k.startswith("obs/")}
            masks, labels, taken = (data[k] for k in ROUND_KEYS)
    except (OSError, ValueError, KeyError) as exc:
        raise UserInputError(f"cannot read the DAgger round {str(path)!r} ({exc}): delete the "
                             "run's later rounds from imitation.json by hand, or start a new "
                             "run.") from None
    return observations, masks.astype(bool), labels.astype(np.int64), taken.astype(np.int64)


def _read_rounds(out: Path, rounds: int) -> Aggregate:
    """The decisions of rounds 0 .. ``rounds`` - 1 of the run in ``out``."""
    aggregate = Aggregate({}, np.zeros((0, 0), bool), np.zeros(0, np.int64))
    for i in range(rounds):
        observations, masks, labels, _ = read_round(out / "rounds" / f"round_{i:03d}.npz")
        aggregate = aggregate.extended(observations, masks, labels)
    return aggregate
