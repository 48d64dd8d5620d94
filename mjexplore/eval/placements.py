"""Where a team starts: ``--starts`` of ``explore --robots N`` and ``bench --robots N``.

A placement is Explore-Bench's 'close' or 'far' on its own maps, 'drawn' (robot 0 at the
scene's start, the others drawn 1-3 m around it from the seed), or for ``explore`` one pose
per robot. The team's run folder is :func:`~mjexplore.eval.run.write_run`'s.
"""

from __future__ import annotations

from pathlib import Path

from mjexplore.errors import UserInputError
from mjexplore.scenes.scene import SceneFiles
from mjexplore.scenes.team import (
    EXPLORE_BENCH_TEAM_STARTS,
    PLACEMENTS,
    explore_bench_starts,
    parse_starts,
)

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


__all__ = ["DRAWN", "check_placements", "team_starts"]
