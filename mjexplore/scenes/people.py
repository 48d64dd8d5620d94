"""Pedestrians in a scene's MJCF: the bodies :mod:`mjexplore.sim.people`'s crowd moves."""

from __future__ import annotations

import mujoco

PERSON = "person_{}"  # A pedestrian's body (a mocap body) in a model with people.
PERSON_GROUP = 2  # Rendered; not cast by the lidar's rays (it casts people itself).


def add_people(spec: mujoco.MjSpec, count: int, radius: float, height: float) -> None:
    """Adds ``count`` pedestrians to ``spec``: mocap bodies ``person_{i}`` (placed by the
    simulator), each an upright cylinder of ``radius`` and ``height`` metres that the robots
    touch (MuJoCo contacts) and that renders; the lidar casts them itself
    (:class:`~mjexplore.sim.lidar.Lidar`)."""
    for i in range(count):
        body = spec.worldbody.add_body(name=PERSON.format(i), mocap=True, pos=[0, 0, 0])
        body.add_geom(name=PERSON.format(i), type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                      size=[radius, height / 2, 0], pos=[0, 0, height / 2],
                      group=PERSON_GROUP, rgba=[0.78, 0.16, 0.63, 1.0])


__all__ = ["PERSON", "PERSON_GROUP", "add_people"]
