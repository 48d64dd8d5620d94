"""Episode videos and still figures.

:class:`EpisodeVideo` is an episode observer: at a chosen video rate (simulated seconds per
frame, not every physics step) it renders the 3D scene (:class:`SceneView`) and the 2D map
panel (:func:`render_panel`) side by side into an H.264 MP4.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import cv2
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic
from mjexplore.io.video import VideoWriter
from mjexplore.render.panel import PanelContent, RobotOverlay, gvd_segments, render_panel
from mjexplore.render.scene_view import CameraConfig, SceneView
from mjexplore.topology.frontiers import estimated_information_gain

# The largest frame an H.264 video may have: level 6.2, the standard's highest (ITU-T H.264
# Table A-1, MaxFS), in macroblocks of 16 x 16 pixels (e.g. 8192 x 4352), and x264's largest
# side (it refuses larger frames: "invalid width x height").
MAX_FRAME_MACROBLOCKS = 139264
MAX_FRAME_SIDE = 16384


@dataclasses.dataclass(frozen=True, kw_only=True)
class VideoConfig:
    """Video settings.

    Attributes:
        width, height: Size of each of the two panels in pixels (the frame is 2 width x
            height); even numbers, the frame within H.264's largest (at most
            ``MAX_FRAME_SIDE`` pixels a side and ``MAX_FRAME_MACROBLOCKS`` macroblocks).
        fps: Frames per second of the video file.
        sim_seconds_per_frame: Simulated time between frames (the video rate): 1.0 at 20
            fps plays the episode 20 times faster than real time.
        camera: The 3D panel's camera.
    """

    width: int = 640
    height: int = 480
    fps: float = 20.0
    sim_seconds_per_frame: float = 1.0
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)

    def __post_init__(self) -> None:
        """Refuses sizes and rates no video can have (UserInputError, a ValueError)."""
        if self.width < 16 or self.height < 16 or self.width % 2 or self.height % 2:
            raise UserInputError("video width and height must be even and at least 16 pixels")
        if self.fps <= 0 or self.sim_seconds_per_frame <= 0:
            raise UserInputError("video fps and sim_seconds_per_frame must be positive")
        w, h = 2 * self.width, self.height  # The frame: two panels side by side.
        if max(w, h) > MAX_FRAME_SIDE or -(-w // 16) * -(-h // 16) > MAX_FRAME_MACROBLOCKS:
            raise UserInputError(
                f"video size {self.width}x{self.height} per panel makes {w}x{h} frames, larger "
                f"than an H.264 video can be (at most {MAX_FRAME_SIDE} pixels a side and "
                f"{MAX_FRAME_MACROBLOCKS * 256 / 1e6:.1f} million pixels, level 6.2): choose "
                "--video-size up to 4096x4352 per panel, e.g. 1920x1080.")


def encode_png_rgb(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def episode_panel(episode, width: int, height: int, ter=None, frontiers=None,
                  gains=None, title: str = "") -> np.ndarray:
    """The 2D panel of an episode's current state: the map, robot 0's goal, path and
    trajectory, a team's other robots in colours of their own, and the people (if the
    world has any) where they are."""
    lead, *others = episode.agents
    ratio = episode.curve[-1][1] if episode.curve else 0.0
    text = tuple(t for t in (title, f"t = {episode.time:7.1f} s (simulated)",
                             f"explored {100 * ratio:5.1f} %") if t)

    def planned(agent) -> np.ndarray | None:
        return agent.navigator.path if agent.navigator.status.value == "active" else None

    crowd = getattr(episode.world, "crowd", None)
    content = PanelContent(
        grid=episode.mapper.grid,
        gvd_segments=gvd_segments(episode.tracker.graph(episode.mapper.grid),
                                  episode.mapper.grid),
        ter_positions=None if ter is None else ter.positions,
        ter_edges=None if ter is None else ter.edges,
        ter_flags=None if ter is None else ter.flags,
        frontier_cells=None if frontiers is None else [f.cells for f in frontiers],
        frontier_gains=gains, goal=lead.goal, path=planned(lead),
        trajectory=lead.sim.kinematics_rows[:, 5:7], pose=lead.sim.pose, text=text,
        teammates=tuple(RobotOverlay(a.sim.pose, a.sim.kinematics_rows[:, 5:7], a.goal,
                                     planned(a)) for a in others),
        people=None if crowd is None else np.array(crowd.positions, float),
        people_radius=PanelContent.people_radius if crowd is None else
        float(crowd.config.radius))
    return render_panel(content, width, height)


def camera_target(episode, distance: float) -> tuple[np.ndarray, float]:
    """Where the 3D panel looks: robot 0 (x, y, yaw), or a team's centre with robot 0's
    heading, from ``distance`` metres or as far as keeps every robot in view."""
    poses = np.array([a.sim.pose for a in episode.agents])
    if len(poses) == 1:
        return poses[0], distance
    centre = poses[:, :2].mean(axis=0)
    spread = float(np.hypot(*(poses[:, :2] - centre).T).max())
    return np.array([*centre, poses[0, 2]]), max(distance, 2.5 * spread + 1.0)


class EpisodeVideo:
    """Episode observer writing a video (see the module docstring): frames at simulated
    times 0, period, 2 period, ... (taken at the scan of that instant) and the final state.

    Args:
        path: Output ``.mp4``.
        config: Video settings.
        title: Text on the 2D panel (e.g. scene / explorer / seed).
    """

    def __init__(self, path: str | os.PathLike, config: VideoConfig | None = None,
                 title: str = "") -> None:
        self.config = config or VideoConfig()
        self.path = Path(path)
        self.title = title
        self.writer = VideoWriter(self.path, self.config.fps)
        self._view: SceneView | None = None
        self._next = 0.0
        self._ter = None
        self._frontiers = None
        self._gains: np.ndarray | None = None
        self._episode = None
        self._last_frame_time = -1.0

    def frame(self, episode) -> np.ndarray:
        """The current composite frame (height, 2 width, 3)."""
        c = self.config
        world = episode.world
        target, distance = camera_target(episode, c.camera.distance)
        camera = dataclasses.replace(c.camera, distance=distance)
        if self._view is None:
            self._view = SceneView(world.model, c.width, c.height, camera)
        self._view.config = camera  # A team's camera backs off as the robots spread.
        left = self._view.render(world.data, target,
                                 episode.agents[0].sim.kinematics_rows[:, 5:7])
        right = episode_panel(episode, c.width, c.height, self._ter, self._frontiers,
                              self._gains, self.title)
        return np.concatenate([left, right], axis=1)

    def on_scan(self, agent, scan) -> None:
        episode = self._episode = agent.episode
        if scan.stamp + 1e-9 >= self._next:
            frame = self.frame(episode)
            self._last_frame_time = scan.stamp
            while scan.stamp + 1e-9 >= self._next:  # Periods shorter than a scan repeat it.
                self.writer.append(frame)
                self._next += self.config.sim_seconds_per_frame

    def on_decision(self, agent, state) -> None:
        ter = state.extras.get("ter")
        if ter is None:
            ter, _, _ = agent.tracker.ter(state.grid, state.pose)
            state.extras["ter"] = ter
        self._ter = ter
        self._frontiers = state.frontiers
        self._gains = estimated_information_gain(state.grid, state.frontiers)

    def on_step(self, episode) -> None:
        del episode

    def close(self) -> None:
        """Adds the final state (unless its frame is already in) and closes the file; always
        leaves a playable file."""
        try:
            ep = self._episode
            if ep is not None and ep.time > self._last_frame_time + 1e-9:
                self.writer.append(self.frame(ep))
        finally:
            self.writer.close()


def write_stills(episode, out_dir: str | os.PathLike, title: str = "",
                 render_3d: bool = False) -> list[Path]:
    """Still figures of an episode's end (the paper's Fig. 6 and Fig. 1 style).

    ``ter.png``: the final map with the driven trajectory and the final TER overlaid
    (1200 x 900). With ``render_3d``, also ``scene.png``: a bird's-eye 3D view of the whole
    scene with the trajectory (needs a GL backend).
    """
    out_dir = Path(out_dir)
    grid = episode.mapper.grid
    ter, frontiers, gains = episode.tracker.ter(grid, episode.agents[0].sim.pose)
    img = episode_panel(episode, 1200, 900, ter, frontiers, gains, title)
    written = [out_dir / "ter.png"]
    write_bytes_atomic(written[0], encode_png_rgb(img))
    if render_3d:
        rows, cols = grid.shape
        extent = max(rows, cols) * grid.resolution
        centre = np.array(grid.origin[:2]) + np.array([cols, rows]) * grid.resolution / 2
        view = SceneView(episode.world.model, 1200, 900, CameraConfig(
            distance=1.1 * extent, elevation=-70.0, azimuth=90.0))
        img = view.render(episode.world.data, np.array([*centre, 0.0]),
                          episode.agents[0].sim.kinematics_rows[:, 5:7])
        written.append(out_dir / "scene.png")
        write_bytes_atomic(written[1], encode_png_rgb(img))
    return written
