"""Benchmark sweeps: scenes x explorers x seeds in worker processes, then tables and plots.

Every episode writes its own run folder under ``OUT/runs/SCENE/EXPLORER/seedN`` (atomic);
a sweep started again skips the episodes whose folder is complete (not ended by Ctrl-C), so
an interrupted sweep resumes where it stopped. Finished runs made with other episode
settings are refused rather than mixed in or overwritten. The summary is a Table-1-like
table (mean +- std of IoU, ER, ET, PL, T80, T98.5 per scene and method) in ``results.md``
and ``results.csv``, a Fig-5-like plot per scene (``ratio_SCENE.png``) and a Fig-9-like
kinematics plot per scene (``kinematics_SCENE.png``).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import io
import json
import logging
import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from mjexplore.episode import EpisodeConfig
from mjexplore.episode.team import TeamConfig
from mjexplore.episode.workers import init_episode_worker
from mjexplore.errors import UserInputError
from mjexplore.eval.methods import LEARNED, parse_method, team_explorers
from mjexplore.eval.placements import team_starts
from mjexplore.eval.plots import kinematics_figure, ratio_figure
from mjexplore.eval.run import write_run
from mjexplore.io.atomic import atomic_directory, refuse_foreign_files, write_text_atomic
from mjexplore.io.bundle import Bundle, write_files
from mjexplore.io.progress import Progress
from mjexplore.io.provenance import git_revision
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.scene import SceneFiles
from mjexplore.sim.kinematics import KinematicsLog
from mjexplore.sim.simulator import compile_scene

# What a sweep folder holds (run_sweep and the team sweep), as shell patterns.
SWEEP_OUTPUTS = ("sweep.json", "runs", "results.md", "results.csv", "ratio_*.png",
                 "kinematics_*.png", ".*.tmp")
METRICS = (("iou", "IoU"), ("exploration_ratio", "ER"), ("exploration_time_s", "ET (s)"),
           ("path_length_m", "PL (m)"), ("t80_s", "T80 (s)"), ("t985_s", "T98.5 (s)"))


log = logging.getLogger(__name__)


def scene_label(scene: str) -> str:
    """The name a scene's runs are filed under: a scene folder's name (also for its
    ``scene.xml``), else the file's stem."""
    path = Path(scene)
    return path.parent.name if path.name == "scene.xml" and path.parent.name else path.stem


@dataclasses.dataclass(frozen=True)
class Job:
    """One episode of a sweep: ``explorer`` is the run label (its folder), ``spec`` the
    method spec that builds its explorer (:mod:`mjexplore.eval.methods`; None: the label).

    A team sweep's jobs also name their start ``placement`` (:mod:`mjexplore.eval.
    placements`; 'single' for the single-robot baseline), which files them under
    ``runs/SCENE/PLACEMENT/EXPLORER/seedN``, and run ``robots`` robots of the team method
    ``spec`` (``unknown_starts``: the robots merge their maps, as ``TeamConfig`` says)."""

    scene: str
    explorer: str
    seed: int
    spec: str | None = None
    placement: str | None = None
    robots: int = 1
    unknown_starts: bool = False

    @property
    def label(self) -> str:
        return scene_label(self.scene)

    def folder(self, out: Path) -> Path:
        where = [self.placement] if self.placement else []
        return out.joinpath("runs", self.label, *where, self.explorer, f"seed{self.seed}")


def finished_metrics(folder: Path) -> dict[str, Any] | None:
    """A run folder's metrics if the episode ran to its end (not cut off by Ctrl-C)."""
    try:
        metrics = json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    return None if metrics.get("end_reason") == "interrupted" else metrics


def _episode_settings(config: EpisodeConfig) -> Any:
    """The episode settings as a run folder's config.json stores them."""
    return json.loads(json.dumps(dataclasses.asdict(config), default=str))


def check_settings(jobs: list[Any], out: Path, config: EpisodeConfig) -> None:
    """Refuses to resume into finished runs made with other episode settings."""
    wanted = _episode_settings(config)
    for job in jobs:
        folder = job.folder(out)
        if finished_metrics(folder) is None:
            continue
        try:
            stored = json.loads((folder / "config.json").read_text())["episode"]
        except (OSError, ValueError, KeyError):
            stored = None
        if stored != wanted:
            raise UserInputError(
                f"{str(folder)!r} holds a finished run made with other episode settings "
                "(time limit, profile, lidar, ...); resuming would mix the two in one table. "
                "Use another --out, or delete that sweep's runs/ to start it afresh.")


