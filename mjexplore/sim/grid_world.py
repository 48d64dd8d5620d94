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
* kinematics log: the same samples and columns; the IMU's are NaN (no dynamics);
* people (``SimConfig.people``): the physics and kinematic worlds' crowd
  (:class:`~mjexplore.sim.people.Crowd`, the same random stream of the seed), walked every
  sample period with the robots' bodies where they are, its discs cast by every robot's
  lidar (:func:`~mjexplore.sim.lidar.ray_discs`, as the MuJoCo lidar casts them), a move
  into a person refused and counted as the kinematic world counts it.

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

from mjexplore.errors import UserInputError
from mjexplore.maps import GridMap, traversal_start
from mjexplore.robot import TURTLEBOT3_WAFFLE, MotionProfile, motion_profile
from mjexplore.scenes.scene import PHYSICS_TIMESTEP, SceneFiles, load_scene_files
from mjexplore.scenes.team import SILHOUETTE_HALF, SILHOUETTE_POS, robot_prefix
from mjexplore.sim.kinematics import KinematicsRecorder
from mjexplore.sim.lidar import LaserScan, LidarConfig, measure_ranges, ray_boxes, ray_discs
from mjexplore.sim.motion import (
    BODY_RADIUS,
    kinematic_step,
    mean_ramp_twist,
    ramp_command,
    wall_clearance,
)
from mjexplore.sim.people import Crowd
from mjexplore.sim.robot_world import (
    RobotWorld,
    new_crowd,
    people_contacts,
    people_to_walk,
    walk_crowd,
)
from mjexplore.sim.simulator import (
    BASE_BODY,
    COLLISION_GAP_S,
    NO_IMU,
    SimConfig,
    _steps_per,
    float_pose,
    robot_seed,
)

