"""Episode logs that open in Foxglove, stamped with simulated time.

:class:`EpisodeLogger` holds what every log shares: the REP-105 frames at each scan, when the
map is due, the kinematics samples since the last scan and the TER at each decision. Two logs
write it: :class:`FoxgloveEpisodeLog` (this module; to an MCAP file and/or a live Foxglove
WebSocket server, see :mod:`mjexplore.io.live`) and
:class:`~mjexplore.io.ros2_mcap.Ros2EpisodeLog` (ROS 2 messages).

Foxglove topics (Foxglove schemas, protobuf encoded by ``foxglove-sdk``), a robot alone's;
a team's robots each have /scan, /pose, /odom, /goal and /kinematics under their namespace
(``/robot_0/scan``, ...) and their frames prefixed by it (``robot_0/base_link``, as ROS
multi-robot setups prefix their ``tf`` frames), beside the shared /tf, /map and /ter:
    /scan        foxglove.LaserScan in ``base_scan`` (every scan)
    /tf          foxglove.FrameTransforms: map->odom, odom->base_link, base_link->base_scan
    /pose        foxglove.PoseInFrame: ground-truth pose of base_link in ``map``
    /odom        foxglove.PoseInFrame: wheel-odometry pose of base_link in ``odom``
    /map         foxglove.Grid: the occupancy map (int8: -1 unknown, 0..100), ``map_period``
    /ter         foxglove.SceneUpdate: TER nodes (spheres, coloured by kind) and edges (lines)
    /goal        foxglove.PoseInFrame: each exploration goal in ``map``
    /kinematics  JSON (mjexplore.Kinematics): linear and angular velocity of base_link and
                 their accelerations (backward differences)
    /people      foxglove.SceneUpdate: one upright cylinder entity per pedestrian (``person_I``)
                 in ``map``, every ``people_period`` (10 Hz) of simulated time; only in a world
                 with people (a run without them has no such channel)
Log time and message timestamps are simulated time in nanoseconds since the episode start.
"""

from __future__ import annotations

import dataclasses
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
    SceneUpdateChannel,
)
from foxglove.messages import (
    Color,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    Grid,
    LinePrimitive,
    LinePrimitiveLineType,
    PackedElementField,
    PackedElementFieldNumericType,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector2,
    Vector3,
)
from foxglove.messages import LaserScan as FoxgloveLaserScan

from mjexplore.io.stamps import sec_nsec, sim_ns
from mjexplore.robot import TURTLEBOT3_WAFFLE

if TYPE_CHECKING:
    from mjexplore.io.live import LiveServer
    from mjexplore.maps import GridMap

KINEMATICS_SCHEMA = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in (
        "t", "linear_velocity", "angular_velocity", "linear_acceleration",
        "angular_acceleration")},
}
TOPICS = ("/scan", "/tf", "/pose", "/odom", "/map", "/ter", "/goal", "/kinematics")
ROBOT_TOPICS = ("scan", "pose", "odom", "goal", "kinematics")  # Namespaced in a team.
# TER node colours (r, g, b, a) by node flag: 0 explored, 1 frontier, -1 dead end.
NODE_RGBA = {0.0: (0.1, 0.8, 0.1, 1.0), 1.0: (0.1, 0.3, 1.0, 1.0), -1.0: (0.9, 0.2, 0.2, 1.0)}
EDGE_RGBA = (0.9, 0.6, 0.1, 1.0)
NODE_SIZE = 0.25  # Sphere diameter, metres.
EDGE_WIDTH = 0.04  # Line width, metres.
TER_HEIGHT = 0.2  # Height of the drawn TER above the floor, metres.
_NODE_COLOURS = {flag: Color(r=r, g=g, b=b, a=a) for flag, (r, g, b, a) in NODE_RGBA.items()}
PEOPLE_TOPIC = "/people"  # Written only when the world has people (not in TOPICS).
PEOPLE_PERIOD = 0.1  # Simulated seconds between /people messages (10 Hz).
PERSON_RGBA = (0.78, 0.16, 0.63, 1.0)  # A pedestrian, as its MuJoCo body is coloured.
PERSON_ID = "person_{}"  # A pedestrian's entity (marker) id, as its MuJoCo body is named.
_PERSON_COLOUR = Color(r=PERSON_RGBA[0], g=PERSON_RGBA[1], b=PERSON_RGBA[2], a=PERSON_RGBA[3])


