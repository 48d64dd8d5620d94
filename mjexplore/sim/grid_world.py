"""The grid world: the fastest training world, with no MuJoCo at all.

:class:`GridWorld` has :class:`~mjexplore.sim.simulator.Simulator`'s interface and the
kinematic mode's behaviour, on the scene's ground-truth grid instead of its MJCF:

* motion: the kinematic mode's (:mod:`mjexplore.sim.motion`): commands clipped to the
  motion profile and ramped by the same acceleration limiter every sample period, the
  base moved along the exact unicycle arc of the mean twist of each interval between
  sample and scan instants, on the same grid of 0.005 s physics steps
  (:data:`~mjexplore.scenes.scene.PHYSICS_TIMESTEP`);
* walls: every ground-truth cell that is not free (unknown ones too, as the MJCF has
  them); a move that would bring the body's bounding circle into one is refused and
  counted as a collision, as in the kinematic mode;
* lidar (:class:`GridLidar`): each beam walks the grid's cells (Amanatides-Woo, in numba,
  one call per scan) to the first wall cell and returns the distance to its face, which is
  where the MJCF's wall boxes are; the beam pattern, offset of ``base_scan``, limits,
  rate, stamps and error model (:func:`~mjexplore.sim.lidar.measure_ranges`, drawing from
  the generator seeded with ``SimConfig.seed`` in the same order) are the MuJoCo lidar's;
* odometry: :class:`~mjexplore.sim.odometry.WheelOdometry` on wheel angles that follow the
  moves, as in the kinematic mode: with exact odometry (``odometry_error='none'``) it
  equals the integrated pose (``odom_pose`` is the pose relative to ``odom_origin``);
* kinematics log: the same samples and columns; the IMU's are NaN (no dynamics).

So the grid and kinematic worlds drive the same trajectory for the same commands, and
their scans differ only by float rounding (a beam through a wall's corner may differ
where the boxes and the cells meet at a point).

For training, ``SimConfig.scan_travel`` (:class:`~mjexplore.sim.simulator.ScanTravel`)
scans by travel instead: a denser scan every ``distance`` driven or ``angle`` turned and
before each decision, which maps about as the lidar's rate does for a fraction of the
scans (training/gvn_v2.yaml uses it; ``tools/sim_to_sim.py`` measures it against physics).

``model`` and ``data`` exist for rendering only: the scene's MJCF is compiled on first use
and shows the robot at its pose; nothing is ever stepped.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os

import mujoco
import numba
import numpy as np
from scipy.ndimage import distance_transform_edt

from mjexplore.maps import GridMap, traversal_start
from mjexplore.robot import TURTLEBOT3_WAFFLE, MotionProfile, motion_profile
from mjexplore.scenes.scene import PHYSICS_TIMESTEP, SceneFiles, load_scene_files
from mjexplore.sim.kinematics import KinematicsRecorder
from mjexplore.sim.lidar import LaserScan, LidarConfig, measure_ranges
from mjexplore.sim.motion import kinematic_step, mean_ramp_twist, ramp_command, wall_clearance
from mjexplore.sim.robot_world import RobotWorld
from mjexplore.sim.simulator import BASE_BODY, COLLISION_GAP_S, NO_IMU, SimConfig, _steps_per

# Rays are cast this far past range_max, as the MuJoCo lidar's cutoff: noise may bring a
# return just beyond range_max back within it.
CAST_MARGIN = 0.1


@numba.njit(cache=True)
def cast_rays(cells, x0, y0, heading, reach, scale, dist, cos_incidence):
    """Casts rays on a grid until the first opaque cell.

    Each ray walks the cells it crosses (Amanatides-Woo) and jumps ahead where no opaque
    cell is near (so open space costs a few steps).

    Lengths are in cell units of the grid (x along columns, y along rows, the origin at the
    lower-left corner of cell (0, 0)) but for ``dist``.

    Args:
        cells: (rows, cols) int16 grid from :func:`ray_grid`: -1 where a cell stops a
            ray, else how far a ray may jump from any point of the cell.
        x0, y0: (n,) ray origins.
        heading: (n,) ray directions in radians, counter-clockwise from +x.
        reach: Longest ray; farther cells are not looked at.
        scale: ``dist`` is in cells times this (the resolution, for metres).
        dist: (n,) out: distance to the face of the first opaque cell, -1 for none within
            ``reach`` or the grid (0 from inside an opaque cell).
        cos_incidence: (n,) out: |cos| of the angle between the ray and the face's normal
            (1 where nothing was hit).
    """
    rows, cols = cells.shape
    for i in range(len(heading)):
        dx = math.cos(heading[i])
        dy = math.sin(heading[i])
        cx, cy, step_x, step_y, t_max_x, t_max_y, t_dx, t_dy = traversal_start(
            x0[i], y0[i], dx, dy)
        t = 0.0  # The ray's parameter where it entered the current cell.
        across_x = True  # Whether the last step crossed a face normal to x.
        dist[i] = -1.0
        cos_incidence[i] = 1.0
        while t <= reach and 0 <= cy < rows and 0 <= cx < cols:
            jump = cells[cy, cx]
            if jump < 0:
                dist[i] = t * scale
                if t > 0:
                    cos_incidence[i] = abs(dx) if across_x else abs(dy)
                break
            if jump > 1:  # Open space: restart the walk further on.
                t += jump
                cx, cy, step_x, step_y, t_max_x, t_max_y, t_dx, t_dy = traversal_start(
                    x0[i] + t * dx, y0[i] + t * dy, dx, dy)
                t_max_x += t
                t_max_y += t
            elif t_max_x < t_max_y:
                t = t_max_x
                cx += step_x
                t_max_x += t_dx
                across_x = True
            else:
                t = t_max_y
                cy += step_y
                t_max_y += t_dy
                across_x = False


def ray_grid(opaque: np.ndarray) -> np.ndarray:
    """The grid :func:`cast_rays` walks: -1 for opaque cells; elsewhere how far (whole
    cells) a ray may go from any point of the cell without entering an opaque one: the
    distance between cell centres to the nearest opaque cell less the half-diagonals of
    both cells, rounded down."""
    jump = np.floor(distance_transform_edt(~opaque) - math.sqrt(2.0))
    return np.where(opaque, -1, np.clip(jump, 0, np.iinfo(np.int16).max)).astype(np.int16)


class GridLidar:
    """A 2D lidar cast on a grid: the ground truth's cells that are not free are walls.

    Same interface and readings as :class:`~mjexplore.sim.lidar.Lidar`, given the robot
    base's pose instead of a MuJoCo state. With ``motion_skew``, the world reports the
    base's pose at each of its samples (:meth:`observe_base_pose`) and each beam is cast
    from the pose of its own instant, interpolated between them.

    Args:
        ground_truth: The grid.
        config: Lidar settings.
        rng: Generator for range noise and dropouts.
        offset: (x, y) of ``base_scan`` in ``base_link``, metres.
    """

    def __init__(self, ground_truth: GridMap, config: LidarConfig,
                 rng: np.random.Generator | None = None,
                 offset: tuple[float, float] = TURTLEBOT3_WAFFLE.scan_offset[:2]) -> None:
        self.config = config
        self.ground_truth = ground_truth
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._cells = ray_grid(~ground_truth.free)
        self._offset = (float(offset[0]), float(offset[1]))
        self._angles = config.angles
        n = config.num_beams
        self._dist = np.empty(n)
        self._cos = np.empty(n)
        self._period = 1.0 / config.rate_hz
        self.time_increment = -self._period / n if config.motion_skew else 0.0
        self._beam_dt = self.time_increment * np.arange(n)
        self._history: collections.deque[tuple[float, float, float, float]] = (
            collections.deque())

    def clear_history(self) -> None:
        """Forgets the poses observed so far (at a reset)."""
        self._history.clear()

    def observe_base_pose(self, t: float, x: float, y: float, yaw: float) -> None:
        """Records the base's pose (``map`` frame, metres, radians) at simulated time ``t``
        (seconds), for motion skew."""
        self._history.append((t, x, y, yaw))

    def _skewed_poses(self, x: float, y: float, yaw: float, stamp: float,
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The base's pose at each beam's instant, interpolated between the samples."""
        history = self._history
        while len(history) >= 2 and history[1][0] <= stamp - self._period:
            history.popleft()
        t, hx, hy, hyaw = np.array([*(h for h in history if h[0] < stamp - 1e-9),
                                    (stamp, x, y, yaw)]).T
        when = stamp + self._beam_dt
        return (np.interp(when, t, hx), np.interp(when, t, hy),
                np.interp(when, t, np.unwrap(hyaw)))

    def cast(self, x: float | np.ndarray, y: float | np.ndarray, yaw: float | np.ndarray,
             ) -> np.ndarray:
        """True distances (metres, -1 for no hit within range) of every beam with the base
        at (x, y, yaw) in the ``map`` frame: floats for all beams, or (n,) arrays, one pose
        per beam; one numba call. A view, valid until the next cast."""
        gt = self.ground_truth
        ox, oy = self._offset
        c, s = np.cos(yaw), np.sin(yaw)
        n = self.config.num_beams
        sx = (x + c * ox - s * oy - gt.origin[0]) / gt.resolution
        sy = (y + s * ox + c * oy - gt.origin[1]) / gt.resolution
        if np.ndim(sx) == 0:
            sx, sy = np.full(n, sx), np.full(n, sy)
        cast_rays(self._cells, sx, sy, yaw + self._angles,
                  (self.config.range_max + CAST_MARGIN) / gt.resolution, gt.resolution,
                  self._dist, self._cos)
        return self._dist

    def scan(self, x: float, y: float, yaw: float, stamp: float) -> LaserScan:
        """One scan with the base at (x, y, yaw) (``map`` frame) at simulated time
        ``stamp`` (seconds): beam 0's instant."""
        cfg = self.config
        if cfg.motion_skew:
            self.cast(*self._skewed_poses(x, y, yaw, stamp))
        else:
            self.cast(x, y, yaw)
        cos_incidence = self._cos if cfg.incidence_dropouts else None
        ranges = measure_ranges(self._dist, cfg, self.rng, cos_incidence)
        ox, oy = self._offset
        c, s = math.cos(yaw), math.sin(yaw)
        return LaserScan(stamp, ranges, self._angles, cfg.range_max,
                         np.array([x + c * ox - s * oy, y + s * ox + c * oy, yaw]),
                         self.time_increment)