# Rays are cast this far past range_max, as the MuJoCo lidar's cutoff: noise may bring a
# return just beyond range_max back within it.
CAST_MARGIN = 0.1
SCAN_HEIGHT = 0.132  # base_scan above the floor, metres (the MJCF's).


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
        # A team's other robots (their ``_pose``), whose silhouettes stop the beams too.
        self.teammates: list = []
        # People walking in the building (a Crowd: ``positions`` (n, 2), ``config.radius``),
        # cast as upright cylinders taller than the scan plane; None: no one.
        self.people: Crowd | None = None

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
        people = self.people is not None and len(self.people.positions) > 0
        if self.teammates or people:
            origin, vec = self._beams(x, y, yaw)
            if self.teammates:
                self._cast_teammates(origin, vec)
            if people:
                self._cast_people(origin, vec)
        return self._dist

    def _beams(self, x, y, yaw) -> tuple[np.ndarray, np.ndarray]:
        """The scan's origin ((3,), ``map`` frame; under motion skew the origin of its last
        beam) and its beams' unit directions (n, 3), for the bodies cast on the walls."""
        bx, by, byaw = (float(np.ravel(v)[-1]) for v in (x, y, yaw))
        ox, oy = self._offset
        c, s = math.cos(byaw), math.sin(byaw)
        origin = np.array([bx + c * ox - s * oy, by + s * ox + c * oy, SCAN_HEIGHT])
        heading = np.asarray(yaw) + self._angles
        vec = np.column_stack([np.cos(heading), np.sin(heading), np.zeros(len(heading))])
        return origin, vec

    def _cast_teammates(self, origin: np.ndarray, vec: np.ndarray) -> None:
        """The teammates' silhouettes (the MuJoCo team's boxes, cast by
        :func:`~mjexplore.sim.lidar.ray_boxes`) where nearer than the walls."""
        dist = self._dist
        centres, rots = [], []
        reach = self.config.range_max + 0.3
        for r in self.teammates:
            rx, ry, ryaw = r._pose
            cx = rx + SILHOUETTE_POS[0] * math.cos(ryaw)
            cy = ry + SILHOUETTE_POS[0] * math.sin(ryaw)
            if math.hypot(cx - origin[0], cy - origin[1]) > reach:
                continue
            cr, sr = math.cos(ryaw), math.sin(ryaw)
            centres.append((cx, cy, SCAN_HEIGHT))
            rots.append(((cr, -sr, 0.0), (sr, cr, 0.0), (0.0, 0.0, 1.0)))
        if not centres:
            return
        hit, _, normal = ray_boxes(origin, vec, np.array(centres), np.array(rots),
                                   np.array(SILHOUETTE_HALF))
        nearer = (hit >= 0) & ((dist < 0) | (hit < dist))
        dist[nearer] = hit[nearer]
        self._cos[nearer] = np.abs(np.einsum("ij,ij->i", vec[nearer], normal[nearer]))

    def _cast_people(self, origin: np.ndarray, vec: np.ndarray) -> None:
        """The people's discs (cast by :func:`~mjexplore.sim.lidar.ray_discs`, as the
        MuJoCo lidar casts them) where nearer than the walls."""
        assert self.people is not None  # Cast only among people.
        centres = self.people.positions
        r = self.people.config.radius
        reach = self.config.range_max + CAST_MARGIN + r
        near = np.hypot(centres[:, 0] - origin[0], centres[:, 1] - origin[1]) <= reach
        if not near.any():
            return
        hit, normal = ray_discs(origin, vec, centres[near], r)
        dist = self._dist
        nearer = np.isfinite(hit) & ((dist < 0) | (hit < dist))
        dist[nearer] = hit[nearer]
        self._cos[nearer] = np.abs(np.einsum("ij,ij->i", vec[nearer, :2], normal[nearer]))

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
        starts: A team's start poses, one per robot (None: the robot alone at the scene's
            start). Robot 0 is this world, the others are grid robots of their own stepped
            with it (:meth:`step_all`) on one clock; each lidar also sees its teammates'
            silhouettes (the MuJoCo team's boxes), a move that would bring a robot's
            bounding circle into a teammate's is refused and counted as a robot-robot
            contact; robot ``i`` draws from :func:`~mjexplore.sim.simulator.robot_seed`.

    Attributes:
        crowd: The people walking in the building (a team's robots share one), or None.
        scene: Paths and facts of the loaded scene (ground truth, start pose).
        profile: The motion profile in force.
        lidar: The lidar (:class:`GridLidar`).
        odometry: The wheel odometry.
        collisions: Number of collisions with walls since reset; contacts less than
            ``COLLISION_GAP_S`` apart count as one.
    """

    timestep = PHYSICS_TIMESTEP

    def __init__(self, scene: str | os.PathLike | SceneFiles, config: SimConfig | None = None,
                 starts: list | None = None, *, _index: int = 0) -> None:
        self.config = config or SimConfig(dynamics="grid")
        self.scene = scene if isinstance(scene, SceneFiles) else load_scene_files(scene)
        if starts is not None:
            if self.config.scan_travel is not None:
                raise UserInputError("a team's grid world scans at the lidar's rate: drop "
                                     "scan_travel.")
            self.scene = dataclasses.replace(self.scene, start=float_pose(starts[0]))
        self.index = _index
        self.name = robot_prefix(_index).rstrip("/")
        self.robot_contacts = 0
        self._teammate_contact = False
        self._last_teammate = -math.inf
        self._refused_by_teammate = False
        self._kinematic_person = False
        self.robot_collisions = 0
        self._pair_last: dict[tuple[int, int], float] = {}
        self.robots: list[GridWorld] = [self]
        self._clearance = wall_clearance(self.scene.ground_truth)
        # The people robot 0 walks (the world's; checked before anything is built).
        self._walkers = None if _index else people_to_walk(self.config.people,
                                                           self.scene.ground_truth)
        self._crowd: Crowd | None = None
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
        if starts is not None and len(starts) > 1:
            self.robots += [GridWorld(dataclasses.replace(self.scene, start=float_pose(p)),
                                      dataclasses.replace(self.config,
                                                          seed=robot_seed(self.config.seed, i)),
                                      _index=i)
                            for i, p in enumerate(starts[1:], start=1)]
            for r in self.robots:
                r.robots = self.robots
                r.lidar.teammates = [o for o in self.robots if o is not r]
            self.reset_all()  # Again, with every robot in place.

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
    def crowd(self) -> Crowd | None:
        """The people walking in the building (robot 0's, shared by a team), or None."""
        return self.robots[0]._crowd

    def _people(self) -> Crowd | None:
        return self.crowd

    @property
    def is_upright(self) -> bool:
        """Always True: nothing tips over in the grid world."""
        return True

    @property
    def physics_fault(self) -> bool:
        """True once a robot's pose is not finite."""
        return not all(math.isfinite(v) for r in self.robots for v in r._pose)

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
        self._reset_people()
        if self._walkers is not None:  # Robot 0 among people: a new crowd, clear of all.
            assert self.scene.ground_truth is not None  # See __init__.
            self._crowd = new_crowd(self._walkers, self.scene.ground_truth, self.config.seed,
                                    [self._pose, *(r._pose for r in self.robots[1:])])
            for r in self.robots:
                r.lidar.people = self._crowd
        self.odometry.reset(self._wheels, 0.0, true_yaw=self._pose[2])
        self._kinematics.clear()
        self.lidar.clear_history()
        crowd = self.crowd
        if crowd is not None:
            self._teammate_contact = False  # Noted afresh at time 0.
            touch, gap = people_contacts(crowd, [self])
            self._note_people(bool(touch[0]), float(gap[0]))
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
                if self.crowd is not None:
                    self._walk_people()
                    self._contacts()
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

    # ------------------------------------------------------------------ a team

    def __len__(self) -> int:
        return len(self.robots)

    def poses(self) -> np.ndarray:
        """(n, 3) ground-truth (x, y, yaw) of every robot's ``base_link``."""
        return np.array([r.pose for r in self.robots])

    def reset_all(self) -> list[LaserScan]:
        """Puts every robot at rest at its start at time 0; returns each one's first scan
        (taken with every robot in place)."""
        for r in self.robots:
            r._pose = float_pose(r.scene.start)  # Everyone in place before the first scans.
        for r in self.robots:
            r.reset()
            r.robot_contacts = 0
            r._teammate_contact = False
            r._last_teammate = -math.inf
        self.robot_collisions = 0
        self._pair_last = {}
        return [r.latest_scan for r in self.robots]

    def step_all(self, duration: float) -> list[list[LaserScan]]:
        """Advances every robot by ``duration`` seconds on one clock (moves, then samples,
        then scans, on the same grids of steps); each robot's scans, oldest first."""
        end = self._steps + max(0, round(duration / self.timestep))
        sample, scan = self._sample_every, self._scan_every
        scans: list[list[LaserScan]] = [[] for _ in self.robots]
        while self._steps < end:
            stop = min((self._steps // sample + 1) * sample,
                       (self._steps // scan + 1) * scan, end)
            for r in self.robots:
                r._move(stop)
            if stop % sample == 0:
                if self.crowd is not None:
                    self._walk_people()
                self._contacts()
                for r in self.robots:
                    r._sample()
                    r._cmd_base = r._cmd
                    r._ramp()
            if stop % scan == 0:
                for r, out in zip(self.robots, scans):
                    out.append(r._take_scan())
        return scans

    def _walk_people(self) -> None:
        """The crowd's walk over a sample period, with the robots where they are now."""
        assert self.crowd is not None  # Walked only among people.
        walk_crowd(self.crowd, self._sample_every * self.timestep, self.robots)

    def _contacts(self) -> None:
        """Which robots touch a teammate now (a refused move), and the pairs' collisions;
        among people, each robot's contacts with them and its gap to the nearest."""
        pairs = set()
        touching = np.zeros(len(self.robots), bool)
        for r in self.robots:
            if not r._refused_by_teammate:
                continue
            cx, cy = r.body_centre
            for o in self.robots:
                ox, oy = o.body_centre
                if o is not r and math.hypot(cx - ox, cy - oy) < 2 * BODY_RADIUS + 0.01:
                    touching[[r.index, o.index]] = True
                    pairs.add((min(r.index, o.index), max(r.index, o.index)))
        for r in self.robots:
            r._note_teammate(bool(touching[r.index]))
        t = self.time
        for pair in pairs:
            if t - self._pair_last.get(pair, -math.inf) > COLLISION_GAP_S:
                self.robot_collisions += 1
            self._pair_last[pair] = t
        crowd = self.crowd
        if crowd is not None:
            people, gaps = people_contacts(crowd, self.robots)
            for r in self.robots:
                r._note_people(bool(people[r.index]), float(gaps[r.index]))

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
        """Moves the base from step ``self._steps`` to ``stop`` (and sets the step count);
        in a team or among people, a move into a teammate's or a person's body is
        refused."""
        if len(self.robots) > 1 or self.crowd is not None:
            before, centre = (self._pose, self._wheels), self.body_centre
            self._move_alone(stop)
            refused = self._moved_into_teammate(centre)
            self._refused_by_teammate = refused and not self._kinematic_person
            if refused:
                self._pose, self._wheels = before
                self._twist = (0.0, 0.0)
            return
        self._move_alone(stop)

    def _move_alone(self, stop: int) -> None:
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
