"""Sweeps of team episodes (``bench --robots N``), with the single robot's time beside.

Every scene x start placement x team method x seed runs as a team episode
(:func:`~mjexplore.eval.run.write_run`) into
``OUT/runs/SCENE/PLACEMENT/METHOD/seedK`` (``PLACEMENT``: ``close`` or ``far``, Explore-Bench's
on its maps, or ``drawn``: robot 0 at the scene's start, the others drawn around it); each
scene and seed also runs the single robot with ``single`` (default ``nearest``) into
``OUT/runs/SCENE/single/METHOD/seedK``. Finished runs are kept (an interrupted sweep resumes).
``results.md`` and ``results.csv`` hold, per scene, placement and method: runs, explored,
the team's time to 98.5 % (mean +- std), the same over the single robot's of the same seeds
(mean of the per-seed ratios), time to 90 %, overlap ratio, summed and longest path, and
robot-robot collisions.
"""

from __future__ import annotations

import csv
import functools
import io
from pathlib import Path
from typing import Any

import numpy as np

from mjexplore.episode import EpisodeConfig
from mjexplore.errors import UserInputError
from mjexplore.eval.placements import DRAWN, check_placements, team_starts
from mjexplore.eval.sweep import (
    SWEEP_OUTPUTS,
    Job,
    check_settings,
    episode_failure,
    failed_note,
    finished_metrics,
    format_mean_std,
    markdown_table,
    record_start,
    run_job,
    run_jobs,
)
from mjexplore.io.atomic import refuse_foreign_files, write_text_atomic
from mjexplore.io.provenance import git_revision
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.team import check_starts, draw_starts

SINGLE = "single"  # The placement the single-robot baseline's runs are filed under.


def team_jobs(scenes: list[str], methods: list[str], robots: int, placements: list[str],
              seeds: list[int], single: str | None = "nearest",
              unknown_starts: bool = False) -> list[Job]:
    """The jobs of a team sweep, the single-robot baseline's first (placement 'single')."""
    jobs = []
    if single:
        jobs += [Job(s, single, k, single, SINGLE) for s in scenes for k in seeds]
    jobs += [Job(s, m + ("+unknown" if unknown_starts else ""), k, m, p, robots, unknown_starts)
             for s in scenes for p in placements for m in methods for k in seeds]
    return jobs


def run_team_sweep(scenes: list[str], methods: list[str], robots: int, placements: list[str],
                   seeds: list[int], out: Path, config: EpisodeConfig, workers: int = 1,
                   single: str | None = "nearest", unknown_starts: bool = False,
                   ray_address: str | None = None, progress: bool = True,
                   command: str | None = None) -> list[dict[str, Any]]:
    """Runs (or resumes) a team sweep and writes its summary; returns every episode's
    metrics or failure record (``unknown_starts``: the teams merge their maps, as
    ``TeamConfig`` says). Resuming, settings, failures (``seedN.failed.json``),
    ``sweep.json``, progress, ``workers`` and ``ray_address`` as in
    :func:`~mjexplore.eval.sweep.run_sweep`, which runs its jobs the same way.

    Raises:
        UserInputError: an unknown placement, a placement a scene does not define, or one
            whose starts are not free, or more robots than fit around a scene's start for
            ``drawn`` (checked before anything runs).
    """
    if robots < 2:
        raise UserInputError("a team sweep needs --robots 2 or more.")
    check_placements(placements)
    for name in scenes:
        scene = resolve_scene(name)
        for placement in placements:
            starts = team_starts(scene, placement, robots, poses=False)
            if scene.ground_truth is None:
                continue  # Its episodes say so.
            if starts is None:  # Drawn around the scene's start (each seed's jitters).
                draw_starts(scene.ground_truth, scene.start, robots,
                            np.random.default_rng([0, robots]))
            else:
                check_starts(scene.ground_truth, starts)
    jobs = team_jobs(scenes, methods, robots, placements, seeds, single, unknown_starts)
    refuse_foreign_files(out, SWEEP_OUTPUTS, "a bench sweep")
    check_settings(jobs, out, config)
    out.mkdir(parents=True, exist_ok=True)
    record_start(out, {"command": command, "git_revision": git_revision(), "kind": "team",
                       "scenes": scenes, "methods": methods, "robots": robots,
                       "placements": placements, "single": single,
                       "unknown_starts": unknown_starts, "seeds": seeds})
    results = run_jobs(jobs, out, functools.partial(run_job, config=config, mcap=False,
                                                     command=command),
                       episode_failure, workers, ray_address, progress)
    write_team_summary(out, jobs)
    return results


