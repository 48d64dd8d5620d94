"""Gymnasium environments of the exploration decision process.

Registered ids (``gymnasium.make(id, **overrides)``; overrides are :class:`EnvConfig`
fields):

* ``mjexplore/Explore-LoopWithCorridor-v0``, ``mjexplore/Explore-Maze-v0``,
  ``mjexplore/Explore-Office-v0``: the paper's three evaluation scenes, full physics.
* ``mjexplore/Explore-Lobby-v0``: the real-robot lobby with the ``real`` profile.
* ``mjexplore/Explore-Train-v0``: the nine canonical training scenes, one per reset.
* ``mjexplore/Explore-Procedural-v0``: a fresh generated layout per reset, in the
  kinematic training mode.
* ``mjexplore/ExploreGrid-Procedural-v0``, ``mjexplore/ExploreGrid-Office-v0``: the same with
  the grid decision space of the CNN baseline (map image in, coarse goal cell out).
"""

from __future__ import annotations

import gymnasium as gym

from mjexplore.envs.decisions import GridConfig, GridDecisions, TerDecisions, ter_action_mask
from mjexplore.envs.exploration import (
    EnvConfig,
    ExplorationEnv,
    NodeGoals,
    ProceduralScenes,
    RewardConfig,
)
from mjexplore.envs.observation import ObservationConfig, TerMemory

__all__ = ["EnvConfig", "ExplorationEnv", "GridConfig", "GridDecisions", "NodeGoals",
           "ObservationConfig", "ProceduralScenes", "RewardConfig", "TerDecisions", "TerMemory",
           "ENV_IDS", "ter_action_mask"]

ENTRY_POINT = "mjexplore.envs.exploration:ExplorationEnv"


def _configs() -> dict[str, EnvConfig]:
    from mjexplore.episode import EpisodeConfig
    from mjexplore.scenes.canonical import canonical_names
    from mjexplore.sim.simulator import SimConfig

    kinematic = EpisodeConfig(sim=SimConfig(dynamics="kinematic"))
    return {
        "mjexplore/Explore-LoopWithCorridor-v0": EnvConfig(scenes=("loop_with_corridor",)),
        "mjexplore/Explore-Maze-v0": EnvConfig(scenes=("maze",)),
        "mjexplore/Explore-Office-v0": EnvConfig(scenes=("office",)),
        "mjexplore/Explore-Lobby-v0": EnvConfig(
            scenes=("lobby",), episode=EpisodeConfig(sim=SimConfig(profile="real"))),
        "mjexplore/Explore-Train-v0": EnvConfig(scenes=tuple(canonical_names("train")),
                                                episode=kinematic),
        "mjexplore/Explore-Procedural-v0": EnvConfig(procedural=ProceduralScenes(),
                                                     episode=kinematic),
        "mjexplore/ExploreGrid-Procedural-v0": EnvConfig(procedural=ProceduralScenes(),
                                                         episode=kinematic, decisions="grid"),
        "mjexplore/ExploreGrid-Office-v0": EnvConfig(scenes=("office",), decisions="grid"),
    }


ENV_IDS: tuple[str, ...] = tuple(_configs())

for _id, _config in _configs().items():
    if _id not in gym.registry:
        gym.register(id=_id, entry_point=ENTRY_POINT, kwargs={"config": _config})
