"""Re-rendering a recorded run (``mjexplore render RUN_DIR``) from its ``episode.mcap``.

The MCAP holds the ground-truth pose at every scan, the map every second, the TER and goal
at every decision and, in a world with people, the people at 10 Hz; frames are rebuilt from
the latest of each at the frame's simulated time (the GVD and frontiers are recomputed from
the map; the planned path is not logged, so replays do not show it). The people are drawn
in the map panel and stand in the 3D view as the bodies they were.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.io.progress import Progress
from mjexplore.io.video import VideoWriter
from mjexplore.maps import GridMap
from mjexplore.render.panel import PanelContent, gvd_segments, render_panel
from mjexplore.render.recorder import VideoConfig
from mjexplore.render.scene_view import SceneView
from mjexplore.scenes.people import PERSON, add_people
from mjexplore.topology.frontiers import estimated_information_gain, find_frontiers
from mjexplore.topology.pipeline import TopologyTracker

if TYPE_CHECKING:
    from google.protobuf.message import Message

# TER node colours in the MCAP (see mcap_log._NODE_COLOURS), by their green channel.
_FLAG_BY_GREEN = {0.8: 0.0, 0.3: 1.0, 0.2: -1.0}


def _decoders(summary) -> dict[int, type[Message]]:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    classes = {}
    for sid, schema in summary.schemas.items():
        if schema.encoding != "protobuf":
            continue
        fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
        for fd in fds.file:
            try:
                pool.Add(fd)
            except (TypeError, ValueError):
                pass  # Already added by another schema.
        classes[sid] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    return classes


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class RecordedEpisode:
    """The timelines of a run's MCAP (times in simulated seconds)."""

    def __init__(self, path: Path) -> None:
        from mcap.reader import make_reader

        self.poses: list[tuple[float, float, float, float]] = []
        self.maps: list[tuple[float, GridMap]] = []
        self.ters: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []
        self.goals: list[tuple[float, np.ndarray]] = []
        # (t, (n, 2) centres, radius, height) of the people, in a world with people.
        self.people: list[tuple[float, np.ndarray, float, float]] = []
        try:
            with open(path, "rb") as f:
                reader = make_reader(f)
                if reader.get_header().profile == "ros2":
                    raise UserInputError(
                        f"{str(path)!r} holds ROS 2 messages (--mcap-profile ros2); render "
                        "reads Foxglove ones: re-run the episode without --mcap-profile ros2.")
                classes = _decoders(reader.get_summary())
                for schema, channel, message in reader.iter_messages(
                        topics=["/pose", "/map", "/ter", "/goal", "/people"]):
                    assert schema is not None  # Foxglove writes each channel's schema.
                    msg = classes[schema.id].FromString(message.data)
                    self._add(channel.topic, message.log_time * 1e-9, msg)
        except OSError as exc:
            raise UserInputError(f"cannot read {str(path)!r}: {exc.strerror}; render needs a run "
                                 "folder written by 'mjexplore explore' (without --no-mcap).") \
                from None
        except UserInputError:
            raise
        except Exception as exc:  # The mcap reader raises many kinds for damaged files.
            raise UserInputError(f"{str(path)!r} is not a readable MCAP ({type(exc).__name__}: "
                                 f"{exc}); re-run the episode to record it again.") from None
        if not self.poses or not self.maps:
            raise UserInputError(f"{str(path)!r} holds no /pose or /map messages to render.")

    def _add(self, topic: str, t: float, msg) -> None:
        if topic == "/pose":
            p = msg.pose
            self.poses.append((t, p.position.x, p.position.y, _yaw(p.orientation)))
        elif topic == "/map":
            res = msg.cell_size.x
            cols = msg.column_count
            data = np.frombuffer(msg.data, np.int8).reshape(-1, cols)
            origin = (msg.pose.position.x, msg.pose.position.y, 0.0)
            self.maps.append((t, GridMap(data.copy(), res, origin)))
        elif topic == "/ter":
            entity = msg.entities[0]
            pos = np.array([[s.pose.position.x, s.pose.position.y] for s in entity.spheres])
            flags = np.array([_FLAG_BY_GREEN.get(round(s.color.g, 1), -1.0)
                              for s in entity.spheres])
            edges = np.zeros((0, 2), int)
            if entity.lines and len(pos):
                pts = np.array([[q.x, q.y] for q in entity.lines[0].points]).reshape(-1, 2)
                idx = np.argmin(np.linalg.norm(pts[:, None] - pos[None], axis=2), axis=1)
                edges = idx.reshape(-1, 2)
            self.ters.append((t, pos.reshape(-1, 2), edges, flags))
        elif topic == "/goal":
            self.goals.append((t, np.array([msg.pose.position.x, msg.pose.position.y])))
        elif topic == "/people":
            cylinders = [e.cylinders[0] for e in msg.entities if e.cylinders]
            xy = np.array([[c.pose.position.x, c.pose.position.y] for c in cylinders])
            size = cylinders[0].size if cylinders else None
            self.people.append((t, xy.reshape(-1, 2), size.x / 2 if size else 0.0,
                                size.z if size else 0.0))

    @staticmethod
    def latest(items: list, t: float):
        """The last item stamped at or before ``t`` (None if none)."""
        times = [i[0] for i in items]
        k = int(np.searchsorted(times, t + 1e-9)) - 1
        return items[k] if k >= 0 else None


