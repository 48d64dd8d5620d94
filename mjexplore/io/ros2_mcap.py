"""Episode logs as ROS 2 MCAP files (profile ``ros2``, CDR messages, ``ros2msg`` schemas):
``ros2 bag play episode.mcap`` publishes them, Foxglove and PlotJuggler open them.

Topics (REP-105 frames ``map``, ``odom``, ``base_link``, ``base_scan``):
    /scan                     sensor_msgs/msg/LaserScan in ``base_scan`` (every scan)
    /tf                       tf2_msgs/msg/TFMessage: map->odom, odom->base_link
    /tf_static                tf2_msgs/msg/TFMessage: base_link->base_scan (once, at 0 s)
    /pose                     geometry_msgs/msg/PoseStamped: ground-truth pose in ``map``
    /odom                     nav_msgs/msg/Odometry: wheel-odometry pose in ``odom`` and the
                              velocity in ``base_link``
    /map                      nav_msgs/msg/OccupancyGrid, every ``map_period`` and at the end
    /goal                     geometry_msgs/msg/PoseStamped: each exploration goal in ``map``
    /ter                      visualization_msgs/msg/MarkerArray: TER nodes (a sphere list
                              coloured by kind) and edges (a line list)
    /kinematics/velocity      geometry_msgs/msg/TwistStamped in ``base_link`` (every sample)
    /kinematics/acceleration  geometry_msgs/msg/AccelStamped in ``base_link`` (backward
                              differences)
    /people                   visualization_msgs/msg/MarkerArray: one cylinder marker per
                              pedestrian (ns ``people``, id I) in ``map``, every
                              ``people_period`` (10 Hz); only in a world with people (a run
                              without them has no such channel)
Header stamps and log times are simulated time since the episode start. The messages are
those of :mod:`mjexplore.io.mcap_log` (same frames, same map times), in ROS 2 types; the
message definitions are ROS 2 Humble's and later's.
"""

from __future__ import annotations

import os
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, Profile, SchemaEncoding
from mcap.writer import Writer

# The public mcap_ros2.writer.Writer encodes an int8[] cell by cell in Python (a tenth of a
# second per office map); its encoder is used here for the small messages and the map's
# cells are appended as bytes (see _with_bytes).
from mcap_ros2._dynamic import serialize_dynamic

import mjexplore
from mjexplore.io.mcap_log import (
    EDGE_RGBA,
    EDGE_WIDTH,
    NODE_RGBA,
    NODE_SIZE,
    PEOPLE_TOPIC,
    PERSON_RGBA,
    SCAN_OFFSET,
    TER_HEIGHT,
    EpisodeLogger,
    ScanFrames,
    yaw_quaternion,
)
from mjexplore.io.stamps import sec_nsec, sim_ns

# ROS 2 message definitions (fields only; comments and constants left out).
MSG_DEFINITIONS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "builtin_interfaces/Duration": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "std_msgs/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/TwistStamped": "std_msgs/Header header\ngeometry_msgs/Twist twist",
    "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance",
    "geometry_msgs/Accel": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/AccelStamped": "std_msgs/Header header\ngeometry_msgs/Accel accel",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\n"
                               "geometry_msgs/Quaternion rotation",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\n"
                                      "geometry_msgs/Transform transform",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    "sensor_msgs/LaserScan": "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\n"
                             "float32 angle_increment\nfloat32 time_increment\n"
                             "float32 scan_time\nfloat32 range_min\nfloat32 range_max\n"
                             "float32[] ranges\nfloat32[] intensities",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data",
    "nav_msgs/MapMetaData": "builtin_interfaces/Time map_load_time\nfloat32 resolution\n"
                            "uint32 width\nuint32 height\ngeometry_msgs/Pose origin",
    "nav_msgs/OccupancyGrid": "std_msgs/Header header\nnav_msgs/MapMetaData info\nint8[] data",
    "nav_msgs/Odometry": "std_msgs/Header header\nstring child_frame_id\n"
                         "geometry_msgs/PoseWithCovariance pose\n"
                         "geometry_msgs/TwistWithCovariance twist",
    "visualization_msgs/UVCoordinate": "float32 u\nfloat32 v",
    "visualization_msgs/MeshFile": "string filename\nuint8[] data",
    "visualization_msgs/Marker": (
        "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n"
        "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\n"
        "builtin_interfaces/Duration lifetime\nbool frame_locked\n"
        "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\n"
        "sensor_msgs/CompressedImage texture\nvisualization_msgs/UVCoordinate[] uv_coordinates\n"
        "string text\nstring mesh_resource\nvisualization_msgs/MeshFile mesh_file\n"
        "bool mesh_use_embedded_materials"),
    "visualization_msgs/MarkerArray": "visualization_msgs/Marker[] markers",
}
TOPICS = {
    "/scan": "sensor_msgs/msg/LaserScan",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/pose": "geometry_msgs/msg/PoseStamped",
    "/odom": "nav_msgs/msg/Odometry",
    "/map": "nav_msgs/msg/OccupancyGrid",
    "/goal": "geometry_msgs/msg/PoseStamped",
    "/ter": "visualization_msgs/msg/MarkerArray",
    "/kinematics/velocity": "geometry_msgs/msg/TwistStamped",
    "/kinematics/acceleration": "geometry_msgs/msg/AccelStamped",
}
PEOPLE_TYPE = "visualization_msgs/msg/MarkerArray"  # /people's, registered on its first.
# visualization_msgs/Marker types and actions.
SPHERE_LIST, LINE_LIST, CYLINDER, ADD, DELETE = 7, 5, 3, 0, 2
_SEPARATOR = "=" * 80


