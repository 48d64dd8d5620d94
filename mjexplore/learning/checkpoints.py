"""Checkpoints of a run folder: written atomically between PPO updates with the run's
``sessions.json`` ledger (:class:`Checkpointer`), read back for a resume
(:func:`load_checkpoint`) and exported as a weights file (:func:`export_checkpoint`)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import torch

from mjexplore.config import to_dict
from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic, write_text_atomic
from mjexplore.io.provenance import git_revision
from mjexplore.learning.policy_network import fresh_policy, network_kwargs
from mjexplore.learning.train_config import TrainConfig
from mjexplore.policies.registry import layout_of
from mjexplore.policies.weights import save_policy_weights

CHECKPOINT_FORMAT = "mjexplore-checkpoint-v1"


class Checkpointer:
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


def export_checkpoint(checkpoint: str | Path, out: str | Path,
                      git_revision_override: str | None = None) -> dict[str, Any]:
    """Writes the policy weights of a checkpoint as a safetensors file; returns its
    provenance. ``git_revision_override`` corrects the recorded revision of checkpoints
    written before it was fixed at the start of training."""
    from mjexplore.config import from_dict
    state = load_checkpoint(Path(checkpoint))
    config = from_dict(TrainConfig, json.loads(state["config"]))
    policy = fresh_policy(config)
    policy.load_state_dict(state["policy"])
    provenance = {"git_revision": git_revision_override or state["git_revision"],
                  "config": to_dict(config),
                  "num_timesteps": int(state["num_timesteps"]),
                  "checkpoint": Path(checkpoint).name}
    save_policy_weights(out, policy, config.kind, network_kwargs(config),
                        layout_of(config.kind, config.env), provenance)
    return provenance
