"""MCAP logs of episodes that open in Foxglove, stamped with simulated time.

Topics (Foxglove schemas, protobuf encoded by ``foxglove-sdk``):
    /scan        foxglove.LaserScan in ``base_scan`` (every scan)
    /tf          foxglove.FrameTransforms: map->odom, odom->base_link, base_link->base_scan
    /pose        foxglove.PoseInFrame: ground-truth pose of base_link in ``map``
    /odom        foxglove.PoseInFrame: wheel-odometry pose of base_link in ``odom``
    /map         foxglove.Grid: the occupancy map (int8: -1 unknown, 0..100), ``map_period``
    /ter         foxglove.SceneUpdate: TER nodes (spheres, coloured by kind) and edges (lines)
    /goal        foxglove.PoseInFrame: each exploration goal in ``map``
    /kinematics  JSON (mjexplore.Kinematics): linear and angular velocity of base_link and
                 their accelerations (backward differences)
Log time and message timestamps are simulated time in nanoseconds since the episode start.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import foxglove
import numpy as np
from foxglove.channels import (FrameTransformsChannel, GridChannel, LaserScanChannel,
                               PoseInFrameChannel, SceneUpdateChannel)
from foxglove.messages import (Color, FrameTransform, FrameTransforms, Grid, LinePrimitive,
                               LinePrimitiveLineType, PackedElementField,
                               PackedElementFieldNumericType, Point3, Pose, PoseInFrame,
                               Quaternion, SceneEntity, SceneUpdate, SpherePrimitive,
                               Timestamp, Vector2, Vector3)
from foxglove.messages import LaserScan as FoxgloveLaserScan

from mjexplore.robot import TURTLEBOT3_WAFFLE

KINEMATICS_SCHEMA = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in (
        "t", "linear_velocity", "angular_velocity", "linear_acceleration",
        "angular_acceleration")},
}
TOPICS = ("/scan", "/tf", "/pose", "/odom", "/map", "/ter", "/goal", "/kinematics")
_NODE_COLOURS = {0.0: Color(r=0.1, g=0.8, b=0.1, a=1.0), 1.0: Color(r=0.1, g=0.3, b=1.0, a=1.0),
                 -1.0: Color(r=0.9, g=0.2, b=0.2, a=1.0)}


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _stamp(t: float) -> Timestamp:
    ns = _ns(t)
    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _pose(x: float, y: float, yaw: float, z: float = 0.0) -> Pose:
    return Pose(position=Vector3(x=float(x), y=float(y), z=z),
                orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))


def _transform(t: float, parent: str, child: str, x: float, y: float, yaw: float,
               z: float = 0.0) -> FrameTransform:
    return FrameTransform(timestamp=_stamp(t), parent_frame_id=parent, child_frame_id=child,
                          translation=Vector3(x=float(x), y=float(y), z=z),
                          rotation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2),
                                              w=math.cos(yaw / 2)))


class McapEpisodeLog:
    """Episode observer that writes an MCAP file (written to a temporary name, renamed on
    :meth:`close`).

    Args:
        path: Destination ``.mcap`` file.
        map_period: Seconds of simulated time between /map messages.
    """

    def __init__(self, path: str | os.PathLike, map_period: float = 1.0) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.name}.tmp")
        self.map_period = map_period
        self._next_map = 0.0
        self._map_logged = -math.inf  # Time of the last /map message...
        self._last_scan = None  # ...and (time, live map) at the last scan.
        self._last_kin = 0
        self.context = foxglove.Context()
        self.writer = foxglove.open_mcap(self._tmp, allow_overwrite=True, context=self.context)
        ctx = self.context
        self.scan = LaserScanChannel("/scan", context=ctx)
        self.tf = FrameTransformsChannel("/tf", context=ctx)
        self.pose = PoseInFrameChannel("/pose", context=ctx)
        self.odom = PoseInFrameChannel("/odom", context=ctx)
        self.map = GridChannel("/map", context=ctx)
        self.ter = SceneUpdateChannel("/ter", context=ctx)
        self.goal = PoseInFrameChannel("/goal", context=ctx)
        self.kinematics = foxglove.Channel(
            "/kinematics", message_encoding="json", context=ctx,
            schema=foxglove.Schema(name="mjexplore.Kinematics", encoding="jsonschema",
                                   data=json.dumps(KINEMATICS_SCHEMA).encode()))

    # Observer hooks ---------------------------------------------------------------

    def on_scan(self, episode, scan) -> None:
        t = scan.stamp
        ns = _ns(t)
        sim = episode.sim
        self.scan.log(FoxgloveLaserScan(
            timestamp=_stamp(t), frame_id="base_scan", pose=_pose(0.0, 0.0, 0.0),
            start_angle=float(scan.angles[0]), end_angle=float(scan.angles[-1]),
            ranges=[float(r) for r in scan.ranges],  # +-inf as REP-117 has them.
            intensities=[]), log_time=ns)
        x, y, yaw = sim.pose
        dx, dy, dyaw = sim.odom_pose
        if episode.config.mapping_pose == "ground_truth":
            # REP-105: map -> odom absorbs the drift, as a perfect localiser would, so
            # that base_link through /tf sits where the map was built from.
            oyaw = yaw - dyaw
            c, s_ = math.cos(oyaw), math.sin(oyaw)
            ox, oy = x - (c * dx - s_ * dy), y - (s_ * dx + c * dy)
        else:  # The map is built from odometry: it is the robot's whole estimate.
            ox, oy, oyaw = sim.odom_origin
        sx, sy, sz = TURTLEBOT3_WAFFLE.scan_offset
        self.tf.log(FrameTransforms(transforms=[
            _transform(t, "map", "odom", ox, oy, oyaw),
            _transform(t, "odom", "base_link", dx, dy, dyaw),
            _transform(t, "base_link", "base_scan", sx, sy, 0.0, sz)]), log_time=ns)
        self.pose.log(PoseInFrame(timestamp=_stamp(t), frame_id="map", pose=_pose(x, y, yaw)),
                      log_time=ns)
        self.odom.log(PoseInFrame(timestamp=_stamp(t), frame_id="odom",
                                  pose=_pose(dx, dy, dyaw)), log_time=ns)
        if t >= self._next_map - 1e-9:
            self._next_map = t + self.map_period
            self.log_map(t, episode.mapper.grid)
            self._map_logged = t
        self._last_scan = (t, episode.mapper.grid)
        self._log_kinematics(sim)

    def on_decision(self, episode, state) -> None:
        t = episode.sim.time
        goal = episode.goal
        self.goal.log(PoseInFrame(timestamp=_stamp(t), frame_id="map",
                                  pose=_pose(goal[0], goal[1], 0.0)), log_time=_ns(t))
        ter = state.extras.get("ter")
        if ter is None:
            ter, _, _ = episode.tracker.ter(state.grid, state.pose)
            state.extras["ter"] = ter  # Shared with other observers.
        self.log_ter(t, ter)

    def on_step(self, episode) -> None:
        del episode

    # Messages -----------------------------------------------------------------------

    def _log_kinematics(self, sim) -> None:
        rows = sim.kinematics_rows
        for i in range(max(self._last_kin, 1), len(rows)):
            t, v, w = rows[i, :3]
            dt = t - rows[i - 1, 0]
            self.kinematics.log({"t": float(t), "linear_velocity": float(v),
                                 "angular_velocity": float(w),
                                 "linear_acceleration": float((v - rows[i - 1, 1]) / dt),
                                 "angular_acceleration": float((w - rows[i - 1, 2]) / dt)},
                                log_time=_ns(float(t)))
        self._last_kin = len(rows)

    def log_map(self, t: float, grid) -> None:
        rows, cols = grid.shape
        self.map.log(Grid(
            timestamp=_stamp(t), frame_id="map", pose=_pose(grid.origin[0], grid.origin[1], 0.0),
            column_count=cols, cell_size=Vector2(x=grid.resolution, y=grid.resolution),
            row_stride=cols, cell_stride=1,
            fields=[PackedElementField(name="occupancy", offset=0,
                                       type=PackedElementFieldNumericType.Int8)],
            data=np.ascontiguousarray(grid.data).tobytes()), log_time=_ns(t))

    def log_ter(self, t: float, ter) -> None:
        spheres = [SpherePrimitive(pose=_pose(p[0], p[1], 0.0, 0.2),
                                   size=Vector3(x=0.25, y=0.25, z=0.25),
                                   color=_NODE_COLOURS[float(f)])
                   for p, f in zip(ter.positions, ter.flags)]
        points = [Point3(x=float(ter.positions[i, 0]), y=float(ter.positions[i, 1]), z=0.2)
                  for e in ter.edges for i in e]
        lines = [LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_pose(0, 0, 0),
                               thickness=0.04, scale_invariant=False, points=points,
                               color=Color(r=0.9, g=0.6, b=0.1, a=1.0))] if points else []
        self.ter.log(SceneUpdate(entities=[SceneEntity(
            timestamp=_stamp(t), frame_id="map", id="ter", spheres=spheres, lines=lines)]),
            log_time=_ns(t))

    def close(self) -> None:
        """Logs the final map (if newer than the last one logged), finishes the file and
        moves it into place."""
        if self._last_scan is not None and self._last_scan[0] > self._map_logged:
            self.log_map(*self._last_scan)
        self.writer.close()
        os.replace(self._tmp, self.path)