def schema_text(datatype: str) -> str:
    """The concatenated ``ros2msg`` definition of ``datatype`` (``pkg/msg/Name``): its own
    fields, then each type it uses under a ``MSG: pkg/Name`` line, as rosbag2 writes them."""
    pkg, _, name = datatype.split("/")
    order: list[str] = []

    def visit(short: str) -> None:
        for ftype in re.findall(r"^(\w+/\w+)", MSG_DEFINITIONS[short], flags=re.MULTILINE):
            if ftype not in order:
                order.append(ftype)
                visit(ftype)

    visit(f"{pkg}/{name}")
    return "\n".join([MSG_DEFINITIONS[f"{pkg}/{name}"]] + [
        f"{_SEPARATOR}\nMSG: {dep}\n{MSG_DEFINITIONS[dep]}" for dep in order])


def _with_bytes(encoded: bytes, data: bytes) -> bytes:
    """CDR of a message whose last field is a byte array (int8[] or uint8[]): ``encoded`` is
    the message encoded with that array empty (its last 4 bytes: the uint32 length 0)."""
    if encoded[-4:] != b"\0\0\0\0":
        raise ValueError("the message does not end with an empty array")
    return encoded[:-4] + struct.pack("<I", len(data)) + data


def _time(t: float) -> dict:
    sec, nanosec = sec_nsec(t)
    return {"sec": sec, "nanosec": nanosec}


def _header(t: float, frame: str) -> dict:
    return {"stamp": _time(t), "frame_id": frame}


def _xyz(x: float, y: float, z: float) -> dict:
    return {"x": float(x), "y": float(y), "z": float(z)}


def _quaternion(yaw: float) -> dict:
    return dict(zip("xyzw", yaw_quaternion(yaw)))


def _pose(x: float, y: float, yaw: float, z: float = 0.0) -> dict:
    return {"position": _xyz(x, y, z), "orientation": _quaternion(yaw)}


def _transform(t: float, parent: str, child: str, x: float, y: float, yaw: float,
               z: float = 0.0) -> dict:
    return {"header": _header(t, parent), "child_frame_id": child,
            "transform": {"translation": _xyz(x, y, z), "rotation": _quaternion(yaw)}}


def _rgba(colour: tuple[float, float, float, float]) -> dict:
    return dict(zip("rgba", colour))


