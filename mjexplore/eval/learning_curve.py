"""A training run's learning curve against its prior and the oracle, and how often the policy
departs from its prior.

A run folder of ``mjexplore train --out RUN`` (see :mod:`mjexplore.learning.training`) holds
what is read here: ``eval.csv`` (one row per validation layout per evaluation: ``steps``,
``scene``, ``exploration_time_s``, ``path_length_m``, ``exploration_ratio``, ``end_reason``),
``config.yaml`` (the resolved config, its first line ``# git revision REV``),
``checkpoints/latest.json`` (the newest checkpoint and its decisions) and, after a warm
start, ``imitation.json``.

Baselines (the prior rule alone, ``pocket_nearest``, and the ground-truth ``oracle``) are
measured once on the run's validation layouts with its evaluation settings and cached in
``RUN/baselines.json`` (:func:`cached_baselines`), one entry per key: the layouts, the run's
revision and its env and evaluation settings. Layouts are named by their folder's name (a
generated layout's folder lies in a cache whose path differs between machines).
"""

from __future__ import annotations

import csv
import hashlib
import json
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mjexplore.config import to_dict
from mjexplore.errors import UserInputError
from mjexplore.eval.stats import compare_paired
from mjexplore.io.atomic import write_text_atomic
from mjexplore.learning.evaluation import eval_score, heldout_env
from mjexplore.learning.train_config import TrainConfig

log = logging.getLogger(__name__)

BASELINES_FILE = "baselines.json"
BASELINES_FORMAT = "mjexplore-baselines-v1"
# The baselines measured: the prior rule alone, plain nearest-frontier (what the paper's
# recipe is asked to beat) and the ground-truth bound.
BASELINES = ("pocket_nearest", "nearest", "oracle")


def layout_name(scene: str) -> str:
    """A validation layout's name: its scene folder's name (a canonical scene's name is
    its own)."""
    return Path(scene).name


def read_evaluations(run: str | Path) -> list[dict[str, Any]]:
    """The rows of ``RUN/eval.csv`` with typed values (steps int; seconds, metres and ratio
    float); [] without the file.

    Raises:
        UserInputError: a row that lacks a column or holds a value of the wrong kind.
    """
    path = Path(run) / "eval.csv"
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    try:
        return [{"steps": int(r["steps"]), "scene": str(r["scene"]),
                 "exploration_time_s": float(r["exploration_time_s"]),
                 "path_length_m": float(r["path_length_m"]),
                 "exploration_ratio": float(r["exploration_ratio"]),
                 "end_reason": str(r["end_reason"])} for r in rows]
    except (KeyError, TypeError, ValueError) as exc:
        raise UserInputError(
            f"{str(path)!r} is not an eval.csv of 'mjexplore train' ({type(exc).__name__}: "
            f"{exc}): it needs the columns steps, scene, exploration_time_s, path_length_m, "
            "exploration_ratio and end_reason with a number in each numeric one.") from None