def render_run(run_dir: str | os.PathLike, out: str | os.PathLike | None = None,
               config: VideoConfig | None = None, progress: bool = False) -> dict:
    """Renders ``run_dir/episode.mcap`` to a video (default ``run_dir/video.mp4``).

    ``progress`` shows the frames rendered on stderr (a bar on a terminal, a line every 30 s
    elsewhere: :class:`~mjexplore.io.progress.Progress`).

    Returns:
        {"video": path, "frames": n, "duration_s": video seconds}.

    Raises:
        UserInputError: not a run folder, or its MCAP or scene cannot be read.
    """
    run_dir = Path(run_dir)
    config = config or VideoConfig()
    try:
        meta = json.loads((run_dir / "config.json").read_text())
        xml = meta["scene"]
    except (OSError, ValueError, KeyError):
        raise UserInputError(f"{str(run_dir)!r} is not a run folder of 'mjexplore explore' "
                             "(config.json with the scene is missing).") from None
    rec = RecordedEpisode(run_dir / "episode.mcap")
    try:
        spec = mujoco.MjSpec.from_file(xml)
        if rec.people:  # The people's bodies, placed at each frame as recorded.
            _, xy, radius, height = rec.people[0]
            add_people(spec, len(xy), radius, height)
        model = spec.compile()
    except ValueError as exc:
        raise UserInputError(f"the run's scene {xml!r} cannot be loaded ({exc}); it was moved or "
                             "deleted.") from None
    data = mujoco.MjData(model)
    mocap = np.array([model.body(PERSON.format(i)).mocapid[0]
                      for i in range(len(rec.people[0][1]) if rec.people else 0)], int)
    base = model.body("base_link").id
    qadr = model.jnt_qposadr[model.body_jntadr[base]]
    z0 = float(model.body_pos[base][2])
    view = SceneView(model, config.width, config.height, config.camera)
    poses = np.array(rec.poses)
    title = f"{meta.get('explorer', '')} / seed {meta.get('seed', '')} (replay)"
    out = Path(out) if out is not None else run_dir / "video.mp4"
    tracker, gvd_map, segments = None, None, None
    frames = 0
    times = np.arange(0.0, poses[-1, 0] + 1e-9, config.sim_seconds_per_frame)
    if poses[-1, 0] > times[-1] + 1e-9:
        times = np.append(times, poses[-1, 0])  # The final state, as the live video.
    with (VideoWriter(out, config.fps) as writer,
          Progress(len(times), "render", "frames", enabled=progress) as shown):
        for t in times:
            k = max(int(np.searchsorted(poses[:, 0], t + 1e-9)) - 1, 0)
            _, x, y, yaw = poses[k]
            data.qpos[qadr:qadr + 7] = (x, y, z0, math.cos(yaw / 2), 0, 0, math.sin(yaw / 2))
            people = rec.latest(rec.people, t)
            if people is not None and len(mocap):
                data.mocap_pos[mocap, :2] = people[1]
            mujoco.mj_forward(model, data)
            left = view.render(data, np.array([x, y, yaw]), poses[:k + 1, 1:3])
            _, grid = rec.latest(rec.maps, t) or rec.maps[0]
            if grid is not gvd_map:
                tracker = tracker or TopologyTracker(grid.shape)
                tracker.observe(grid)
                segments = gvd_segments(tracker.graph(grid), grid)
                gvd_map = grid
            ter = rec.latest(rec.ters, t)
            goal = rec.latest(rec.goals, t)
            frontiers = find_frontiers(grid)
            content = PanelContent(
                grid=grid, gvd_segments=segments,
                ter_positions=None if ter is None else ter[1],
                ter_edges=None if ter is None else ter[2],
                ter_flags=None if ter is None else ter[3],
                frontier_cells=[f.cells for f in frontiers],
                frontier_gains=estimated_information_gain(grid, frontiers),
                goal=None if goal is None else goal[1], trajectory=poses[:k + 1, 1:3],
                pose=np.array([x, y, yaw]),
                people=None if people is None else people[1],
                people_radius=0.25 if people is None else people[2],
                text=(title, f"t = {t:7.1f} s (simulated)"))
            right = render_panel(content, config.width, config.height)
            writer.append(np.concatenate([left, right], axis=1))
            frames += 1
            shown.update()
    return {"video": str(out), "frames": frames, "duration_s": frames / config.fps}