def _merge_cells(ms: list[dict[str, Any]]) -> list[str]:
    """The summary's merge columns: when the teams' maps were merged (mean +- std, with
    how many merged), and the largest merge error (metres, degrees); '-' for known starts."""
    if not any(m.get("unknown_starts") for m in ms):
        return ["-", "-"]
    errors = [(m["merge_error_m"], m["merge_error_deg"]) for m in ms
              if m.get("merge_error_m") is not None]
    worst = (f"{max(e[0] for e in errors):.3f}, {max(e[1] for e in errors):.2f}"
             if errors else "-")
    return [format_mean_std([m.get("merge_time_s") for m in ms]), worst]


def team_table(single: dict[tuple[str, int], dict[str, Any]],
               groups: dict[tuple[str, str, str, int], list[tuple[int, dict[str, Any]]]]
               ) -> tuple[list[str], list[list[Any]]]:
    """The team sweep's table: per scene the single robot's row, then one per (placement,
    method, robots) group.

    Args:
        single: (scene, seed) -> the single robot's metrics.
        groups: (scene, placement, method, robots) -> (seed, metrics) of each run.

    Returns:
        The header and the rows.
    """
    header = ["scene", "placement", "method", "robots", "runs", "explored", "T98.5 (s)",
              "x single", "T90 (s)", "overlap", "path (m)", "longest path (m)",
              "robot collisions", "merged at (s)", "merge error (m, deg)"]
    rows = []
    scenes = sorted({k[0] for k in groups} | {k[0] for k in single})
    for scene in scenes:
        seeds = [s for (sc, s) in single if sc == scene]
        if seeds:
            ms = [single[(scene, s)] for s in seeds]
            rows.append([scene, "-", f"single {ms[0].get('explorer', '')}", 1, len(ms),
                         sum(m["end_reason"] == "explored" for m in ms),
                         format_mean_std([m.get("t985_s") for m in ms]), "1", "-", "-",
                         format_mean_std([m.get("path_length_m") for m in ms]), "-", "-",
                         "-", "-"])
        for key in sorted(k for k in groups if k[0] == scene):
            runs = groups[key]
            ms = [m for _, m in runs]
            rows.append([scene, key[1], key[2], key[3], len(ms),
                         sum(m["end_reason"] == "explored" for m in ms),
                         format_mean_std([m.get("t985_s") for m in ms]),
                         _cell(single_ratios(single, scene, runs)),
                         format_mean_std([m.get("t90_s") for m in ms]),
                         format_mean_std([m.get("overlap_ratio") for m in ms]),
                         format_mean_std([m.get("path_length_m") for m in ms]),
                         format_mean_std([m.get("max_path_length_m") for m in ms]),
                         format_mean_std([m.get("robot_collisions") for m in ms]),
                         *_merge_cells(ms)])
    return header, rows


def single_ratios(single: dict[tuple[str, int], dict[str, Any]], scene: str,
                  runs: list[tuple[int, dict[str, Any]]]) -> list[float]:
    """Each run's time to 98.5 % over the single robot's on the same scene and seed (where
    both reached it)."""
    return [m["t985_s"] / single[(scene, s)]["t985_s"] for s, m in runs
            if m.get("t985_s") and (scene, s) in single and single[(scene, s)].get("t985_s")]


def _cell(ratios: list[float]) -> str:
    return f"{np.mean(ratios):.3f}" if ratios else "-"


TABLE_NOTE = ("Mean +- std over runs; (k/n) where only k of n runs reached the level. "
              "'x single': the team's time to 98.5 % over the single robot's on the same "
              "scene and seed, averaged over the seeds where both reached it. Merge columns "
              "(unknown start poses): when the last robot's map was merged into the team's, "
              "and the largest error of an estimated start pose (translation, rotation).")


def write_team_summary(out: Path, jobs: list[Job]) -> None:
    """``results.md`` and ``results.csv`` of the finished runs among ``jobs``."""
    single: dict[tuple[str, int], dict[str, Any]] = {}
    groups: dict[tuple[str, str, str, int], list[tuple[int, dict[str, Any]]]] = {}
    for job in jobs:
        metrics = finished_metrics(job.folder(out))
        if metrics is None:
            continue
        if job.robots == 1:
            single[(job.label, job.seed)] = metrics
        else:
            key = (job.label, str(job.placement), job.explorer, job.robots)
            groups.setdefault(key, []).append((job.seed, metrics))
    header, rows = team_table(single, groups)
    buf = io.StringIO()
    csv.writer(buf).writerows([header] + rows)
    write_text_atomic(out / "results.csv", buf.getvalue())
    write_text_atomic(out / "results.md", markdown_table(header, rows) + "\n\n" +
                      TABLE_NOTE + "\n" + failed_note(out, jobs))


__all__ = ["DRAWN", "SINGLE", "TABLE_NOTE", "run_team_sweep", "single_ratios", "team_jobs",
           "team_table", "write_team_summary"]
