"""The 3D panel: the MuJoCo scene from an oblique camera that follows the robot, with the
driven trajectory drawn on the floor."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from mjexplore.render.gl import make_renderer

TRAJECTORY_RGBA = np.array([0.1, 0.35, 0.9, 1.0], np.float32)
MAX_SEGMENTS = 2000


@dataclasses.dataclass(frozen=True, kw_only=True)
class CameraConfig:
    """Oblique follow camera.

    Attributes:
        distance: From the robot, metres.
        elevation: Degrees (negative looks down).
        azimuth: Degrees in the ``map`` frame; None turns with the robot (a chase camera,
            behind it).
        wall_alpha: Opacity of the walls (3 m tall: opaque walls would hide the robot in
            narrow corridors from any oblique view).
    """

    distance: float = 8.0
    elevation: float = -72.0
    azimuth: float | None = 90.0
    wall_alpha: float = 0.55


class SceneView:
    """Renders the model's current state.

    Args:
        model: The scene's model (rendering settings and wall colours on it are changed;
            physics is not affected).
        width, height: Pixels.
        camera: Camera settings.
        fast: Fast rendering settings (see :func:`make_renderer`).
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int,
                 camera: CameraConfig | None = None, fast: bool = True) -> None:
        self.model = model
        self.renderer = make_renderer(model, width, height, fast=fast)
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.config = camera or CameraConfig()
        self._opt = mujoco.MjvOption()
        walls = (model.geom_bodyid == 0) & (model.geom_type == mujoco.mjtGeom.mjGEOM_BOX)
        model.geom_rgba[walls, 3] = self.config.wall_alpha
        if model.nmat:
            model.mat_rgba[:, 3] = np.where(np.isin(np.arange(model.nmat),
                                                    model.geom_matid[walls]),
                                            self.config.wall_alpha, model.mat_rgba[:, 3])

    def render(self, data: mujoco.MjData, robot_pose: np.ndarray,
               trajectory: np.ndarray | None = None) -> np.ndarray:
        """(height, width, 3) RGB uint8 of the scene with the robot at ``data``'s state."""
        c = self.config
        x, y, yaw = robot_pose
        self.camera.lookat[:] = (x, y, 0.2)
        self.camera.distance = c.distance
        self.camera.elevation = c.elevation
        self.camera.azimuth = math.degrees(yaw) if c.azimuth is None else c.azimuth
        self.renderer.update_scene(data, self.camera, self._opt)
        if trajectory is not None and len(trajectory) > 1:
            self._draw_trajectory(np.asarray(trajectory, float))
        return self.renderer.render()

    def _draw_trajectory(self, xy: np.ndarray) -> None:
        # Line geoms (a few pixels wide): capsules cost 10x the frame time at this count.
        scene = self.renderer.scene
        keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-9])
        xy = xy[keep]
        step = max(1, int(math.ceil((len(xy) - 1) / MAX_SEGMENTS)))
        pts = xy[::step]
        if (pts[-1] != xy[-1]).any():
            pts = np.vstack([pts, xy[-1]])
        room = scene.maxgeom - scene.ngeom
        pts = pts[-(room + 1):]
        for a, b in zip(pts[:-1], pts[1:]):
            geom = scene.geoms[scene.ngeom]
            mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3),
                                np.zeros(9), TRAJECTORY_RGBA)
            mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_LINE, 4.0,
                                 np.array([a[0], a[1], 0.03]), np.array([b[0], b[1], 0.03]))
            scene.ngeom += 1
