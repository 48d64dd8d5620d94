"""The classic explorers and the ground-truth oracle, behind the episode's explorer interface
(:class:`~mjexplore.episode.explorer.Explorer`: state in, goal out).

The learned explorers (``gvn``, ``cnn``) sit beside the policies they run, in
:mod:`mjexplore.policies`; :mod:`mjexplore.eval.methods` names every method.
"""

from __future__ import annotations

import importlib

from mjexplore.episode.explorer import ExplorationState, Explorer
from mjexplore.errors import UserInputError

# name -> (module, class[, constructor keyword arguments]); modules are imported on first
# use (the oracle's and the tour planner's solvers are heavy to import).
CLASSIC: dict[str, tuple] = {
    "nearest": ("mjexplore.episode.nearest", "NearestFrontier"),
    "pocket_nearest": ("mjexplore.explorers.pocket_nearest", "PocketNearest"),
    "distance_advantage": ("mjexplore.explorers.distance_advantage", "DistanceAdvantage"),
    "pocket_advantage": ("mjexplore.explorers.distance_advantage", "DistanceAdvantage",
                         {"pocket_m": 50.0}),
    "explore_lite": ("mjexplore.explorers.explore_lite", "ExploreLite"),
    "frontier_tsp": ("mjexplore.explorers.frontier_tsp", "FrontierTsp"),
    "rrt": ("mjexplore.explorers.rrt", "RRTExplorer"),
    "potential": ("mjexplore.explorers.potential", "PotentialField"),
    "oracle": ("mjexplore.explorers.oracle", "OracleExplorer"),
    "pocket_truth": ("mjexplore.explorers.pocket_nearest", "TruePocketNearest"),
    "oracle_2m": ("mjexplore.explorers.map_planner", "HorizonOracle", {"horizon": 2.0}),
    "oracle_5m": ("mjexplore.explorers.map_planner", "HorizonOracle", {"horizon": 5.0}),
    "oracle_10m": ("mjexplore.explorers.map_planner", "HorizonOracle", {"horizon": 10.0}),
    "predicted_tour": ("mjexplore.explorers.predicted_tour", "PredictedTour"),
    "predicted_tour_inpainting": ("mjexplore.explorers.predicted_tour", "PredictedTour",
                                  {"source": "inpainting"}),
    "predicted_tour_truth": ("mjexplore.explorers.predicted_tour", "PredictedTour",
                             {"source": "truth"}),
    "predicted_plan": ("mjexplore.explorers.predicted_tour", "PredictedPlan"),
    "predicted_plan_inpainting": ("mjexplore.explorers.predicted_tour", "PredictedPlan",
                                  {"source": "inpainting"}),
    "predicted_plan_truth": ("mjexplore.explorers.predicted_tour", "PredictedPlan",
                             {"source": "truth"}),
    "predicted_drive": ("mjexplore.explorers.predicted_tour", "PredictedDrive"),
    "predicted_drive_inpainting": ("mjexplore.explorers.predicted_tour", "PredictedDrive",
                                   {"source": "inpainting"}),
    "predicted_drive_truth": ("mjexplore.explorers.predicted_tour", "PredictedDrive",
                              {"source": "truth"}),
    "pocket_predicted": ("mjexplore.explorers.predicted_tour", "PredictedPocketNearest"),
    "pocket_predicted_inpainting": ("mjexplore.explorers.predicted_tour",
                                    "PredictedPocketNearest", {"source": "inpainting"}),
}


def explorer_class(name: str) -> type:
    """The class of the classic explorer ``name``.

    Raises:
        UserInputError: unknown name.
    """
    if name not in CLASSIC:
        raise UserInputError(f"unknown explorer {name!r}: use one of {', '.join(CLASSIC)}.")
    module, cls = CLASSIC[name][:2]
    return getattr(importlib.import_module(module), cls)


def make_explorer(name: str, **kwargs) -> Explorer:
    """A classic explorer by name, with its constructor's keyword arguments.

    Raises:
        UserInputError: unknown name.
    """
    preset = CLASSIC[name][2] if name in CLASSIC and len(CLASSIC[name]) > 2 else {}
    return explorer_class(name)(**{**preset, **kwargs})


__all__ = ["CLASSIC", "ExplorationState", "Explorer", "explorer_class", "make_explorer"]
