"""The ``drive`` job: wander through a scene in closed loop and record what happened.

Until the exploration stack exists this is the demo's main job: the reactive
:class:`WanderController` drives the robot at 10 Hz from the latest scan; the run folder
gets the kinematics log, a trajectory picture (ground truth, odometry, last scan) and a
summary with path length, odometry drift, collisions and the real-time factor.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time

import cv2
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import atomic_directory, write_bytes_atomic, write_text_atomic
from mjexplore.maps import GridMap
from mjexplore.navigation.wander import WanderController
from mjexplore.scenes.scene import SceneFiles, encode_png, preview_image
from mjexplore.sim.odometry import odom_in_map
from mjexplore.sim.simulator import SimConfig
from mjexplore.sim.world import make_world


@dataclasses.dataclass(frozen=True, kw_only=True)
class DriveConfig:
    """Settings of a drive run.

    Attributes:
        duration: Simulated seconds to drive.
        control_rate_hz: Controller rate in Hz.
        seed: Seed of the controller's tie-breaking (and the lidar noise).
        sim: Simulator settings (``dynamics`` picks the world, see
            :func:`~mjexplore.sim.world.make_world`).
    """

    duration: float = 120.0
    control_rate_hz: float = 10.0
    seed: int = 0
    sim: SimConfig = dataclasses.field(default_factory=SimConfig)

    def __post_init__(self) -> None:
        if not 0 < self.duration <= 24 * 3600:
            raise UserInputError(f"duration {self.duration} s is out of range: give 0 to 86400 s.")
        if not 0 < self.control_rate_hz <= 100:
            raise UserInputError(f"control rate {self.control_rate_hz} Hz is out of range: "
                                 "give 0 to 100 Hz.")


def trajectory_image(grid: GridMap, truth: np.ndarray, odom: np.ndarray,
                     scan_points: np.ndarray) -> np.ndarray:
    """Ground-truth map with the true path (green), odometry (blue) and scan points (red)."""
    img = preview_image(grid)
    scale = img.shape[1] / grid.shape[1] / grid.resolution

    def pixels(xy: np.ndarray) -> np.ndarray:
        px = (xy[:, 0] - grid.origin[0]) * scale
        py = img.shape[0] - (xy[:, 1] - grid.origin[1]) * scale
        return np.round(np.column_stack([px, py])).astype(np.int32)

    cv2.polylines(img, [pixels(odom)], False, (200, 90, 30), 1, cv2.LINE_AA)
    cv2.polylines(img, [pixels(truth)], False, (40, 160, 40), 2, cv2.LINE_AA)
    for p in pixels(scan_points):
        cv2.circle(img, (int(p[0]), int(p[1])), 1, (30, 30, 220), -1)
    return img


def run_drive(scene: SceneFiles, config: DriveConfig, out_dir: str | os.PathLike) -> dict:
    """Drives the robot through ``scene`` and writes the run folder atomically.

    Returns:
        The summary written to ``summary.json``.
    """
    sim = make_world(scene, config.sim)
    controller = WanderController(rng=np.random.default_rng(config.seed))
    period = 1.0 / config.control_rate_hz
    wall_start = time.perf_counter()
    while sim.time < config.duration - 1e-9:
        v, w = controller(sim.latest_scan, sim.pose)
        sim.command(v, w)
        sim.step(min(period, config.duration - sim.time))
        if not sim.is_upright:
            break
    wall = time.perf_counter() - wall_start
    log = sim.kinematics()
    truth = log.pose
    odom_final = odom_in_map(sim.odom_origin, sim.odom_pose[None])[0]
    scan = sim.latest_scan
    hits = np.isfinite(scan.ranges)
    angles = scan.angles[hits] + scan.pose[2]
    points = scan.pose[:2] + scan.ranges[hits, None] * np.column_stack([np.cos(angles),
                                                                         np.sin(angles)])
    summary = {
        "scene": str(scene.xml),
        "simulated_time_s": round(sim.time, 3),
        "path_length_m": round(log.path_length(), 3),
        "collisions": sim.collisions,
        "final_pose": [round(float(v), 4) for v in sim.pose],
        "odometry_final_pose": [round(float(v), 4) for v in odom_final],
        "odometry_position_error_m": round(float(np.hypot(*(odom_final[:2] - truth[-1, :2]))), 4),
        "max_linear_speed_mps": round(float(np.abs(log.linear_velocity).max()), 4),
        "max_angular_speed_radps": round(float(np.abs(log.angular_velocity).max()), 4),
        "mujoco_warnings": sim.warnings(),
        "upright": sim.is_upright,
        "real_time_factor": round(sim.time / wall, 1),
    }
    resolved = {"drive": dataclasses.asdict(config), "scene": str(scene.xml),
                "scene_metadata": scene.metadata}
    odom_path = odom_in_map(sim.odom_origin, log.odom_pose)
    with atomic_directory(out_dir, "summary.json") as tmp:
        write_text_atomic(tmp / "kinematics.csv", log.to_csv())
        write_text_atomic(tmp / "summary.json", json.dumps(summary, indent=2) + "\n")
        write_text_atomic(tmp / "config.json", json.dumps(resolved, indent=2, default=str) + "\n")
        if scene.ground_truth is not None:
            write_bytes_atomic(tmp / "trajectory.png", encode_png(
                trajectory_image(scene.ground_truth, truth, odom_path, points)))
    return summary


__all__ = ["DriveConfig", "run_drive"]
