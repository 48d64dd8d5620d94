"""Building the world a robot runs in, by ``SimConfig.dynamics``.

* 'physics': MuJoCo contact dynamics (:class:`~mjexplore.sim.simulator.Simulator`);
* 'kinematic': MuJoCo for the lidar, the body moved kinematically (the same class);
* 'grid': no MuJoCo, the lidar cast on the ground-truth grid
  (:class:`~mjexplore.sim.grid_world.GridWorld`).

All three have the same interface (``reset``, ``command``, ``step``, ``pose``, ``odom_pose``,
``latest_scan``, ``kinematics()``, ...).
"""

from __future__ import annotations

import os

from mjexplore.scenes.scene import SceneFiles
from mjexplore.sim.grid_world import GridWorld
from mjexplore.sim.simulator import SimConfig, Simulator

World = Simulator | GridWorld


def make_world(scene: str | os.PathLike | SceneFiles, config: SimConfig | None = None,
               starts: list | None = None) -> World:
    """The world ``config.dynamics`` asks for, in ``scene`` (a scene folder, its
    ``scene.xml`` or :class:`SceneFiles`), reset to the scene's start, or with ``starts``
    a team's world with one robot at each (its robots in ``robots``, stepped together by
    ``step_all``).

    Raises:
        UserInputError: the scene cannot be loaded, or the grid or kinematic world lacks
            its ground truth.
    """
    config = config or SimConfig()
    if config.dynamics == "grid":
        return GridWorld(scene, config, starts)
    return Simulator(scene, config, starts)