def episode_failure(job: Job, exc: BaseException) -> dict[str, Any]:
    """The record of an episode that raised ``exc`` (logged here), for ``failed.json``."""
    if isinstance(exc, UserInputError):  # Its message says it all.
        log.error("episode %s/%s/seed%d failed: %s", job.label, job.explorer, job.seed, exc)
    else:
        log.error("episode %s failed", job, exc_info=exc)
    return {"scene": job.label, "explorer": job.explorer, "seed": job.seed,
            "end_reason": "error", "error": f"{type(exc).__name__}: {exc}"}


def write_failure(folder: Path, failure: dict[str, Any]) -> None:
    """Files a failed episode's record beside its (absent) run folder: ``seedN.failed.json``."""
    folder.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(folder.parent / f"{folder.name}.failed.json",
                      json.dumps(failure, indent=2) + "\n")


def run_job(job: Job, folder: Path, config: EpisodeConfig, mcap: bool | str,
            scene: SceneFiles | None = None, spec: str | None = None,
            command: str | None = None) -> dict[str, Any]:
    """Runs ``job``'s episode into the run folder ``folder``; its metrics, or its failure
    record (:func:`episode_failure`) if it raised. ``scene`` and ``spec`` replace the job's
    own (a Ray worker's copies of its files); ``command`` (the sweep's) goes in its
    ``config.json``."""
    try:
        scene = scene or resolve_scene(job.scene)
        spec = spec or job.spec
        label, starts, team = job.explorer, None, None
        if job.robots > 1:
            label = team_explorers(spec or job.explorer, job.robots)[1]
            starts = team_starts(scene, job.placement, job.robots, poses=False)
            team = TeamConfig(unknown_starts=job.unknown_starts)
        metrics = write_run(folder, scene, label, job.seed, config, mcap, spec=spec,
                            command=command, robots=job.robots, starts=starts,
                            team_config=team)
    except Exception as exc:  # noqa: BLE001 - one broken episode must not end the sweep
        return episode_failure(job, exc)
    metrics["scene"] = job.label
    return metrics


def file_results(out: Path, results: Iterable[tuple[Any, dict[str, Any], Bundle]]
                 ) -> Iterator[dict[str, Any]]:
    """Writes episodes that ran elsewhere (``(job, metrics or failure record, run folder's
    files)``, as :func:`mjexplore.eval.remote.run_remote` yields them) as run folders under
    ``out`` (atomically) or failure records; yields each one's metrics or failure record."""
    for job, metrics, files in results:
        folder = job.folder(out)
        if metrics.get("end_reason") == "error":
            write_failure(folder, metrics)
        else:
            with atomic_directory(folder, "metrics.json") as tmp:
                write_files(tmp, files)
        yield metrics


def sweep_history(out: Path) -> list[dict[str, Any]]:
    """The plans (command, revision, scenes, explorers, specs, seeds) of every earlier start
    of the sweep in ``out``, oldest first, from its ``sweep.json`` (a sweep.json written
    before the history was kept counts as one start)."""
    try:
        info = json.loads((out / "sweep.json").read_text())
    except (OSError, ValueError):
        return []
    if not isinstance(info, dict):
        return []
    return info.get("history") or [{k: v for k, v in info.items() if k != "history"}]


def record_start(out: Path, plan: dict[str, Any]) -> None:
    """Writes ``OUT/sweep.json``: this start's ``plan`` (its command, revision, scenes,
    methods and seeds) and the ``history`` of every start's, this one last."""
    write_text_atomic(out / "sweep.json", json.dumps(
        {**plan, "history": sweep_history(out) + [plan]}, indent=2) + "\n")


