"""A team episode's log that opens in Foxglove: every robot's topics under its namespace.

Topics (Foxglove schemas; log time = simulated time in nanoseconds):
    /robot_{i}/scan        foxglove.LaserScan in ``robot_{i}/base_scan`` (every scan)
    /robot_{i}/pose        foxglove.PoseInFrame: ground-truth pose of its base in ``map``
    /robot_{i}/odom        foxglove.PoseInFrame: its wheel-odometry pose in ``robot_{i}/odom``
    /robot_{i}/goal        foxglove.PoseInFrame: each of its exploration goals in ``map``
    /robot_{i}/kinematics  JSON (mjexplore.Kinematics), as the single robot's /kinematics
    /tf                    foxglove.FrameTransforms: map -> robot_{i}/odom ->
                           robot_{i}/base_link -> robot_{i}/base_scan, at each of its scans
    /map                   foxglove.Grid: the team's shared occupancy map, ``map_period``

The frames follow the single robot's log (:mod:`mjexplore.io.mcap_log`), each robot's
prefixed by its namespace, as ROS multi-robot setups prefix their ``tf`` frames.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import foxglove
import numpy as np
from foxglove.channels import (
    FrameTransformsChannel,
    GridChannel,
    LaserScanChannel,
    PoseInFrameChannel,
)
from foxglove.messages import FrameTransforms, PoseInFrame
from foxglove.messages import LaserScan as FoxgloveLaserScan

from mjexplore.io.mcap_log import (
    KINEMATICS_SCHEMA,
    SCAN_OFFSET,
    FoxgloveEpisodeLog,
    _pose,
    _stamp,
    _transform,
)
from mjexplore.io.stamps import sim_ns

if TYPE_CHECKING:
    from mjexplore.maps import GridMap


def robot_topics(name: str) -> tuple[str, ...]:
    """The topics of the robot namespaced ``name`` (``robot_0``...)."""
    return tuple(f"/{name}/{t}" for t in ("scan", "pose", "odom", "goal", "kinematics"))


class _RobotChannels:
    def __init__(self, name: str, context: foxglove.Context) -> None:
        self.name = name
        self.scan = LaserScanChannel(f"/{name}/scan", context=context)
        self.pose = PoseInFrameChannel(f"/{name}/pose", context=context)
        self.odom = PoseInFrameChannel(f"/{name}/odom", context=context)
        self.goal = PoseInFrameChannel(f"/{name}/goal", context=context)
        self.kinematics = foxglove.Channel(
            f"/{name}/kinematics", message_encoding="json", context=context,
            schema=foxglove.Schema(name="mjexplore.Kinematics", encoding="jsonschema",
                                   data=json.dumps(KINEMATICS_SCHEMA).encode()))
        self.last_kin = 0


class TeamFoxgloveLog:
    """Team episode observer writing an MCAP file (to a temporary name, moved into place
    on :meth:`close`).

    Args:
        path: Destination ``.mcap`` file.
        names: The robots' namespaces, in order (``robot_0``, ...).
        map_period: Seconds of simulated time between /map messages.
    """

    def __init__(self, path: str | os.PathLike, names: list[str],
                 map_period: float = 1.0) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.name}.tmp")
        self.context = foxglove.Context()
        self.writer = foxglove.open_mcap(self._tmp, allow_overwrite=True, context=self.context)
        self.robots = [_RobotChannels(n, self.context) for n in names]
        self.tf = FrameTransformsChannel("/tf", context=self.context)
        self.map = GridChannel("/map", context=self.context)
        self.map_period = map_period
        self._next_map = 0.0
        self._map_logged = -math.inf
        self._last_scan: tuple[float, GridMap] | None = None

    # Observer hooks ---------------------------------------------------------------

    def on_scan(self, agent, scan) -> None:
        index, episode = agent.index, agent.episode
        t = scan.stamp
        ns = sim_ns(t)
        ch = self.robots[index]
        robot = episode.world.robots[index]
        x, y, yaw = (float(v) for v in robot.pose)
        dx, dy, dyaw = (float(v) for v in robot.odom_pose)
        oyaw = yaw - dyaw
        c, s = math.cos(oyaw), math.sin(oyaw)
        map_odom = (x - (c * dx - s * dy), y - (s * dx + c * dy), oyaw)
        name = ch.name
        ch.scan.log(FoxgloveLaserScan(
            timestamp=_stamp(t), frame_id=f"{name}/base_scan", pose=_pose(0.0, 0.0, 0.0),
            start_angle=float(scan.angles[0]), end_angle=float(scan.angles[-1]),
            ranges=scan.ranges.tolist(), intensities=[]), log_time=ns)
        sx, sy, sz = SCAN_OFFSET
        self.tf.log(FrameTransforms(transforms=[
            _transform(t, "map", f"{name}/odom", *map_odom),
            _transform(t, f"{name}/odom", f"{name}/base_link", dx, dy, dyaw),
            _transform(t, f"{name}/base_link", f"{name}/base_scan", sx, sy, 0.0, sz)]),
            log_time=ns)
        ch.pose.log(PoseInFrame(timestamp=_stamp(t), frame_id="map", pose=_pose(x, y, yaw)),
                    log_time=ns)
        ch.odom.log(PoseInFrame(timestamp=_stamp(t), frame_id=f"{name}/odom",
                                pose=_pose(dx, dy, dyaw)), log_time=ns)
        rows = robot.kinematics_rows
        start = max(ch.last_kin, 1)
        if len(rows) > start:
            tt, v, w = rows[start - 1:, 0], rows[start - 1:, 1], rows[start - 1:, 2]
            dt = np.diff(tt)
            for row in np.column_stack([tt[1:], v[1:], w[1:], np.diff(v) / dt,
                                        np.diff(w) / dt]).tolist():
                ch.kinematics.log(dict(zip(("t", "linear_velocity", "angular_velocity",
                                            "linear_acceleration", "angular_acceleration"),
                                           row)), log_time=sim_ns(row[0]))
        ch.last_kin = len(rows)
        if t >= self._next_map - 1e-9:
            self._next_map = t + self.map_period
            self.write_map(t, episode.mapper.grid)
            self._map_logged = t
        self._last_scan = (t, episode.mapper.grid)

    def write_map(self, t: float, grid) -> None:
        """The shared map, as the single robot's log writes its map."""
        # Borrowed, not inherited: it needs only a ``map`` channel, which this log has.
        FoxgloveEpisodeLog.write_map(self, t, grid)  # type: ignore[arg-type]

    def on_goal(self, episode, index: int, t: float, x: float, y: float) -> None:
        del episode
        self.robots[index].goal.log(PoseInFrame(timestamp=_stamp(t), frame_id="map",
                                                pose=_pose(x, y, 0.0)), log_time=sim_ns(t))

    def on_step(self, episode) -> None:
        del episode

    def close(self) -> None:
        """Writes the final map (if newer than the last one written) and finishes the file."""
        if self._last_scan is not None and self._last_scan[0] > self._map_logged:
            self.write_map(*self._last_scan)
        self.writer.close()
        os.replace(self._tmp, self.path)


__all__ = ["TeamFoxgloveLog", "robot_topics"]
