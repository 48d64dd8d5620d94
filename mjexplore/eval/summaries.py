"""Compact, committable summaries of benchmark sweeps, the input of the results report.

A sweep's run folders hold megabytes per episode (20 Hz kinematics, 0.1 s ratio curves,
figures). ``collect_sweep`` keeps what the report needs from each episode: its metrics, the
exploration ratio resampled every ``RATIO_DT`` simulated seconds, kinematic smoothness
statistics and, on request, the velocity and acceleration as ``KINEMATICS_DT``-second bin
means (the paper's Fig. 9). One JSON file per experiment, a few hundred kilobytes, so the
report regenerates in seconds from files in the repository, without re-running anything.
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.eval.plots import resample
from mjexplore.eval.sweep import (
    Job,
    finished_metrics,
    read_kinematics,
    read_ratio_curve,
    sweep_history,
)
from mjexplore.io.atomic import write_text_atomic
from mjexplore.io.provenance import git_revision

FORMAT = "mjexplore-sweep-summary"
VERSION = 1
RATIO_DT = 2.0  # s between stored exploration-ratio samples.
KINEMATICS_DT = 1.0  # s per bin of the stored velocity and acceleration series.
KINEMATIC_FIELDS = ("linear_velocity", "angular_velocity", "linear_acceleration",
                    "angular_acceleration")
REPO = Path(__file__).resolve().parents[2]


def _policy_file(method: str) -> Path | None:
    """The weights file a run label's learned explorer reads (None for a classic one)."""
    from mjexplore.eval.methods import LEARNED, parse_method
    from mjexplore.policies.models import resolve_policy

    try:
        spec = parse_method(method)
        return resolve_policy(spec.policy, spec.method)[1] if spec.method in LEARNED else None
    except UserInputError:
        return None


def _policy_record(path: Path) -> dict[str, Any] | None:
    """The weights' hash prefix and training steps (``None`` if the file is missing)."""
    if not path.is_file():
        return None
    from mjexplore.policies.weights import read_policy_weights, weights_sha256

    _, meta = read_policy_weights(path)
    return {"sha256": weights_sha256(path),
            "num_timesteps": meta["provenance"].get("num_timesteps")}


def _run_folders(sweep: Path) -> list[Path]:
    """The finished runs: ``runs/SCENE/METHOD/seedN``, or a team sweep's
    ``runs/SCENE/PLACEMENT/METHOD/seedN`` (``bench --robots``); an episode cut off by
    Ctrl-C is not finished (the sweep runs it again when resumed)."""
    return sorted(p.parent for pattern in ("runs/*/*/seed*/metrics.json",
                                           "runs/*/*/*/seed*/metrics.json")
                  for p in sweep.glob(pattern) if finished_metrics(p.parent) is not None)


def skipped_runs(sweep: str | os.PathLike) -> list[tuple[str, str]]:
    """What a collect of ``sweep`` leaves out, and why: (path under the sweep, reason) for
    each episode that failed (``seedN.failed.json``), was cut off by Ctrl-C, or wrote its
    metrics where no run folder belongs (``runs/SCENE/METHOD/seedN``, or a team sweep's
    ``runs/SCENE/PLACEMENT/METHOD/seedN``)."""
    sweep = Path(sweep)
    finished = set(_run_folders(sweep))
    skipped = []
    for path in sorted((sweep / "runs").rglob("*")):
        where = str(path.relative_to(sweep))
        if path.name.endswith(".failed.json") and path.is_file():
            try:
                error = json.loads(path.read_text()).get("error")
            except (OSError, ValueError, AttributeError):
                error = None
            skipped.append((where.removesuffix(".failed.json"), f"failed: {error}"))
        elif path.name == "metrics.json" and path.parent not in finished and \
                not any(part.startswith(".") for part in path.relative_to(sweep).parts):
            run = str(path.parent.relative_to(sweep))
            depth = len(path.parent.relative_to(sweep / "runs").parts)
            skipped.append((run, "interrupted (Ctrl-C): a re-run of the sweep runs it again"
                            if depth in (3, 4) and path.parent.name.startswith("seed") else
                            "not a run folder of a sweep (runs/SCENE/METHOD/seedN)"))
    return skipped


def team_runs(sweep: str | os.PathLike) -> dict[Path, bool]:
    """Each finished run of a sweep folder: whether it is a team sweep's
    (``runs/SCENE/PLACEMENT/METHOD/seedN``, ``bench --robots``)."""
    sweep = Path(sweep)
    return {folder: len(folder.relative_to(sweep / "runs").parts) == 4
            for folder in _run_folders(sweep)}