def run_sweep(scenes: list[str], explorers: list[str], seeds: list[int], out: Path,
              config: EpisodeConfig, workers: int = 2, mcap: bool | str = False,
              progress: bool = True, command: str | None = None,
              ray_address: str | None = None) -> list[dict[str, Any]]:
    """Runs (or resumes) a sweep and writes its summary; returns every episode's metrics.

    ``explorers`` are method specs (:func:`mjexplore.eval.methods.parse_method`); each
    one's runs are filed under its run label.

    ``mcap``: False for no MCAPs, True or a profile (``"foxglove"``, ``"ros2"``) for one per
    episode (see :func:`mjexplore.eval.run.write_run`).

    ``command`` (the command line that started the sweep) is kept in ``OUT/sweep.json`` with
    the code revision and the plan, for the reports made from the sweep; ``history`` there
    keeps every earlier start's, so that runs made by an earlier command of the same
    folder are not credited to the last one.

    ``progress``: a bar of finished episodes on a terminal, a line per episode elsewhere
    (:class:`~mjexplore.io.progress.Progress`); False shows nothing.

    ``ray_address``: run the episodes as Ray tasks (:mod:`mjexplore.eval.remote`) on the
    cluster there ('local': a Ray instance on this machine with ``workers`` CPUs) instead
    of ``workers`` processes; the run folders are the same.

    Raises:
        UserInputError: a bad scene or explorer spec, or a learned explorer's weights that
            are missing, damaged or of another kind (checked here, before any episode).
    """
    for scene in scenes:
        compile_scene(resolve_scene(scene))  # Fail early, in the parent, on a bad scene.
    labels: dict[str, str] = {}
    for scene in scenes:
        other = labels.setdefault(scene_label(scene), scene)
        if other != scene:
            raise UserInputError(
                f"scenes {other!r} and {scene!r} would share the run folders "
                f"runs/{scene_label(scene)}/: give scene folders or files with distinct names.")
    specs = [parse_method(e) for e in explorers]
    for spec in specs:
        if spec.method in LEARNED:
            spec.build()  # Fail early, in the parent: the weights are read and checked.
    jobs = [Job(s, spec.label, seed, spec.text) for s in scenes for spec in specs
            for seed in seeds]
    refuse_foreign_files(out, SWEEP_OUTPUTS, "a bench sweep")
    check_settings(jobs, out, config)
    out.mkdir(parents=True, exist_ok=True)
    record_start(out, {"command": command, "git_revision": git_revision(), "scenes": scenes,
                       "explorers": [spec.label for spec in specs],
                       "specs": [spec.text for spec in specs], "seeds": seeds})
    results = run_jobs(jobs, out, functools.partial(run_job, config=config, mcap=mcap,
                                                     command=command),
                       episode_failure, workers, ray_address, progress)
    write_summary(out, jobs)
    return results


def _run_here(args: tuple[Callable[..., dict[str, Any]], Any, Path]) -> dict[str, Any]:
    """One job in this process or a pool's worker: its metrics or filed failure record."""
    run, job, out = args
    metrics = run(job, job.folder(out))
    if metrics.get("end_reason") == "error":
        write_failure(job.folder(out), metrics)
    return metrics


def run_jobs(jobs: list[Any], out: Path, run: Callable[..., dict[str, Any]],
             failure: Callable[[Any, BaseException], dict[str, Any]], workers: int,
             ray_address: str | None, progress: bool) -> list[dict[str, Any]]:
    """Runs the jobs of a sweep whose run folder is not finished, and returns every job's
    metrics or failure record (the finished ones' as they were).

    Args:
        jobs: Jobs with ``folder(out)`` (their run folder) and ``scene``.
        out: The sweep folder.
        run: ``run(job, folder, scene=None, spec=None)`` runs one job into ``folder`` and
            returns its metrics, or its failure record if it raised (a ``functools.partial``
            of a module-level function: it is sent to worker processes or Ray tasks).
        failure: ``failure(job, error)``, the record of a Ray task that did not return.
        workers: Processes (one thread each: :func:`init_episode_worker`), or a local Ray
            instance's CPUs.
        ray_address: Run as Ray tasks there (:mod:`mjexplore.eval.remote`); None: processes.
        progress: A bar of finished episodes on a terminal, a line per episode elsewhere.
    """
    earlier = {job: finished_metrics(job.folder(out)) for job in jobs}
    results = [m for m in earlier.values() if m is not None]
    todo = [job for job, m in earlier.items() if m is None]
    with (Progress(len(jobs), "bench", "episodes", enabled=progress, every=0) as bar,
          contextlib.ExitStack() as stack):
        if results:
            bar.update(len(results), detail=f"{len(results)} finished earlier")
        if ray_address is not None:
            from mjexplore.eval.remote import run_remote

            finished = file_results(out, run_remote(todo, run, failure, ray_address, workers))
        elif workers <= 1:
            finished = map(_run_here, [(run, job, out) for job in todo])
        else:
            ctx = multiprocessing.get_context("spawn")
            pool = stack.enter_context(ctx.Pool(workers, initializer=init_episode_worker))
            finished = pool.imap_unordered(_run_here, [(run, job, out) for job in todo])
        for metrics in finished:
            results.append(metrics)
            bar.update(detail=_episode_note(metrics))
    return results


def _episode_note(metrics: dict[str, Any]) -> str:
    """The last finished episode, for the progress display."""
    where = f"{metrics.get('scene')}/{metrics.get('explorer')}/seed{metrics.get('seed')}"
    if metrics.get("end_reason") == "error":
        return f"last {where}: failed"
    return (f"last {where}: {metrics.get('end_reason')} at "
            f"{metrics.get('exploration_time_s', 0):.0f} s")


def read_ratio_curve(folder: Path) -> np.ndarray:
    """A run folder's exploration ratio as (N, 2) rows of (t s, ratio)."""
    return np.loadtxt(folder / "ratio.csv", delimiter=",", skiprows=1, ndmin=2)