def learning_curve(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One point per evaluation, in order of decisions trained.

    Returns:
        Per evaluation: ``steps`` (decisions trained), ``layouts`` (rows), ``explored``
        (layouts explored), ``mean_exploration_time_s`` (simulated s) and ``score``
        (:func:`~mjexplore.learning.evaluation.eval_score`, what model selection maximises).
    """
    points = []
    for steps in sorted({r["steps"] for r in rows}):
        mine = [r for r in rows if r["steps"] == steps]
        points.append({"steps": steps, "layouts": len(mine),
                       "explored": sum(r["end_reason"] == "explored" for r in mine),
                       "mean_exploration_time_s": round(float(np.mean(
                           [r["exploration_time_s"] for r in mine])), 2),
                       "score": round(eval_score(mine), 3)})
    return points


def best_evaluation(points: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The point training kept as ``best.safetensors``: the first with the highest score
    (None without evaluations)."""
    best = None
    for p in points:
        if best is None or p["score"] > best["score"]:
            best = p
    return best


def run_revision(run: str | Path) -> str | None:
    """The git revision a run was trained at (``config.yaml``'s first line; None if it has
    none)."""
    path = Path(run) / "config.yaml"
    if not path.is_file():
        return None
    first = path.read_text().partition("\n")[0]
    prefix = "# git revision "
    if not first.startswith(prefix):
        return None
    return first[len(prefix):].strip() or None


def start_revision(run: str | Path) -> str | None:
    """The git revision a run started at: its first session's (``sessions.json``), else
    :func:`run_revision` (a resume rewrites ``config.yaml`` with its own revision)."""
    ledger = Path(run) / "sessions.json"
    if ledger.is_file():
        sessions = json.loads(ledger.read_text()).get("sessions") or []
        if sessions and sessions[0].get("revision"):
            return sessions[0]["revision"]
    return run_revision(run)


def shipped_weights(run: str | Path) -> Path | None:
    """A run's shipped policy: the best evaluated weights (``best.safetensors``), else the
    final ones (``policy.safetensors``); None if it has neither."""
    for name in ("best.safetensors", "policy.safetensors"):
        if (Path(run) / name).is_file():
            return Path(run) / name
    return None


def run_facts(run: str | Path) -> dict[str, Any]:
    """What a run folder records of its training, and only that.

    Returns:
        ``revision`` (see :func:`run_revision`; else the shipped weights'), and where
        recorded: ``decisions_trained`` and ``checkpoint`` (``checkpoints/latest.json``),
        ``shipped`` (the shipped weights' file and the decisions they were trained, from
        their provenance; see :func:`shipped_weights`), and with a warm start
        ``imitation``: its decisions, episodes and wall time (s); from ``sessions.json``
        (runs since 51c9f13) ``sessions`` (each start or resume: host, cores, device,
        revision, steps from and to, wall and learner CPU seconds) and their total
        ``sessions_wall_s``. Older runs have only the phase times TensorBoard holds (see the tool
        ``mjexplore plot-training``).
    """
    from mjexplore.policies.weights import read_policy_weights

    run = Path(run)
    facts: dict[str, Any] = {"revision": run_revision(run)}
    weights = shipped_weights(run)
    if weights is not None:
        provenance = read_policy_weights(weights)[1]["provenance"]
        facts["shipped"] = {"weights": weights.name,
                            "decisions": provenance.get("num_timesteps")}
        facts["revision"] = facts["revision"] or provenance.get("git_revision")
    latest = run / "checkpoints" / "latest.json"
    if latest.is_file():
        marker = json.loads(latest.read_text())
        facts["decisions_trained"] = int(marker["num_timesteps"])
        facts["checkpoint"] = marker["checkpoint"]
    imitation = run / "imitation.json"
    if imitation.is_file():
        stats = json.loads(imitation.read_text())
        facts["imitation"] = {k: stats[k] for k in ("decisions", "episodes", "wall_s")
                              if k in stats}
    ledger = run / "sessions.json"
    if ledger.is_file():
        facts["sessions"] = json.loads(ledger.read_text())["sessions"]
        facts["sessions_wall_s"] = round(sum(e.get("wall_s", 0.0) for e in facts["sessions"]), 1)
    return facts


def baseline_key(config: TrainConfig, revision: str | None) -> dict[str, Any]:
    """What the baselines of a run depend on: its validation layouts (names), revision, and
    a digest of its env, evaluation and prior settings."""
    settings = json.dumps({"env": to_dict(config.env), "eval": to_dict(config.eval),
                           "prior_pocket_m": config.policy.prior_pocket_m}, sort_keys=True)
    return {"layouts": [layout_name(s) for s in config.eval.scene_list()],
            "revision": revision,
            "settings_sha256": hashlib.sha256(settings.encode()).hexdigest()[:16]}


def _key_id(key: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


# Per baseline, per layout in the key's order: {"layout", "exploration_time_s",
# "path_length_m", "explored"}.
Measured = dict[str, list[dict[str, Any]]]


def cached_baselines(run: str | Path, config: TrainConfig, revision: str | None,
                     measure: Callable[[TrainConfig, list[str]], Measured],
                     recompute: bool = False, names: Sequence[str] = BASELINES
                     ) -> tuple[dict[str, Any], bool]:
    """The run's baselines from ``RUN/baselines.json``; those of ``names`` the file has not
    for this key (:func:`baseline_key`), or all of them with ``recompute``, are measured
    and added.

    Args:
        run: The run folder.
        config: The run's config.
        revision: The revision the run started at (part of the key; :func:`start_revision`).
        measure: Measures the named baselines on ``config.eval.scene_list()`` (see
            :data:`Measured`).
        recompute: Measure again even if cached.
        names: The baselines wanted (those that apply to the run).

    Returns:
        (the entry: ``key``, ``measured_at`` (per baseline, the revision of the code that
        measured it) and the per-layout figures of each baseline; whether it came from the
        cache alone).
    """
    from mjexplore.io.provenance import git_revision

    path = Path(run) / BASELINES_FILE
    stored: dict[str, Any] = {"format": BASELINES_FORMAT, "entries": {}}
    if path.is_file():
        try:
            loaded = json.loads(path.read_text())
            if loaded.get("format") == BASELINES_FORMAT:
                stored = loaded
        except ValueError:
            log.warning("%s is damaged: its baselines are measured again", path)
    key = baseline_key(config, revision)
    entry = stored["entries"].get(_key_id(key))
    if entry is None or recompute:
        entry = {"key": key, "measured_at": {}}
    elif isinstance(entry["measured_at"], str):  # One revision for all: an older file.
        entry["measured_at"] = {n: entry["measured_at"] for n in BASELINES if n in entry}
    missing = [n for n in names if n not in entry]
    if not missing:
        return entry, True
    measured = measure(config, missing)
    entry.update(measured)
    entry["measured_at"].update({n: git_revision() for n in measured})
    stored["entries"][_key_id(key)] = entry
    write_text_atomic(path, json.dumps(stored, indent=1) + "\n")
    return entry, False


def baseline_means(entry: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per baseline of a cached entry: mean exploration time (simulated s) and layouts
    explored."""
    return {name: {"mean_exploration_time_s": round(float(np.mean(
                       [r["exploration_time_s"] for r in entry[name]])), 2),
                   "explored": sum(bool(r["explored"]) for r in entry[name]),
                   "layouts": len(entry[name])}
            for name in BASELINES if entry.get(name)}


def paired_ratio(rows: Sequence[dict[str, Any]], baseline: Sequence[dict[str, Any]]
                 ) -> dict[str, Any] | None:
    """The policy's exploration times (eval.csv rows of one evaluation) against a
    baseline's on the same layouts: the mean of per-layout ratios, its bootstrap 95 %
    interval, layouts faster and slower, and the sign test's p-value
    (:func:`~mjexplore.eval.stats.compare_paired`). None without a common layout."""
    theirs = {r["layout"]: r["exploration_time_s"] for r in baseline}
    pairs = [(r["exploration_time_s"], theirs[layout_name(r["scene"])]) for r in rows
             if layout_name(r["scene"]) in theirs]
    if not pairs:
        return None
    c = compare_paired(*zip(*pairs, strict=True))
    return {"ratio": round(c.mean, 4), "ci95": [round(c.low, 4), round(c.high, 4)],
            "faster": c.faster, "slower": c.slower, "p_value": round(c.p_value, 4),
            "layouts": len(pairs)}


def prior_departures(policy, config: TrainConfig,
                     scenes: Sequence[str] | None = None) -> dict[str, Any]:
    """How often a residual policy departs from its prior: runs its greedy episodes (as the
    held-out evaluation does: :func:`~mjexplore.learning.evaluation.heldout_env`, seed
    ``config.eval.seed``) and, at every decision, compares its most probable valid action
    with the argmax of its prior's logits over the same valid actions
    (``policy.pi_features_extractor.prior_logits``).

    Args:
        policy: A GVN policy with a prior (``prior_temperature`` set), in this process.
        config: The settings of its training run.
        scenes: Layouts to run (default: the validation layouts, ``eval.scene_list()``).

    Returns:
        ``decisions``, ``choices`` (decisions with two or more valid actions),
        ``departures`` (decisions where the policy's action is not the prior's), ``share``
        (departures per decision) and ``share_of_choices``, and ``per_layout`` (the same
        counts and the episode's exploration time, simulated s).

    Raises:
        ValueError: The policy has no prior.
    """
    import torch

    extractor = policy.pi_features_extractor
    if getattr(extractor, "prior_temperature", None) is None:
        raise ValueError("departures from the prior need a policy with a prior: a GVN "
                         "trained with policy.prior_temperature set")
    scenes = config.eval.scene_list() if scenes is None else tuple(scenes)
    per_layout = []
    policy.set_training_mode(False)
    for scene in scenes:
        env = heldout_env(config, scene)
        obs, info = env.reset(seed=config.eval.seed)
        counts = {"decisions": 0, "choices": 0, "departures": 0}
        done = info["end_reason"] is not None
        while not done:
            mask = env.action_masks()
            action, _ = policy.predict(obs, deterministic=True, action_masks=mask)
            with torch.no_grad():
                prior = extractor.prior_logits(policy.obs_to_tensor(obs)[0])[0].cpu().numpy()
            counts["decisions"] += 1
            counts["choices"] += int(mask.sum() > 1)
            counts["departures"] += int(int(action) != int(np.argmax(np.where(mask, prior,
                                                                               -np.inf))))
            obs, _, terminated, truncated, info = env.step(int(action))
            done = terminated or truncated
        assert env.episode is not None  # Reset at the top of the loop.
        per_layout.append({"layout": layout_name(scene), **counts, "exploration_time_s":
                           env.episode.result().metrics["exploration_time_s"]})
    totals = {k: sum(r[k] for r in per_layout) for k in ("decisions", "choices", "departures")}
    return {**totals,
            "share": round(totals["departures"] / totals["decisions"], 4)
            if totals["decisions"] else None,
            "share_of_choices": round(totals["departures"] / totals["choices"], 4)
            if totals["choices"] else None,
            "per_layout": per_layout}