class Ros2EpisodeLog(EpisodeLogger):
    """Episode observer that writes a ROS 2 MCAP file (to a temporary name, renamed on
    :meth:`close`).

    Args:
        path: Destination ``.mcap`` file.
        map_period: Seconds of simulated time between /map messages.
    """

    def __init__(self, path: str | os.PathLike, map_period: float = 1.0) -> None:
        super().__init__(map_period)
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.name}.tmp")
        self._file = open(self._tmp, "wb")
        self.writer = Writer(self._file)
        self.writer.start(profile=Profile.ROS2, library=f"mjexplore {mjexplore.__version__}")
        # Topic -> (channel id, encoder); datatype -> (schema id, encoder).
        self._channels: dict[str, tuple[int, Any]] = {}
        self._schemas: dict[str, tuple[int, Any]] = {}
        for topic, datatype in TOPICS.items():
            self._register(topic, datatype)
        sx, sy, sz = SCAN_OFFSET
        self._write("/tf_static", 0.0, {"transforms": [
            _transform(0.0, "base_link", "base_scan", sx, sy, 0.0, sz)]})

    def _register(self, topic: str, datatype: str) -> None:
        """Registers ``topic`` (and ``datatype``'s schema, the first time)."""
        if datatype not in self._schemas:
            text = schema_text(datatype)
            self._schemas[datatype] = (
                self.writer.register_schema(datatype, SchemaEncoding.ROS2, text.encode()),
                serialize_dynamic(datatype, text)[datatype])
        schema_id, encode = self._schemas[datatype]
        self._channels[topic] = (self.writer.register_channel(
            topic, MessageEncoding.CDR, schema_id), encode)

    def _write(self, topic: str, t: float, message: dict, data: bytes | None = None) -> None:
        """Writes ``message`` at simulated time ``t``; ``data``: the bytes of its last field
        (a byte array left out of ``message``)."""
        channel, encode = self._channels[topic]
        payload = encode(message) if data is None else _with_bytes(encode(message), data)
        ns = sim_ns(t)
        self.writer.add_message(channel, log_time=ns, data=payload, publish_time=ns)

    def write_scan(self, agent, scan, frames: ScanFrames, robot: str = "") -> None:
        assert not robot, "ROS 2 logs are of one robot"  # run_episode refuses a team's.
        t = frames.t
        lidar = agent.sim.lidar.config
        angles = scan.angles
        self._write("/scan", t, {
            "header": _header(t, "base_scan"), "angle_min": float(angles[0]),
            "angle_max": float(angles[-1]),
            "angle_increment": float(angles[1] - angles[0]) if len(angles) > 1 else 0.0,
            "time_increment": float(scan.time_increment),  # Negative: LDS-01 turns clockwise.
            "scan_time": 1.0 / lidar.rate_hz, "range_min": lidar.range_min,
            "range_max": float(scan.range_max),
            "ranges": scan.ranges.tolist(),  # +-inf as REP-117 has them.
            "intensities": []})
        self._write("/tf", t, {"transforms": [
            _transform(t, "map", "odom", *frames.map_odom),
            _transform(t, "odom", "base_link", *frames.odom_base)]})
        self._write("/pose", t, {"header": _header(t, "map"), "pose": _pose(*frames.pose)})
        v, w = frames.velocity
        self._write("/odom", t, {
            "header": _header(t, "odom"), "child_frame_id": "base_link",
            "pose": {"pose": _pose(*frames.odom_base)},
            "twist": {"twist": {"linear": _xyz(v, 0, 0), "angular": _xyz(0, 0, w)}}})

    def write_kinematics(self, rows: np.ndarray, robot: str = "") -> None:
        for t, v, w, a, alpha in rows.tolist():
            header = _header(t, "base_link")
            self._write("/kinematics/velocity", t, {"header": header, "twist": {
                "linear": _xyz(v, 0, 0), "angular": _xyz(0, 0, w)}})
            self._write("/kinematics/acceleration", t, {"header": header, "accel": {
                "linear": _xyz(a, 0, 0), "angular": _xyz(0, 0, alpha)}})

    def write_goal(self, t: float, x: float, y: float, robot: str = "") -> None:
        self._write("/goal", t, {"header": _header(t, "map"), "pose": _pose(x, y, 0.0)})

    def write_map(self, t: float, grid) -> None:
        rows, cols = grid.shape
        self._write("/map", t, {"header": _header(t, "map"), "info": {
            "map_load_time": _time(t), "resolution": grid.resolution, "width": cols,
            "height": rows, "origin": _pose(grid.origin[0], grid.origin[1], 0.0)}},
            data=np.ascontiguousarray(grid.data).tobytes())

    def write_ter(self, t: float, ter) -> None:
        header = _header(t, "map")
        nodes = [_xyz(p[0], p[1], TER_HEIGHT) for p in ter.positions]
        edges = [_xyz(ter.positions[i, 0], ter.positions[i, 1], TER_HEIGHT)
                 for e in ter.edges for i in e]
        self._write("/ter", t, {"markers": [
            {"header": header, "ns": "ter", "id": 0, "type": SPHERE_LIST,
             "action": ADD if nodes else DELETE, "pose": _pose(0, 0, 0),
             "scale": _xyz(NODE_SIZE, NODE_SIZE, NODE_SIZE), "color": _rgba((1, 1, 1, 1)),
             "points": nodes, "colors": [_rgba(NODE_RGBA[float(f)]) for f in ter.flags]},
            {"header": header, "ns": "ter", "id": 1, "type": LINE_LIST,
             "action": ADD if edges else DELETE, "pose": _pose(0, 0, 0),
             "scale": _xyz(EDGE_WIDTH, 0, 0), "color": _rgba(EDGE_RGBA), "points": edges}]})

    def write_people(self, t: float, positions: np.ndarray, radius: float,
                     height: float) -> None:
        if PEOPLE_TOPIC not in self._channels:  # A run without people has no such channel.
            self._register(PEOPLE_TOPIC, PEOPLE_TYPE)
        header = _header(t, "map")
        scale = _xyz(2 * radius, 2 * radius, height)
        self._write(PEOPLE_TOPIC, t, {"markers": [
            {"header": header, "ns": "people", "id": i, "type": CYLINDER, "action": ADD,
             "pose": _pose(x, y, 0.0, height / 2), "scale": scale,
             "color": _rgba(PERSON_RGBA)}
            for i, (x, y) in enumerate(positions.tolist())]})

    def finish(self) -> None:
        """Finishes the MCAP file and moves it into place."""
        self.writer.finish()
        self._file.close()
        os.replace(self._tmp, self.path)