def read_kinematics(folder: Path) -> KinematicsLog:
    """A run folder's logged kinematics (``kinematics.csv``)."""
    table = np.loadtxt(folder / "kinematics.csv", delimiter=",", skiprows=1, ndmin=2)
    return KinematicsLog(t=table[:, 0], linear_velocity=table[:, 1],
                         angular_velocity=table[:, 2], linear_acceleration=table[:, 3],
                         angular_acceleration=table[:, 4], cmd_linear=table[:, 5],
                         cmd_angular=table[:, 6], pose=table[:, 7:10], odom_pose=table[:, 10:13])


def format_mean_std(values: list, digits: int | None = None) -> str:
    """``mean +- std`` of the values that are not None, with ``(k/n)`` when some are None;
    to ``digits`` decimals (None: 3 when every value is below 10, else 1)."""
    vals = [v for v in values if v is not None]
    if not vals:
        return "-"
    if digits is None:
        digits = 3 if max(abs(v) for v in vals) < 10 else 1
    text = f"{np.mean(vals):.{digits}f} +- {np.std(vals):.{digits}f}"
    return text + (f" ({len(vals)}/{len(values)})" if len(vals) < len(values) else "")


def write_summary(out: Path, jobs: list[Job]) -> None:
    """Writes the tables and figures of the finished runs among ``jobs``."""
    by_scene: dict[str, dict[str, list[Path]]] = {}
    finished: dict[Path, dict[str, Any]] = {}
    for job in jobs:
        folder = job.folder(out)
        metrics = finished_metrics(folder)
        if metrics is not None:
            finished[folder] = metrics
            by_scene.setdefault(job.label, {}).setdefault(job.explorer, []).append(folder)
    header, rows = summary_table(
        {(scene, method): [finished[f] for f in folders]
         for scene, methods in by_scene.items() for method, folders in methods.items()})
    for scene, methods in by_scene.items():
        ratio_figure({m: [read_ratio_curve(f) for f in fs] for m, fs in methods.items()},
                     out / f"ratio_{scene}.png", f"{scene}: exploration ratio over time")
        kinematics_figure({m: [read_kinematics(f) for f in fs] for m, fs in methods.items()},
                          out / f"kinematics_{scene}.png", f"{scene}: kinematics")
    buf = io.StringIO()
    csv.writer(buf).writerows([header] + rows)
    write_text_atomic(out / "results.csv", buf.getvalue())
    write_text_atomic(out / "results.md", markdown_table(header, rows) + "\n\n" +
                      MEAN_STD_NOTE + "\n" + failed_note(out, jobs))


MEAN_STD_NOTE = "Mean +- std over runs; (k/n) where only k of n runs reached the level."


def failed_note(out: Path, jobs: list[Any]) -> str:
    """The line under a sweep's table that lists its failed episodes ('' if none)."""
    failed = [job for job in jobs if finished_metrics(job.folder(out)) is None and
              job.folder(out).with_name(job.folder(out).name + ".failed.json").is_file()]
    if not failed:
        return ""
    return ("\nFailed episodes (see runs/.../seedN.failed.json; a re-run retries them): " +
            ", ".join(job.folder(out).relative_to(out / "runs").as_posix() for job in failed)
            + "\n")


def summary_table(groups: dict[tuple[str, str], list[dict[str, Any]]]
                  ) -> tuple[list[str], list[list[Any]]]:
    """Table-1 header and rows (scene, method, runs, explored, then mean +- std of each of
    ``METRICS``) from each (scene, method)'s episode metrics, in the order given; runs
    among people add their contacts (summed), least gap (the least) and time stood still."""
    among_people = any(m.get("people") for ms in groups.values() for m in ms)
    header = ["scene", "method", "runs", "explored"] + [label for _, label in METRICS]
    if among_people:
        header += ["people contacts", "least gap (m)", "stood still (s)"]
    rows = []
    for (scene, method), ms in groups.items():
        explored = sum(m["end_reason"] == "explored" for m in ms)
        row = [scene, method, len(ms), explored] + \
            [format_mean_std([m.get(key) for m in ms]) for key, _ in METRICS]
        if among_people:
            gaps = [m["people_min_distance_m"] for m in ms
                    if m.get("people_min_distance_m") is not None]
            row += [sum(int(m.get("people_collisions", 0)) for m in ms),
                    f"{min(gaps):.3f}" if gaps else "-",
                    format_mean_std([m.get("time_stopped_s") for m in ms], digits=1)]
        rows.append(row)
    return header, rows


def markdown_table(header: list[str], rows: list[list[Any]]) -> str:
    """A GitHub-flavoured markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)