class GridWorld(RobotWorld):
    """A scene's ground-truth grid with the robot driven by (v, omega) commands.

    The interface of :class:`~mjexplore.sim.simulator.Simulator` (see the module docstring
    for what differs); build it with :func:`mjexplore.sim.world.make_world` and
    ``SimConfig(dynamics='grid')``.

    Args:
        scene: A scene folder, its ``scene.xml``, or :class:`SceneFiles`; it needs its
            ground truth (``map.yaml``).
        config: Simulator settings (``dynamics`` and ``wheel_friction`` are not used).

    Attributes:
        scene: Paths and facts of the loaded scene (ground truth, start pose).
        profile: The motion profile in force.
        lidar: The lidar (:class:`GridLidar`).
        odometry: The wheel odometry.
        collisions: Number of collisions with walls since reset; contacts less than
            ``COLLISION_GAP_S`` apart count as one.
    """

    timestep = PHYSICS_TIMESTEP

    def __init__(self, scene: str | os.PathLike | SceneFiles, config: SimConfig | None = None):
        self.config = config or SimConfig(dynamics="grid")
        self.scene = scene if isinstance(scene, SceneFiles) else load_scene_files(scene)
        self._clearance = wall_clearance(self.scene.ground_truth)
        self.profile: MotionProfile = motion_profile(self.config.profile)
        self._sample_every = _steps_per(1.0 / self.config.sample_rate_hz, self.timestep,
                                        "sample")
        lidar_cfg = self.config.resolved_lidar()
        self._scan_every = _steps_per(1.0 / lidar_cfg.rate_hz, self.timestep, "lidar scan")
        travel = self.config.scan_travel
        if travel is not None:
            lidar_cfg = dataclasses.replace(
                lidar_cfg, num_beams=lidar_cfg.num_beams * travel.beam_factor)
        self._rng = np.random.default_rng(self.config.seed)
        assert self.scene.ground_truth is not None  # wall_clearance refused a scene without one.
        self.lidar = GridLidar(self.scene.ground_truth, lidar_cfg, self._rng)
        self._skew = lidar_cfg.motion_skew
        self.odometry = self.config.make_odometry()
        self._kinematics = KinematicsRecorder()
        self._model: mujoco.MjModel | None = None
        self._data: mujoco.MjData | None = None
        self.reset()

    # ------------------------------------------------------------------ state

    @property
    def time(self) -> float:
        """Simulated time since reset in seconds."""
        return self._steps * self.timestep

    @property
    def pose(self) -> np.ndarray:
        """Ground-truth (x, y, yaw) of ``base_link`` in the ``map`` (world) frame."""
        return np.array(self._pose)

    @property
    def velocity(self) -> np.ndarray:
        """Ground-truth (forward speed m/s, yaw rate rad/s) of ``base_link``."""
        return np.array(self._twist)

    @property
    def is_upright(self) -> bool:
        """Always True: nothing tips over in the grid world."""
        return True

    @property
    def physics_fault(self) -> bool:
        """True once the pose is not finite."""
        return not all(math.isfinite(v) for v in self._pose)

    def warnings(self) -> dict[str, int]:
        """No MuJoCo, no warnings: always empty."""
        return {}

    @property
    def model(self) -> mujoco.MjModel:
        """The scene's MuJoCo model, compiled on first use (for rendering; never stepped)."""
        if self._model is None:
            self._model = mujoco.MjModel.from_xml_path(str(self.scene.xml))
            self._data = mujoco.MjData(self._model)
        return self._model

    @property
    def data(self) -> mujoco.MjData:
        """A MuJoCo state of :attr:`model` with the robot at the current pose (for
        rendering)."""
        m = self.model
        d = self._data
        assert d is not None  # Made with the model.
        base = m.body(BASE_BODY).id
        i = m.jnt_qposadr[m.body_jntadr[base]]
        x, y, yaw = self._pose
        d.qpos[i:i + 7] = (x, y, m.body_pos[base][2], math.cos(yaw / 2), 0.0, 0.0,
                           math.sin(yaw / 2))
        mujoco.mj_kinematics(m, d)
        return d

    # ------------------------------------------------------------------ control

    def reset(self, pose: tuple[float, float, float] | None = None) -> LaserScan:
        """Puts the robot at rest at ``pose`` (default: the scene's start) at time 0.

        Returns:
            The first scan, taken at time 0.
        """
        x, y, yaw = self.scene.start if pose is None else pose
        self._start = np.array([x, y, yaw], dtype=float)
        self._pose = (float(x), float(y), math.remainder(float(yaw), 2 * math.pi))
        self._wheels = (0.0, 0.0)
        self._steps = 0
        self._target = (0.0, 0.0)
        self._cmd_base = (0.0, 0.0)
        self._cmd = (0.0, 0.0)
        self._twist = (0.0, 0.0)
        self.collisions = 0
        self._in_contact = self._blocked = False
        self._last_contact = -math.inf
        self.odometry.reset(self._wheels, 0.0, true_yaw=self._pose[2])
        self._kinematics.clear()
        self.lidar.clear_history()
        self._sample()
        return self._take_scan()

    def step(self, duration: float) -> list[LaserScan]:
        """Advances simulated time by ``duration`` seconds (rounded to physics steps).

        Returns:
            The scans taken during the step, oldest first: one per scan instant, or with
            ``scan_travel`` only those after enough travel.
        """
        end = self._steps + max(0, round(duration / self.timestep))
        sample, scan = self._sample_every, self._scan_every
        scans: list[LaserScan] = []
        while self._steps < end:
            stop = min((self._steps // sample + 1) * sample, (self._steps // scan + 1) * scan,
                       end)
            self._move(stop)
            if stop % sample == 0:
                self._sample()
                self._cmd_base = self._cmd
                self._ramp()
            if stop % scan == 0 and self._travelled():
                scans.append(self._take_scan())
        return scans

    def scan_now(self) -> LaserScan | None:
        """With ``scan_travel``, a scan at the current pose and time if the base has moved
        or turned since the last scan (the one the schedule skipped); the episode maps it
        before each decision. None otherwise (without ``scan_travel`` every scan instant
        has had its scan)."""
        if self.config.scan_travel is None or self._pose == self._scan_pose:
            return None
        return self._take_scan()

    # ------------------------------------------------------------------ internals

    def _take_scan(self) -> LaserScan:
        self._scan = self.lidar.scan(*self._pose, self.time)
        self._scan_pose = self._pose
        return self._scan

    def _travelled(self) -> bool:
        """Whether a scan is due at a scan instant: always, or with ``scan_travel`` once
        the base has moved or turned that much since the last scan."""
        travel = self.config.scan_travel
        if travel is None:
            return True
        (x, y, yaw), (x0, y0, yaw0) = self._pose, self._scan_pose
        return (math.hypot(x - x0, y - y0) >= travel.distance or
                abs(math.remainder(yaw - yaw0, 2 * math.pi)) >= travel.angle)

    def _move(self, stop: int) -> None:
        """Moves the base from step ``self._steps`` to ``stop`` (and sets the step count)."""
        twist = mean_ramp_twist(self._cmd_base, self._cmd, self._steps, stop,
                                self._sample_every)
        assert self.scene.ground_truth is not None  # See __init__.
        (x, y, yaw), self._twist, (left, right), self._blocked = kinematic_step(
            self._clearance, self.scene.ground_truth, self._pose, twist,
            (stop - self._steps) * self.timestep)
        self._pose = (x, y, math.remainder(yaw, 2 * math.pi))
        self._wheels = (self._wheels[0] + left, self._wheels[1] + right)
        self._steps = stop

    def _ramp(self) -> None:
        self._cmd = ramp_command(self._cmd_base, self._target, self.profile,
                                 self._sample_every * self.timestep)

    def _sample(self) -> None:
        t = self.time
        self.odometry.update(self._wheels, t, true_yaw=self._pose[2])
        self._kinematics.record(t, *self._twist, self._cmd, self._pose,
                                self.odometry.pose_tuple, NO_IMU)
        if self._skew:
            self.lidar.observe_base_pose(t, *self._pose)
        if self._blocked:
            if t - self._last_contact > COLLISION_GAP_S:
                self.collisions += 1
            self._last_contact = t
        self._in_contact = self._blocked
