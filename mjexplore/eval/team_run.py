"""The ``explore --robots N`` job: one team episode written to a run folder.

Run folder: ``metrics.json`` (the team's metrics, ``per_robot`` inside), ``config.json``
(resolved settings, start poses and git revision), ``ratio.csv`` (the team's exploration
ratio over simulated time), ``robot_{i}/kinematics.csv`` and ``robot_{i}/coverage.csv``
(what robot i's own scans saw, over time), ``ratio.png`` (the team's ratio and each robot's
coverage), ``map.png`` (final map, every robot's path and goals) and ``episode.mcap``
(every robot's topics under its namespace, :mod:`mjexplore.io.team_mcap`). The folder
appears complete or not at all.

The team's method is a coordinated one (:data:`~mjexplore.explorers.team.TEAM_METHODS`) or
any single-robot method, which then runs as the naive team: each robot with its own
explorer of that method on the shared map.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
from pathlib import Path
from typing import Any, cast

from mjexplore.episode import Episode, EpisodeConfig, Interrupted
from mjexplore.episode.explorer import Explorer
from mjexplore.episode.team import TeamConfig, TeamEpisodeResult
from mjexplore.errors import UserInputError
from mjexplore.eval.methods import parse_method
from mjexplore.eval.progress import EpisodeProgress
from mjexplore.eval.run import Observers
from mjexplore.explorers.team import TEAM_METHODS, make_team_explorers
from mjexplore.io.atomic import atomic_directory, write_bytes_atomic, write_text_atomic
from mjexplore.io.provenance import git_revision
from mjexplore.io.team_mcap import TeamFoxgloveLog
from mjexplore.scenes.scene import SceneFiles
from mjexplore.scenes.team import (
    EXPLORE_BENCH_TEAM_STARTS,
    PLACEMENTS,
    explore_bench_starts,
    parse_starts,
    robot_prefix,
)

ROBOT_COLOURS = ("tab:green", "tab:red", "tab:blue", "tab:orange", "tab:purple", "tab:brown",
                 "tab:pink", "tab:cyan")


def team_explorers(spec: str, n: int) -> tuple[list[Explorer], str]:
    """The ``n`` explorers of a team method spec and the run's label: a coordinated method
    by name, else the naive team of the single-robot method ``spec`` (labelled
    ``naive_LABEL``).

    Raises:
        UserInputError: an unknown method.
    """
    if spec in TEAM_METHODS:
        return make_team_explorers(spec, n), spec
    parsed = parse_method(spec)
    explorers = [parsed.build() for _ in range(n)]
    return explorers, f"naive_{getattr(explorers[0], 'label', parsed.label)}"


# The placement that draws the starts: robot 0 at the scene's start, the others around it.
DRAWN = "drawn"


def team_starts(scene: SceneFiles, text: str | None, n: int,
                poses: bool = True) -> list | None:
    """Start poses from ``--starts``: None (drawn by the episode; ``text`` None or
    ``'drawn'``), Explore-Bench's 'close' or 'far' placement on its own maps (scenes whose
    metadata names one: :func:`~mjexplore.scenes.canonical.resolve_scene` of its YAML), or
    with ``poses`` ``X,Y,YAW;X,Y,YAW;...`` (one per robot).

    Args:
        scene: The scene the team explores.
        text: The ``--starts`` value.
        n: Robots in the team.
        poses: Whether explicit poses are accepted (explore's ``--starts``); without them
            (bench's, a list of placements) the messages offer placements only.

    Raises:
        UserInputError: a placement on another map or for another team size, an unknown
            placement, or a count of poses that is not ``n``.
    """
    if text is None or text == DRAWN:
        return None
    if text in PLACEMENTS:
        name = scene.metadata.get("explore_bench")
        if name not in EXPLORE_BENCH_TEAM_STARTS:
            shown = scene.metadata.get("name", Path(scene.xml).parent.name)
            other = " or give one pose per robot, --starts 'X,Y,YAW;X,Y,YAW'" if poses else ""
            raise UserInputError(
                f"--starts {text}: '{text}' is Explore-Bench's placement, and scene {shown!r} "
                "is not one of its maps (its map_server YAMLs "
                f"{', '.join(EXPLORE_BENCH_TEAM_STARTS)} in a folder named explore_bench, "
                "e.g. ../shared/data/explore_bench/room.yaml): use --starts drawn (robot 0 at "
                f"the scene's start, the others drawn 1-3 m around it){other}.")
        starts = explore_bench_starts(name, text)
        if n != len(starts):
            raise UserInputError(f"Explore-Bench's '{text}' placement is for {len(starts)} "
                                 f"robots, not {n}: use --robots {len(starts)}.")
        return starts
    if not poses or not any(c.isdigit() for c in text):
        raise UserInputError(_not_a_placement(text, poses))
    starts = parse_starts(text)
    if len(starts) != n:
        raise UserInputError(f"--starts gives {len(starts)} poses for {n} robots: give one per "
                             "robot (separated by ';') or set --robots to match.")
    return starts


def _not_a_placement(text: str, poses: bool) -> str:
    """The message for a ``--starts`` that names no placement (``poses``: explore's, which
    also takes poses; else bench's, a comma-separated list of placements)."""
    if poses:
        return (f"--starts {text!r} is neither a placement nor start poses: give close or far "
                "(Explore-Bench's, on its own maps), drawn, or one pose per robot, e.g. "
                "--starts '1,2,0;3,2,1.57'.")
    return (f"--starts {text!r}: bench's --starts takes placements, close or far "
            "(Explore-Bench's, on its own maps) or drawn, comma-separated (e.g. --starts "
            "close,far).")


def check_placements(placements: list[str]) -> None:
    """Refuses a list of bench placements with one that is not close, far or drawn.

    Raises:
        UserInputError: says which placements bench takes.
    """
    if any(p not in (*PLACEMENTS, DRAWN) for p in placements):
        raise UserInputError(_not_a_placement(",".join(placements), poses=False))


class TeamProgress(EpisodeProgress):
    """The progress bar of a team episode: simulated time, the team's ratio, decisions."""

    def _draw(self) -> None:
        episode = self._episode
        self.progress.detail_text = (
            f"ratio {episode.ratio:.1%}, decisions "
            f"{sum(len(a.goals) for a in episode.agents)}")
        self.progress.set(min(episode.time, self.progress.total))

    def on_scan(self, agent, scan) -> None:
        self._episode = agent.episode


def run_team_episode(scene: SceneFiles, spec: str, n: int, seed: int, config: EpisodeConfig,
                     starts: list | None = None, mcap_path: str | os.PathLike | None = None,
                     team_config: TeamConfig | None = None,
                     progress: bool = False) -> tuple[TeamEpisodeResult, str]:
    """Runs one team episode; returns its result and the run's label."""
    explorers, label = team_explorers(spec, n)
    log = None if mcap_path is None else TeamFoxgloveLog(
        mcap_path, [robot_prefix(i).rstrip("/") for i in range(n)])
    observers = Observers(log, TeamProgress(config.max_time) if progress else None)
    try:
        episode = Episode(scene, explorers, seed, config, observers, starts=starts,
                          team_config=team_config)
        result = episode.run()
    finally:
        observers.close()
    return result, label


def _figures(result: TeamEpisodeResult, out: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def save(fig, path):
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
        plt.close(fig)
        write_bytes_atomic(path, buf.getvalue())

    fig, ax = plt.subplots(figsize=(7, 4))
    curve = result.ratio_curve
    ax.plot(curve[:, 0], curve[:, 1], color="black", lw=1.6, label="team")
    for i, c in enumerate(result.robot_curves):
        if len(c):
            ax.plot(c[:, 0], c[:, 1], color=ROBOT_COLOURS[i % len(ROBOT_COLOURS)], lw=1.0,
                    label=f"robot_{i} (own scans)")
    for level in (0.80, 0.90, 0.985):
        ax.axhline(level, color="grey", lw=0.5, ls=":")
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("exploration ratio")
    ax.set_ylim(0, 1.02)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title)
    save(fig, out / "ratio.png")

    import numpy as np

    grid = result.grid
    img = np.full(grid.shape, 0.6)
    img[grid.free] = 1.0
    img[grid.occupied] = 0.0
    x0, y0 = grid.origin[:2]
    w, h = grid.size_m
    fig, ax = plt.subplots(figsize=(8, 8 * h / w + 0.5))
    ax.imshow(img, cmap="gray", origin="lower", extent=(x0, x0 + w, y0, y0 + h), vmin=0, vmax=1)
    for i, (log, goals) in enumerate(zip(result.kinematics, result.goals)):
        colour = ROBOT_COLOURS[i % len(ROBOT_COLOURS)]
        ax.plot(log.pose[:, 0], log.pose[:, 1], color=colour, lw=1.1, label=f"robot_{i}")
        ax.scatter(log.pose[0, 0], log.pose[0, 1], s=40, color=colour, marker="o",
                   edgecolor="black", zorder=4)
        if len(goals):
            ax.scatter(goals[:, 1], goals[:, 2], s=8, color=colour, marker="x", zorder=3)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    save(fig, out / "map.png")


def write_team_run(out_dir: str | os.PathLike, scene: SceneFiles, spec: str, n: int,
                   seed: int, config: EpisodeConfig, starts: list | None = None,
                   mcap: bool = True, team_config: TeamConfig | None = None,
                   progress: bool = False) -> dict[str, Any]:
    """Runs a team episode and writes its run folder atomically; returns the metrics."""
    interrupted = None
    with atomic_directory(out_dir, "metrics.json") as tmp:
        try:
            result, label = run_team_episode(scene, spec, n, seed, config, starts,
                                             tmp / "episode.mcap" if mcap else None,
                                             team_config, progress)
        except Interrupted as exc:  # A team episode's carries a TeamEpisodeResult.
            interrupted, result = exc, cast(TeamEpisodeResult, exc.result)
            label = spec
        name = scene.metadata.get("name", Path(scene.xml).parent.name)
        metrics = {"scene": name, "explorer": label, "seed": seed, **result.metrics}
        write_text_atomic(tmp / "metrics.json", json.dumps(metrics, indent=2) + "\n")
        write_text_atomic(tmp / "config.json", json.dumps({
            "scene": scene.source, "scene_metadata": scene.metadata, "explorer": label,
            "method": spec, "robots": n, "seed": seed,
            "starts": [list(p) for p in result.starts],
            "episode": dataclasses.asdict(config),
            "team": dataclasses.asdict(team_config or TeamConfig()),
            "git_revision": git_revision()}, indent=2, default=str) + "\n")
        write_text_atomic(tmp / "ratio.csv", "t,exploration_ratio\n" + "".join(
            f"{t:.3f},{r:.6f}\n" for t, r in result.ratio_curve))
        for i, (log, curve) in enumerate(zip(result.kinematics, result.robot_curves)):
            folder = tmp / f"robot_{i}"
            folder.mkdir()
            write_text_atomic(folder / "kinematics.csv", log.to_csv())
            write_text_atomic(folder / "coverage.csv", "t,coverage\n" + "".join(
                f"{t:.3f},{r:.6f}\n" for t, r in curve))
        _figures(result, tmp, f"{name} / {label} / {n} robots / seed {seed}")
    if interrupted is not None:
        raise interrupted
    return metrics


__all__ = ["DRAWN", "check_placements", "run_team_episode", "team_explorers", "team_starts",
           "write_team_run"]