def robot_namespace(agent) -> str:
    """The namespace of ``agent``'s topics and frames: none for a robot alone, ``robot_I``
    for robot I of a team."""
    return "" if len(agent.episode.agents) == 1 else f"robot_{agent.index}"


def robot_topics(name: str) -> tuple[str, ...]:
    """The topics of the team robot namespaced ``name`` (``robot_0``...)."""
    return tuple(f"/{name}/{t}" for t in ROBOT_TOPICS)


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by ``yaw`` radians about +z."""
    return 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)


@dataclasses.dataclass(frozen=True)
class ScanFrames:
    """The REP-105 frames at one scan; poses are (x, y, yaw) in metres and radians.

    Attributes:
        t: Simulated time of the scan in seconds.
        map_odom: Pose of ``odom`` in ``map``. When the map is built from the true pose it
            absorbs the odometry drift, as a perfect localiser would, so that ``base_link``
            through the frames sits where the map was built from.
        odom_base: Wheel-odometry pose of ``base_link`` in ``odom``.
        pose: Ground-truth pose of ``base_link`` in ``map``.
        velocity: Ground-truth (forward m/s, yaw rate rad/s) of ``base_link``.
    """

    t: float
    map_odom: tuple[float, float, float]
    odom_base: tuple[float, float, float]
    pose: tuple[float, float, float]
    velocity: tuple[float, float]

    @classmethod
    def of(cls, episode, t: float) -> ScanFrames:
        """The frames of ``episode`` now (``t``: the scan's simulated time, seconds)."""
        sim = episode.sim
        x, y, yaw = (float(v) for v in sim.pose)
        dx, dy, dyaw = (float(v) for v in sim.odom_pose)
        if episode.localizer is None:
            oyaw = yaw - dyaw
            c, s = math.cos(oyaw), math.sin(oyaw)
            map_odom = (x - (c * dx - s * dy), y - (s * dx + c * dy), oyaw)
        else:  # The map is built at the estimate: map -> odom is the localiser's.
            mx, my, myaw = (float(v) for v in episode.localizer.map_to_odom(sim.odom_pose))
            map_odom = (mx, my, myaw)
        v, w = (float(u) for u in sim.velocity)
        return cls(t, map_odom, (dx, dy, dyaw), (x, y, yaw), (v, w))


SCAN_OFFSET = TURTLEBOT3_WAFFLE.scan_offset  # (x, y, z) of base_scan in base_link, metres.


class EpisodeLogger:
    """Episode observer that turns the episode into messages; subclasses write them.

    At each scan: :meth:`write_scan` (scan and frames), :meth:`write_map` every
    ``map_period`` seconds of simulated time (and the final map on :meth:`close` if newer),
    :meth:`write_kinematics` with the samples since the last scan. At each decision:
    :meth:`write_goal` and :meth:`write_ter`. In a world with people (its ``crowd``), at the
    first scan or control period at or after each multiple of ``people_period`` seconds of
    simulated time: :meth:`write_people`, stamped with the world's time (the crowd's).

    Args:
        map_period: Seconds of simulated time between maps.
        people_period: Seconds of simulated time between the people's poses.
    """

    def __init__(self, map_period: float = 1.0, people_period: float = PEOPLE_PERIOD) -> None:
        self.map_period = map_period
        self.people_period = people_period
        self._next_people = 0.0
        self._next_map = 0.0
        self._map_logged = -math.inf  # Time of the last map written...
        # ...and (time, live map) at the last scan.
        self._last_scan: tuple[float, GridMap] | None = None
        self._last_kin: dict[str, int] = {}  # Per robot namespace.

    # Observer hooks ---------------------------------------------------------------

    def on_scan(self, agent, scan) -> None:
        robot = robot_namespace(agent)
        t = scan.stamp
        self.write_scan(agent, scan, ScanFrames.of(agent, t), robot)
        grid = agent.episode.mapper.grid
        if t >= self._next_map - 1e-9:
            self._next_map = t + self.map_period
            self.write_map(t, grid)
            self._map_logged = t
        self._last_scan = (t, grid)
        rows = agent.sim.kinematics_rows
        start = max(self._last_kin.get(robot, 0), 1)
        if len(rows) > start:
            t, v, w = rows[start - 1:, 0], rows[start - 1:, 1], rows[start - 1:, 2]
            dt = np.diff(t)
            self.write_kinematics(np.column_stack(
                [t[1:], v[1:], w[1:], np.diff(v) / dt, np.diff(w) / dt]), robot)
        self._last_kin[robot] = len(rows)
        self._log_people(agent.episode.world)

    def on_decision(self, agent, state) -> None:
        t = agent.sim.time
        goal = agent.goal
        self.write_goal(t, float(goal[0]), float(goal[1]), robot_namespace(agent))
        ter = state.extras.get("ter")
        if ter is None:
            ter, _, _ = agent.tracker.ter(state.grid, state.pose)
            state.extras["ter"] = ter  # Shared with other observers.
        self.write_ter(t, ter)

    def on_step(self, episode) -> None:
        self._log_people(episode.world)

    def _log_people(self, world) -> None:
        """The people's poses now, if the world has people and they are due."""
        crowd = getattr(world, "crowd", None)
        if crowd is None:
            return
        t = float(world.time)
        if t < self._next_people - 1e-9:
            return
        # The next multiple of the period: the rate stays 1 / people_period over a long run.
        self._next_people = (math.floor(t / self.people_period + 1e-6) + 1) * self.people_period
        cfg = crowd.config
        self.write_people(t, np.asarray(crowd.positions, float), float(cfg.radius),
                          float(cfg.height))

    def close(self) -> None:
        """Writes the final map (if newer than the last one written) and finishes."""
        if self._last_scan is not None and self._last_scan[0] > self._map_logged:
            self.write_map(*self._last_scan)
        self.finish()

    # For subclasses -------------------------------------------------------------------

    def write_scan(self, agent, scan, frames: ScanFrames, robot: str = "") -> None:
        """The scan, the frames and the poses at ``frames.t`` of the robot namespaced
        ``robot`` (:func:`robot_namespace`)."""
        raise NotImplementedError

    def write_map(self, t: float, grid) -> None:
        """The occupancy map (:class:`~mjexplore.maps.GridMap`) at ``t``."""
        raise NotImplementedError

    def write_goal(self, t: float, x: float, y: float, robot: str = "") -> None:
        """The goal robot ``robot`` chose at ``t``, in ``map``."""
        raise NotImplementedError

    def write_ter(self, t: float, ter) -> None:
        """The TER at ``t``: nodes (``positions`` in ``map``, ``flags``) and ``edges``."""
        raise NotImplementedError

    def write_kinematics(self, rows: np.ndarray, robot: str = "") -> None:
        """Robot ``robot``'s samples (t s, v m/s, omega rad/s, dv/dt m/s^2, domega/dt
        rad/s^2), one a row."""
        raise NotImplementedError

    def write_people(self, t: float, positions: np.ndarray, radius: float,
                     height: float) -> None:
        """The people at ``t``: (n, 2) disc centres in ``map``, each an upright cylinder of
        ``radius`` and ``height`` metres standing on the floor."""
        raise NotImplementedError

    def finish(self) -> None:
        raise NotImplementedError


def _stamp(t: float) -> Timestamp:
    sec, nsec = sec_nsec(t)
    return Timestamp(sec=sec, nsec=nsec)


def _quaternion(yaw: float) -> Quaternion:
    qx, qy, qz, qw = yaw_quaternion(yaw)
    return Quaternion(x=qx, y=qy, z=qz, w=qw)


def _pose(x: float, y: float, yaw: float, z: float = 0.0) -> Pose:
    return Pose(position=Vector3(x=float(x), y=float(y), z=z), orientation=_quaternion(yaw))


def _transform(t: float, parent: str, child: str, x: float, y: float, yaw: float,
               z: float = 0.0) -> FrameTransform:
    return FrameTransform(timestamp=_stamp(t), parent_frame_id=parent, child_frame_id=child,
                          translation=Vector3(x=float(x), y=float(y), z=z),
                          rotation=_quaternion(yaw))


class _RobotChannels:
    """One robot's channels: /scan, /pose, /odom, /goal and /kinematics, under its
    namespace in a team."""

    def __init__(self, name: str, context: foxglove.Context) -> None:
        topic = (lambda t: f"/{name}/{t}") if name else (lambda t: f"/{t}")
        self.scan = LaserScanChannel(topic("scan"), context=context)
        self.pose = PoseInFrameChannel(topic("pose"), context=context)
        self.odom = PoseInFrameChannel(topic("odom"), context=context)
        self.goal = PoseInFrameChannel(topic("goal"), context=context)
        self.kinematics = foxglove.Channel(
            topic("kinematics"), message_encoding="json", context=context,
            schema=foxglove.Schema(name="mjexplore.Kinematics", encoding="jsonschema",
                                   data=json.dumps(KINEMATICS_SCHEMA).encode()))


class FoxgloveEpisodeLog(EpisodeLogger):
    """Episode log with Foxglove schemas, written to an MCAP file (to a temporary name, renamed
    on :meth:`close`) and/or streamed by a live Foxglove WebSocket server.

    Both are sinks of one ``foxglove.Context``: each message is built once and goes to every
    sink. A message nobody takes (live only, with no client subscribed to its topic) is not
    built at all.

    Args:
        path: Destination ``.mcap`` file, or None for none.
        map_period: Seconds of simulated time between /map messages.
        live: A started :class:`~mjexplore.io.live.LiveServer` to stream to (its context
            is used; it also paces the episode and gets the simulated time), or None.
    """

    def __init__(self, path: str | os.PathLike | None = None, map_period: float = 1.0,
                 live: LiveServer | None = None) -> None:
        super().__init__(map_period)
        self.live = live
        self.context = live.context if live is not None else foxglove.Context()
        self.path = self.writer = None
        if path is not None:
            self.path = Path(path)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._tmp = self.path.with_name(f".{self.path.name}.tmp")
            self.writer = foxglove.open_mcap(self._tmp, allow_overwrite=True,
                                             context=self.context)
        ctx = self.context
        self.tf = FrameTransformsChannel("/tf", context=ctx)
        self.map = GridChannel("/map", context=ctx)
        self.ter = SceneUpdateChannel("/ter", context=ctx)
        self._robots: dict[str, _RobotChannels] = {"": _RobotChannels("", ctx)}
        # Made on the first people's message: a run without people has no such channel.
        self.people: SceneUpdateChannel | None = None

    def robot(self, name: str) -> _RobotChannels:
        """The channels of the robot namespaced ``name`` (made on its first message)."""
        if name not in self._robots:
            self._robots[name] = _RobotChannels(name, self.context)
        return self._robots[name]

    def write_scan(self, agent, scan, frames: ScanFrames, robot: str = "") -> None:
        t = frames.t
        ns = sim_ns(t)
        ch = self.robot(robot)
        p = f"{robot}/" if robot else ""  # Its frames' prefix.
        if ch.scan.has_sinks():
            ch.scan.log(FoxgloveLaserScan(
                timestamp=_stamp(t), frame_id=p + "base_scan", pose=_pose(0.0, 0.0, 0.0),
                start_angle=float(scan.angles[0]), end_angle=float(scan.angles[-1]),
                ranges=scan.ranges.tolist(),  # +-inf as REP-117 has them.
                intensities=[]), log_time=ns)
        if self.tf.has_sinks():
            sx, sy, sz = SCAN_OFFSET
            self.tf.log(FrameTransforms(transforms=[
                _transform(t, "map", p + "odom", *frames.map_odom),
                _transform(t, p + "odom", p + "base_link", *frames.odom_base),
                _transform(t, p + "base_link", p + "base_scan", sx, sy, 0.0, sz)]), log_time=ns)
        if ch.pose.has_sinks():
            ch.pose.log(PoseInFrame(timestamp=_stamp(t), frame_id="map",
                                    pose=_pose(*frames.pose)), log_time=ns)
        if ch.odom.has_sinks():
            ch.odom.log(PoseInFrame(timestamp=_stamp(t), frame_id=p + "odom",
                                    pose=_pose(*frames.odom_base)), log_time=ns)
        if self.live is not None:
            self.live.pace(t)

    def write_kinematics(self, rows: np.ndarray, robot: str = "") -> None:
        channel = self.robot(robot).kinematics
        if not channel.has_sinks():
            return
        for t, v, w, a, alpha in rows.tolist():
            channel.log({"t": t, "linear_velocity": v, "angular_velocity": w,
                         "linear_acceleration": a, "angular_acceleration": alpha},
                        log_time=sim_ns(t))

    def write_goal(self, t: float, x: float, y: float, robot: str = "") -> None:
        channel = self.robot(robot).goal
        if channel.has_sinks():
            channel.log(PoseInFrame(timestamp=_stamp(t), frame_id="map",
                                    pose=_pose(x, y, 0.0)), log_time=sim_ns(t))

    def write_map(self, t: float, grid) -> None:
        if not self.map.has_sinks():
            return
        rows, cols = grid.shape
        self.map.log(Grid(
            timestamp=_stamp(t), frame_id="map", pose=_pose(grid.origin[0], grid.origin[1], 0.0),
            column_count=cols, cell_size=Vector2(x=grid.resolution, y=grid.resolution),
            row_stride=cols, cell_stride=1,
            fields=[PackedElementField(name="occupancy", offset=0,
                                       type=PackedElementFieldNumericType.Int8)],
            data=np.ascontiguousarray(grid.data).tobytes()), log_time=sim_ns(t))

    def write_ter(self, t: float, ter) -> None:
        if not self.ter.has_sinks():
            return
        spheres = [SpherePrimitive(pose=_pose(p[0], p[1], 0.0, TER_HEIGHT),
                                   size=Vector3(x=NODE_SIZE, y=NODE_SIZE, z=NODE_SIZE),
                                   color=_NODE_COLOURS[float(f)])
                   for p, f in zip(ter.positions, ter.flags)]
        points = [Point3(x=float(ter.positions[i, 0]), y=float(ter.positions[i, 1]),
                         z=TER_HEIGHT) for e in ter.edges for i in e]
        lines = [LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_pose(0, 0, 0),
                               thickness=EDGE_WIDTH, scale_invariant=False, points=points,
                               color=Color(r=EDGE_RGBA[0], g=EDGE_RGBA[1], b=EDGE_RGBA[2],
                                           a=EDGE_RGBA[3]))] if points else []
        self.ter.log(SceneUpdate(entities=[SceneEntity(
            timestamp=_stamp(t), frame_id="map", id="ter", spheres=spheres, lines=lines)]),
            log_time=sim_ns(t))

    def write_people(self, t: float, positions: np.ndarray, radius: float,
                     height: float) -> None:
        if self.people is None:
            self.people = SceneUpdateChannel(PEOPLE_TOPIC, context=self.context)
        if not self.people.has_sinks():
            return
        stamp = _stamp(t)
        size = Vector3(x=2 * radius, y=2 * radius, z=height)
        self.people.log(SceneUpdate(entities=[SceneEntity(
            timestamp=stamp, frame_id="map", id=PERSON_ID.format(i),
            cylinders=[CylinderPrimitive(pose=_pose(x, y, 0.0, height / 2), size=size,
                                         bottom_scale=1.0, top_scale=1.0,
                                         color=_PERSON_COLOUR)])
            for i, (x, y) in enumerate(positions.tolist())]), log_time=sim_ns(t))

    def finish(self) -> None:
        """Finishes the MCAP file and moves it into place."""
        if self.writer is not None:
            assert self.path is not None  # A writer is opened only with a path.
            self.writer.close()
            os.replace(self._tmp, self.path)