def _team_run(folder: Path, config: dict[str, Any]) -> dict[str, Any]:
    """A team sweep's run keys: scene, its placement ('single' for the single robot beside),
    robots, revision, and as its method the folder's with both (``assign_greedy x2 far``),
    so that runs of one method with other teams or starts stay apart."""
    robots = int(config.get("robots", 1))
    placement = folder.parent.parent.name
    return {"scene": folder.parent.parent.parent.name, "placement": placement,
            "robots": robots, "method": f"{folder.parent.name} x{robots} {placement}",
            "revision": config.get("git_revision")}


def _unfinished(sweep: Path, info: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """The episodes ``sweep.json`` planned that left no metrics: ``failed`` (an error,
    with its message) and ``not_run`` (the sweep was stopped before them)."""
    failed, not_run = [], []
    for scene, explorer, seed in itertools.product(
            info.get("scenes", []), info.get("explorers", []), info.get("seeds", [])):
        job = Job(scene, explorer, int(seed))
        folder = job.folder(sweep)
        if finished_metrics(folder) is not None:
            continue
        record = {"scene": job.label, "method": explorer, "seed": job.seed}
        error = folder.with_name(folder.name + ".failed.json")
        if error.is_file():
            failed.append({**record, "error": json.loads(error.read_text()).get("error")})
        else:
            not_run.append(record)
    return {"failed": failed, "not_run": not_run}


def _commands_of_runs(folders: list[Path], history: list[dict[str, Any]]) -> list[str]:
    """The commands that made the runs in ``folders``, in the order the sweep was started:
    each run's own (its ``config.json``), else those of the sweep's starts whose plan holds
    its scene, method and seed."""
    planned = [(plan["command"], {(Job(s, e, int(k)).label, e, f"seed{k}")
                                  for s in plan.get("scenes", [])
                                  for e in plan.get("explorers", [])
                                  for k in plan.get("seeds", [])})
               for plan in history if plan.get("command")]
    made = set()
    for folder in folders:
        config = json.loads((folder / "config.json").read_text())
        if config.get("command"):
            made.add(config["command"])
            continue
        key = (folder.parent.parent.name, folder.parent.name, folder.name)
        made |= {command for command, jobs in planned if key in jobs}
    ordered = [plan["command"] for plan in history if plan.get("command") in made]
    return list(dict.fromkeys(ordered + sorted(made - set(ordered))))


def _ratio(folder: Path) -> dict[str, Any]:
    curve = read_ratio_curve(folder)
    times = np.arange(0.0, curve[-1, 0] + 1e-9, RATIO_DT)
    return {"dt": RATIO_DT, "t_end": round(float(curve[-1, 0]), 3),
            "values": [round(float(v), 3) for v in resample(curve, times)]}


def _rms(values: np.ndarray) -> float:
    return round(float(np.sqrt(np.mean(values ** 2))), 4)


def _kinematics(folder: Path, series: bool) -> dict[str, Any]:
    log = read_kinematics(folder)
    columns = {name: getattr(log, name) for name in KINEMATIC_FIELDS}
    out: dict[str, Any] = {"stats": {
        "linear_velocity_std": round(float(np.std(log.linear_velocity)), 4),
        "angular_velocity_rms": _rms(log.angular_velocity),
        "linear_acceleration_rms": _rms(log.linear_acceleration),
        "angular_acceleration_rms": _rms(log.angular_acceleration)}}
    if series:
        bins = np.floor(log.t / KINEMATICS_DT).astype(int)
        counts = np.bincount(bins)
        keep = counts > 0
        out["series"] = {"dt": KINEMATICS_DT, **{
            name: [round(float(v), 3) for v in
                   (np.bincount(bins, weights=values)[keep] / counts[keep])]
            for name, values in columns.items()}}
    return out


def collect_sweep(sweep: str | os.PathLike, experiment: str, command: str | None = None,
                  kinematics_series: bool = False, reference: str | os.PathLike | None = None,
                  stills: str | None = None, media_dir: str | os.PathLike | None = None
                  ) -> dict[str, Any]:
    """Summarises every finished episode of a sweep folder.

    Args:
        sweep: A ``mjexplore bench --out`` folder (``runs/SCENE/METHOD/seedN`` inside).
        experiment: The name the report knows the summary by (e.g. ``table1``).
        command: The command that made the sweep; defaults to the one in ``sweep.json``.
        kinematics_series: Also keep velocity and acceleration over time (Fig. 9).
        reference: A JSON-lines file of reference results to keep beside the runs (e.g.
            ARiADNE's greedy planner: one object per map with ``map`` and ``travel``).
        stills: A method whose seed-0 ``ter.png`` per scene is copied to ``media_dir`` as
            ``EXPERIMENT_SCENE_METHOD.png``.
        media_dir: Where stills go (needed with ``stills``).

    Returns:
        The summary, as :func:`write_summary` stores it.

    Raises:
        UserInputError: ``sweep`` holds no finished episode, or the reference is unreadable.
    """
    sweep = Path(sweep)
    kinds = team_runs(sweep)
    folders = list(kinds)
    if not folders:
        raise UserInputError(f"{str(sweep)!r} holds no finished episode (no "
                             "runs/SCENE/METHOD/seedN/metrics.json): give the --out folder of "
                             "a 'mjexplore bench' sweep.")
    info = json.loads((sweep / "sweep.json").read_text()) if (sweep / "sweep.json").is_file() \
        else {}
    runs, revisions, settings = [], set(), None
    for folder in folders:
        config = json.loads((folder / "config.json").read_text())
        revisions.add(config.get("git_revision"))
        settings = settings or config["episode"]
        clash = _differing_setting(settings, config["episode"])
        if clash:
            raise UserInputError(f"{folder} ran with another {clash} than the sweep's first "
                                 "episode: a summary mixes no settings; sweep it into its own "
                                 "--out folder.")
        metrics = json.loads((folder / "metrics.json").read_text())
        team = kinds[folder]
        keys = _team_run(folder, config) if team else \
            {"scene": folder.parent.parent.name, "method": folder.parent.name}
        runs.append({**keys, "seed": int(config["seed"]),
                     "resolution": config.get("scene_metadata", {}).get("resolution"),
                     "metrics": {k: v for k, v in metrics.items()
                                 if k not in ("scene", "explorer", "seed")},
                     "ratio": _ratio(folder),
                     # A team's robots each have their own log (robot_i/kinematics.csv).
                     "kinematics": {} if team and int(keys["robots"]) > 1 else
                     _kinematics(folder, kinematics_series)})
    methods = sorted({r["method"] for r in runs})
    specs = dict(zip(info.get("explorers", []), info.get("specs", []), strict=False))
    made_by = _commands_of_runs(folders, sweep_history(sweep))
    summary = {"format": FORMAT, "version": VERSION, "experiment": experiment,
               # The commands that made the runs collected (not merely the last start's).
               "command": command or "\n".join(made_by) or info.get("command"),
               "collected_at_revision": git_revision(),
               "run_revisions": sorted(r for r in revisions if r),
               # By the spec each label ran (sweep.json): a label such as gvn may have run
               # another model than the one it names today (gvn:gvn_paper).
               "policies": {m: _policy_record(path) for m in methods
                            if (path := _policy_file(specs.get(m, m))) is not None},
               # The weights each learned method's runs really used, from their metrics.
               "run_weights": {m: sorted({r["metrics"]["weights_sha256"] for r in runs
                                          if r["method"] == m and "weights_sha256" in r["metrics"]})
                               for m in methods},
               "episode": settings, "reference": _read_reference(reference), "runs": runs,
               "unfinished": _unfinished(sweep, info)}
    if stills is not None:
        summary["stills"] = _copy_stills(folders, experiment, stills, media_dir)
        summary["stills_method"] = stills
    return summary


def merge_summaries(new: dict[str, Any], old: dict[str, Any]) -> dict[str, Any]:
    """``new`` with the runs of ``old`` of the scene and method pairs ``new`` lacks (a sweep
    that adds or re-runs methods or scenes of an experiment whose other runs are kept as
    they were measured).

    The merged summary lists both sweeps' commands and every run's revision.

    Raises:
        UserInputError: The two sweeps ran with different episode settings.
    """
    clash = _differing_setting(old["episode"], new["episode"])
    if clash:
        raise UserInputError(f"the existing summary ran with another {clash} than the sweep: "
                             "a summary mixes no settings; collect without --merge.")
    fresh = {(r["scene"], r["method"]) for r in new["runs"]}
    kept = [r for r in old["runs"] if (r["scene"], r["method"]) not in fresh]
    if not kept:
        return new
    kept_methods = {r["method"] for r in kept} - {r["method"] for r in new["runs"]}
    commands = [c for c in (old.get("command"), new.get("command")) if c]
    merged = dict(new)
    merged["command"] = "\n".join(dict.fromkeys(commands)) or None
    merged["run_revisions"] = sorted(set(old.get("run_revisions", [])) |
                                     set(new.get("run_revisions", [])))
    merged["policies"] = {**{m: rec for m, rec in (old.get("policies") or {}).items()
                             if m in kept_methods}, **(new.get("policies") or {})}
    for key in ("stills", "stills_method", "reference"):
        if not new.get(key) and old.get(key):
            merged[key] = old[key]
    merged["runs"] = kept + new["runs"]
    return merged


def _flatten(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _differing_setting(a: dict[str, Any], b: dict[str, Any]) -> str | None:
    """The first episode setting two runs both record with different values, if any. The
    per-run seed differs by design; settings only one records (added in a later revision
    with the earlier behaviour as default) are not compared."""
    fa, fb = _flatten(a), _flatten(b)
    for key in sorted(fa.keys() & fb.keys()):
        if key != "sim.seed" and fa[key] != fb[key]:
            return key
    return None


def _copy_stills(folders: list[Path], experiment: str, method: str,
                 media_dir: str | os.PathLike | None) -> dict[str, str]:
    """Copies ``method``'s seed-0 ``ter.png`` per scene; returns scene -> file name."""
    if media_dir is None:
        raise UserInputError("stills need a figures folder to copy them to.")
    media = Path(media_dir)
    media.mkdir(parents=True, exist_ok=True)
    copied = {}
    for folder in folders:
        scene = folder.parent.parent.name
        if folder.parent.name == method and folder.name == "seed0" and \
                (folder / "ter.png").is_file():
            target = media / f"{experiment}_{scene}_{method}.png"
            shutil.copyfile(folder / "ter.png", target.with_suffix(".tmp"))
            os.replace(target.with_suffix(".tmp"), target)
            copied[scene] = target.name
    if not copied:
        raise UserInputError(f"no seed-0 run of {method!r} with a ter.png in the sweep: check "
                             "the method name given to --stills.")
    return copied


def _read_reference(path: str | os.PathLike | None) -> list[dict[str, Any]] | None:
    if path is None:
        return None
    try:
        lines = Path(path).read_text().splitlines()
        return [json.loads(line) for line in lines if line.strip()]
    except (OSError, ValueError) as exc:
        raise UserInputError(f"cannot read the reference {str(path)!r} ({exc}): give a JSON-lines "
                             "file, one object per line.") from None


def write_summary(summary: dict[str, Any], path: str | os.PathLike) -> Path:
    """Writes a summary atomically, one line per run (so it diffs run by run)."""
    path = Path(path)
    head = json.dumps({k: v for k, v in summary.items() if k != "runs"}, indent=1)
    runs = ",\n".join(json.dumps(run, separators=(",", ":")) for run in summary["runs"])
    write_text_atomic(path, head[:-2] + ',\n "runs": [\n' + runs + "\n ]\n}\n")
    return path


def read_summary(path: str | os.PathLike) -> dict[str, Any]:
    """Reads and checks a summary written by :func:`write_summary`.

    Raises:
        UserInputError: The file is missing, not JSON, or not a sweep summary of this version.
    """
    try:
        summary = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise UserInputError(f"cannot read the sweep summary {str(path)!r} ({exc}): re-create "
                             "it with 'mjexplore collect'.") from None
    if not isinstance(summary, dict) or summary.get("format") != FORMAT or \
            summary.get("version") != VERSION or not isinstance(summary.get("runs"), list):
        raise UserInputError(f"{str(path)!r} is not a version-{VERSION} mjexplore sweep "
                             "summary: re-create it with 'mjexplore collect'.")
    for run in summary["runs"]:
        if not {"scene", "method", "seed", "metrics", "ratio"} <= set(run):
            raise UserInputError(f"{str(path)!r} has a run without scene/method/seed/metrics/"
                                 "ratio: re-create it with 'mjexplore collect'.")
    return summary


def ratio_curve(run: dict[str, Any]) -> np.ndarray:
    """A stored run's exploration ratio as (N, 2) rows of (t s, ratio), ending with the
    episode's final ratio at its end time (between two stored samples)."""
    values = np.asarray(run["ratio"]["values"], dtype=float)
    curve = np.column_stack([np.arange(len(values)) * run["ratio"]["dt"], values])
    t_end = float(run["ratio"]["t_end"])
    if len(curve) == 0 or t_end > curve[-1, 0] + 1e-9:
        curve = np.vstack([curve, [t_end, run["metrics"]["exploration_ratio"]]])
    return curve


__all__ = ["collect_sweep", "ratio_curve", "read_summary", "write_summary"]
