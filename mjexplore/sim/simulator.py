"""The MuJoCo simulator core: diff-drive robots with 2D lidars in a scene's world.

One world (:class:`Simulator`) owns the model, the data, the clock and its robots
(:class:`MujocoRobot`): a robot alone loads the scene's MJCF untouched and is the world's
robot 0; a team's model holds N copies of the robot (``starts``), which see and touch each
other, stepped together on the same grids of physics steps.

Time is simulated time only. Physics runs at the model's time step; three things happen
on fixed grids of physics steps:

* every sample period (``sample_rate_hz``, default 20 Hz): odometry update, kinematics
  and IMU sample, collision check, and one step of the acceleration limiter: the wheel
  speed set-points then ramp linearly inside MuJoCo (integrator actuators) to the limited
  command (within the wheels' speed limit) by the end of the period;
* every scan period (``LidarConfig.rate_hz``, default 10 Hz): one lidar scan;
* a controller calls :meth:`Simulator.command` whenever it likes (typically 10 Hz).

Between those instants MuJoCo steps with ``mj_step(..., nstep=k)``, so no Python runs per
physics step.

``dynamics='kinematic'`` is a faster fidelity mode for policy training: no contact dynamics;
the base follows the acceleration-limited command exactly (unicycle model, integrated in
closed form over each interval), wheel angles follow the wheel speeds (so odometry reads
the truth), and a move that would bring the body's bounding circle into a wall of the
ground truth is refused and counted as a collision. Lidar, sampling and timing are the
same as in physics mode, so everything downstream sees the same kinds of data (but the
IMU's, which are NaN: there are no dynamics to measure). The motion model is
:mod:`mjexplore.sim.motion`.

``dynamics='grid'`` is the fastest: the same motion as the kinematic mode without MuJoCo,
the lidar cast on the ground-truth grid (:class:`mjexplore.sim.grid_world.GridWorld`;
:func:`mjexplore.sim.world.make_world` builds the world any ``dynamics`` asks for).
"""

from __future__ import annotations

import dataclasses
import math
import os

import mujoco
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.robot import TURTLEBOT3_WAFFLE, MotionProfile, motion_profile
from mjexplore.scenes.people import PERSON, add_people
from mjexplore.scenes.scene import SceneFiles, load_scene_files
from mjexplore.scenes.team import SILHOUETTE, robot_prefix, team_spec
from mjexplore.sim.kinematics import KinematicsRecorder
from mjexplore.sim.lidar import LaserScan, Lidar, LidarConfig
from mjexplore.sim.motion import (  # noqa: F401 (re-exported)
    BODY_CENTRE_X,
    BODY_RADIUS,
    kinematic_step,
    mean_ramp_twist,
    ramp_command,
    wall_clearance,
)
from mjexplore.sim.odometry import (
    HEADINGS,
    OdometryErrorConfig,
    WheelOdometry,
    odometry_error_config,
    wheel_odometry,
)
from mjexplore.sim.people import Crowd, PeopleConfig
from mjexplore.sim.robot_world import (  # noqa: F401 (PEOPLE_STREAM re-exported)
    COLLISION_GAP_S,
    PEOPLE_STREAM,
    RobotWorld,
    new_crowd,
    people_contacts,
    people_to_walk,
    walk_crowd,
)

BASE_BODY = "base_link"
SCAN_SITE = "base_scan"
WHEEL_JOINTS = ("wheel_left_joint", "wheel_right_joint")
WHEEL_ACTUATORS = ("wheel_left", "wheel_right")
WHEEL_GEOMS = ("wheel_left_collision", "wheel_right_collision")
IMU_SENSORS = ("imu_gyro", "imu_accel")
# IMU readings where there are none: the kinematic mode has no dynamics to measure.
NO_IMU = (math.nan,) * 6
UPRIGHT_COS = math.cos(math.radians(30.0))
DYNAMICS = ("physics", "kinematic", "grid")


@dataclasses.dataclass(frozen=True, kw_only=True)
class ScanTravel:
    """The grid world's training scan schedule: scans by travel instead of at the lidar's
    rate.

    At a scan instant a scan is taken only once the base has moved ``distance`` or turned
    ``angle`` since the last one, and the episode asks for one before each decision
    (:meth:`~mjexplore.sim.grid_world.GridWorld.scan_now`). Consecutive scans 5 cm apart add
    little, but they sweep each beam over the cells between the beams' far ends (1 degree
    is 10 cm at 6 m): sparser scans leave holes there, which read as frontiers and cost
    exploration time. Each scan therefore casts ``beam_factor`` times the lidar's beams,
    evenly over its field of view, so that the map fills as it does at the lidar's rate.

    Attributes:
        distance: Metres driven between scans.
        angle: Radians turned between scans.
        beam_factor: Beams cast per beam of the lidar.
    """

    distance: float = 0.25
    angle: float = 0.5
    beam_factor: int = 2

    def __post_init__(self) -> None:
        if not (self.distance > 0 and self.angle > 0 and self.beam_factor >= 1):
            raise UserInputError(f"scan_travel {self!r} needs distance > 0 (m), angle > 0 (rad) "
                                 "and beam_factor >= 1.")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SimConfig:
    """Simulator settings.

    Attributes:
        profile: Motion profile name ('sim' or 'real'): speed and acceleration limits.
        lidar: Lidar settings; None uses the defaults with the profile's range.
        sample_rate_hz: Rate of odometry, kinematics samples, collision checks and the
            acceleration limiter, in Hz of simulated time. Its period must be a whole
            number of physics steps.
        seed: Seed for sensor noise.
        dynamics: 'physics' (MuJoCo contact dynamics), 'kinematic' or 'grid' (training
            modes, see the module docstring; 'grid' needs :func:`~mjexplore.sim.world.make_world`).
        wheel_friction: Sliding friction coefficient of the drive wheels' contacts (the
            wheels' friction wins over the floor's). 1.0 is rubber on an indoor floor;
            turtlebot3_gazebo's 0.1 lets the wheels slip above about 0.6 m/s^2.
        odometry_error: The wheel odometry's errors: 'none' (exact geometry), 'typical'
            or an :class:`~mjexplore.sim.odometry.OdometryErrorConfig`; drawn from ``seed``.
        odometry_heading: Where the odometry's heading comes from: 'wheels' (their
            difference over the track width) or 'imu' (the gyro, as ``turtlebot3_node``
            with ``use_imu``; its errors are ``odometry_error``'s ``gyro_*``).
        scan_travel: Grid world only (a training setting): scans by travel
            (:class:`ScanTravel`); None scans at the lidar's rate.
        people: Pedestrians walking in the building (:class:`~mjexplore.sim.people.
            PeopleConfig`; in every world: MuJoCo bodies in the physics and kinematic
            worlds, discs on the grid world's ground truth); None: nobody.
    """

    profile: str = "sim"
    lidar: LidarConfig | None = None
    sample_rate_hz: float = 20.0
    seed: int = 0
    dynamics: str = "physics"
    wheel_friction: float = 1.0
    odometry_error: str | OdometryErrorConfig = "none"
    odometry_heading: str = "wheels"
    scan_travel: ScanTravel | None = None
    people: PeopleConfig | None = None

    def __post_init__(self) -> None:
        odometry_error_config(self.odometry_error)  # Refuses an unknown preset now.
        if self.odometry_heading not in HEADINGS:
            raise UserInputError(f"odometry_heading {self.odometry_heading!r} is unknown: use "
                                 f"one of {', '.join(HEADINGS)}.")
        if self.scan_travel is not None and self.dynamics != "grid":
            raise UserInputError(f"scan_travel is a grid-world setting; the {self.dynamics} "
                                 "world scans at the lidar's rate: drop scan_travel or use "
                                 "dynamics: grid.")
        if not self.wheel_friction > 0:
            raise UserInputError(f"wheel_friction {self.wheel_friction} must be positive.")
        if self.dynamics not in DYNAMICS:
            raise UserInputError(f"dynamics {self.dynamics!r} is unknown: use one of "
                                 f"{', '.join(DYNAMICS)}.")

    def resolved_lidar(self) -> LidarConfig:
        return self.lidar or LidarConfig(range_max=motion_profile(self.profile).lidar_range)

    def make_odometry(self) -> WheelOdometry:
        """The robot's odometry, its errors drawn from ``seed``."""
        return wheel_odometry(self.odometry_error, self.odometry_heading, self.seed)


def _steps_per(period: float, timestep: float, what: str) -> int:
    steps = period / timestep
    if steps < 1 or abs(steps - round(steps)) > 1e-6:
        raise UserInputError(f"{what} period {period:g} s is not a whole number of physics steps "
                             f"of {timestep:g} s: choose a rate whose period is a multiple of it.")
    return int(round(steps))


def yaw_from_quat(q: np.ndarray) -> float:
    """Yaw (rotation about z) of a (w, x, y, z) quaternion, radians."""
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def keep_awake(model: mujoco.MjModel, body: int) -> None:
    """Turns on MuJoCo's sleeping (``mjENBL_SLEEP``) with the kinematic tree of ``body``
    (a robot's base) never asleep.

    The robot must answer every command, so its tree never sleeps; the walls (geoms of the
    world body) are static, and with sleeping on MuJoCo skips their collision checks with
    one another and whatever else is at rest, which makes a step on a large map about
    twice as fast (100 x 100 m office, 1510 wall boxes: 43 us against 19 us). The awake
    robot's arithmetic is unchanged: its trajectory is the same bit for bit.
    """
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
    model.tree_sleep_policy[model.body_treeid[body]] = mujoco.mjtSleepPolicy.mjSLEEP_NEVER


def compile_scene(scene: SceneFiles) -> mujoco.MjModel:
    """The scene's compiled MJCF.

    Raises:
        UserInputError: it does not compile (the message has MuJoCo's reason and the fix).
    """
    try:
        return mujoco.MjModel.from_xml_path(str(scene.xml))
    except ValueError as exc:
        raise UserInputError(f"MJCF {str(scene.xml)!r} failed to compile: {exc}. Fix the "
                             "file or regenerate it with 'mjexplore scene-gen'.") from None


def robot_seed(seed: int, i: int) -> int:
    """The seed of robot ``i``'s noise and errors: ``seed`` itself for robot 0."""
    if i == 0:
        return seed
    return int(np.random.SeedSequence([seed, i]).generate_state(1)[0])


def float_pose(values) -> tuple[float, float, float]:
    """A pose (x, y, yaw) given as any three numbers, as floats."""
    x, y, yaw = (float(v) for v in values)
    return x, y, yaw


class MujocoRobot(RobotWorld):
    """One robot of a :class:`Simulator`'s model: its addresses in the model, lidar, wheel
    odometry, kinematics log, acceleration limiter and contacts; the world steps it.

    Attributes:
        index: The robot's number in the world.
        name: Its namespace (``robot_{index}`` in a team).
        lidar: The lidar (a teammate's silhouette stops its beams too).
        collisions: Number of collisions with walls since reset; contacts less than
            ``COLLISION_GAP_S`` apart count as one.
        robot_contacts: Contacts with teammates since reset, counted the same way.
    """

    config: SimConfig
    scene: SceneFiles
    model: mujoco.MjModel
    data: mujoco.MjData
    _sample_every: int
    _scan_every: int
    _clearance: np.ndarray | None

    def __init__(self, world: Simulator, index: int, prefix: str,
                 silhouettes: list[int]) -> None:  # noqa: D107
        self._world = world
        self.index = index
        self.name = prefix.rstrip("/") or "robot_0"
        self.config = dataclasses.replace(world.config, seed=robot_seed(world.config.seed,
                                                                       index))
        self.scene = world.scene
        self.model, self.data = world.model, world.data
        self.profile: MotionProfile = world.profile
        self._bind_robot(prefix)
        self._sample_every = world._sample_every
        self._scan_every = world._scan_every
        self._clearance = world._clearance
        self._rng = np.random.default_rng(self.config.seed)
        lidar_cfg = self.config.resolved_lidar()
        self.lidar = Lidar(self.model, prefix + SCAN_SITE, lidar_cfg, self._rng, silhouettes)
        self._skew = lidar_cfg.motion_skew
        self.odometry = self.config.make_odometry()
        self._kinematics = KinematicsRecorder()
        self._start = np.zeros(3)

    def _bind_robot(self, prefix: str) -> None:
        """Finds the robot whose MJCF names start with ``prefix`` (``""`` for a scene's one
        robot; ``robot_0/``... in a team's model) and sets its addresses."""
        m = self.model
        try:
            self._base = m.body(prefix + BASE_BODY).id
            self._wheel_qpos = np.array([m.joint(prefix + j).qposadr[0] for j in WHEEL_JOINTS])
            self._act_left, self._act_right = (m.actuator(prefix + a).id
                                               for a in WHEEL_ACTUATORS)
            self._actadr_left, self._actadr_right = (m.actuator_actadr[i] for i in (
                self._act_left, self._act_right))
            m.site(prefix + SCAN_SITE)
            wheel_geoms = [m.geom(prefix + g).id for g in WHEEL_GEOMS]
        except KeyError as exc:
            raise UserInputError(f"MJCF {str(self.scene.xml)!r} lacks the robot's {exc}: include "
                                 "assets/turtlebot3_waffle/robot.xml.") from None
        m.geom_friction[wheel_geoms, 0] = self.config.wheel_friction
        keep_awake(m, self._base)
        # The IMU's (gyro, accelerometer) sensordata addresses; an MJCF from before the
        # IMU has none, and its IMU columns are NaN.
        names = [m.sensor(i).name for i in range(m.nsensor)]
        imu = [prefix + n for n in IMU_SENSORS]
        self._imu_adr = tuple(int(m.sensor_adr[names.index(n)]) for n in imu) if all(
            n in names for n in imu) else None
        free = m.body_jntadr[self._base]
        if m.jnt_type[free] != mujoco.mjtJoint.mjJNT_FREE:
            raise UserInputError("the robot's base_link must have a free joint.")
        self._qpos0 = m.jnt_qposadr[free]
        self._qvel0 = m.jnt_dofadr[free]
        self._z0 = float(m.body_pos[self._base][2])

    # ------------------------------------------------------------------ state

    @property
    def _steps(self) -> int:  # type: ignore[override]
        """Physics steps of the world since reset (its clock; the robot never steps)."""
        return self._world._world_steps

    @property
    def time(self) -> float:
        """Simulated time since reset in seconds."""
        return self._world._world_steps * self.model.opt.timestep

    @property
    def pose(self) -> np.ndarray:
        """Ground-truth (x, y, yaw) of ``base_link`` in the ``map`` (world) frame."""
        q = self.data.qpos[self._qpos0:self._qpos0 + 7]
        return np.array([q[0], q[1], yaw_from_quat(q[3:7])])

    @property
    def velocity(self) -> np.ndarray:
        """Ground-truth (forward speed m/s, yaw rate rad/s) of ``base_link``."""
        q = self.data.qpos[self._qpos0 + 3:self._qpos0 + 7]
        yaw = yaw_from_quat(q)
        lin = self.data.qvel[self._qvel0:self._qvel0 + 3]
        return np.array([lin[0] * math.cos(yaw) + lin[1] * math.sin(yaw),
                         self.data.qvel[self._qvel0 + 5]])

    @property
    def is_upright(self) -> bool:
        """False if the base is tilted more than 30 degrees (tipped over)."""
        return bool(self.data.xmat[self._base][8] > UPRIGHT_COS)

    @property
    def physics_fault(self) -> bool:
        """True once the state is not finite or MuJoCo has reset an unstable simulation
        (``mjWARN_BADQACC``): the episode cannot go on."""
        d = self.data
        return bool(d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0 or
                    not np.isfinite(d.qpos).all() or not np.isfinite(d.qvel).all())

    def warnings(self) -> dict[str, int]:
        """MuJoCo warnings raised since reset, by kind (empty when none)."""
        return {mujoco.mjtWarning(i).name: int(w.number)
                for i, w in enumerate(self.data.warning) if w.number}

    def _people(self) -> Crowd | None:
        return self._world.crowd

    # ------------------------------------------------------------------ the world's calls

    def _place(self, pose: tuple[float, float, float]) -> None:
        x, y, yaw = pose
        self.data.qpos[self._qpos0:self._qpos0 + 7] = [x, y, self._z0, math.cos(yaw / 2), 0, 0,
                                                       math.sin(yaw / 2)]
        self._start = np.array([x, y, yaw], dtype=float)

    def _reset_state(self) -> None:
        """At rest, no command, nothing recorded (after the world placed every robot)."""
        self._target = (0.0, 0.0)
        self._cmd_base = (0.0, 0.0)
        self._cmd = (0.0, 0.0)
        self._apply_cmd()
        self.collisions = 0
        self.robot_contacts = 0
        self._in_contact = False
        self._teammate_contact = False
        self._last_contact = -math.inf
        self._last_teammate = -math.inf
        self._kinematic_contact = False
        self._kinematic_teammate = False
        self._reset_people()
        self.odometry.reset(self.data.qpos[self._wheel_qpos], 0.0, true_yaw=self._start[2])
        self._kinematics.clear()
        self.lidar.clear_history()

    # These run every sample period: plain floats, no small numpy arrays.

    def _move_kinematic(self, stop: int) -> None:
        """Moves the base from the world's step to ``stop`` along the commanded unicycle
        path (the wheel set-points ramp linearly over each sample period); a move that
        would bring the body into a teammate's (bounding circles, nearer than before) is
        refused as well as one into a wall."""
        # Kinematic dynamics: the clearance was made from the ground truth.
        assert self._clearance is not None and self.scene.ground_truth is not None
        d = self.data
        q = d.qpos
        i = self._qpos0
        crowd = self._world.crowd
        teammates = len(self._world.robots) > 1 or crowd is not None
        if teammates:
            before = q[i:i + 7].copy(), q[self._wheel_qpos].copy()
            centre = self.body_centre
        v, w = mean_ramp_twist(self._cmd_base, self._cmd, self._steps, stop,
                               self._sample_every)
        duration = (stop - self._steps) * self.model.opt.timestep
        x, y = float(q[i]), float(q[i + 1])
        yaw = math.atan2(2.0 * (q[i + 3] * q[i + 6] + q[i + 4] * q[i + 5]),
                         1.0 - 2.0 * (q[i + 5] ** 2 + q[i + 6] ** 2))
        (nx, ny, nyaw), (v, w), (left, right), self._kinematic_contact = kinematic_step(
            self._clearance, self.scene.ground_truth, (x, y, yaw), (v, w), duration)
        q[i:i + 7] = (nx, ny, self._z0, math.cos(nyaw / 2), 0.0, 0.0, math.sin(nyaw / 2))
        q[self._wheel_qpos[0]] += left
        q[self._wheel_qpos[1]] += right
        j = self._qvel0
        d.qvel[j:j + 6] = (v * math.cos(nyaw), v * math.sin(nyaw), 0.0, 0.0, 0.0, w)
        if teammates:
            refused = self._moved_into_teammate(centre)
            self._kinematic_teammate = refused and not self._kinematic_person
            if refused:
                q[i:i + 7], q[self._wheel_qpos] = before
                d.qvel[j:j + 6] = 0.0

    def _ramp(self) -> None:
        self._cmd = ramp_command(self._cmd_base, self._target, self.profile,
                                 self._sample_every * self.model.opt.timestep)
        self._apply_cmd()

    def _apply_cmd(self) -> None:
        # The wheel actuators integrate ctrl (wheel acceleration) into their speed
        # set-point; choose ctrl so that the set-point reaches the wheel speeds of
        # self._cmd exactly at the end of this sample period.
        v, w = self._cmd
        half = TURTLEBOT3_WAFFLE.wheel_separation / 2
        r = TURTLEBOT3_WAFFLE.wheel_radius
        d = self.data
        period = self._sample_every * self.model.opt.timestep
        d.ctrl[self._act_left] = ((v - w * half) / r - d.act[self._actadr_left]) / period
        d.ctrl[self._act_right] = ((v + w * half) / r - d.act[self._actadr_right]) / period

    def _sample(self) -> None:
        d = self.data
        t = self.time
        qpos = d.qpos
        left, right = qpos[self._wheel_qpos[0]], qpos[self._wheel_qpos[1]]
        x, y, _, qw, qx, qy, qz = qpos[self._qpos0:self._qpos0 + 7].tolist()
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        self.odometry.update((left, right), t, true_yaw=yaw)
        vx, vy, _, _, _, wz = d.qvel[self._qvel0:self._qvel0 + 6].tolist()
        v = vx * math.cos(yaw) + vy * math.sin(yaw)
        if self._imu_adr is None or self._clearance is not None:
            imu = NO_IMU
        else:
            g, a = self._imu_adr
            imu = (*d.sensordata[g:g + 3].tolist(), *d.sensordata[a:a + 3].tolist())
        self._kinematics.record(t, v, wz, self._cmd, (x, y, yaw), self.odometry.pose_tuple, imu)
        if self._skew:
            self.lidar.observe_base_pose(t, x, y, yaw)
        touching = self._touching()
        if touching:
            if t - self._last_contact > COLLISION_GAP_S:
                self.collisions += 1
            self._last_contact = t
        self._in_contact = touching

    def _touching(self) -> bool:
        """Whether the robot touches a wall now (a refused kinematic move counts;
        teammates are counted apart)."""
        if self._clearance is not None:
            return self._kinematic_contact
        return bool(self._world._wall_touch[self.index])


class Simulator(MujocoRobot):
    """A scene's MuJoCo world with its robots driven by (v, omega) commands; the world is
    also its robot 0, so that a robot alone is driven through it.

    Args:
        scene: A scene folder, its ``scene.xml``, any MJCF containing the robot, or
            :class:`SceneFiles`.
        config: Simulator settings (``seed``: robot 0's; robot ``i``'s is derived from it,
            :func:`robot_seed`).
        starts: None: the scene's one robot, its MJCF untouched. Otherwise one pose per
            robot: the scene's MJCF with its robot replaced by that many copies
            (:func:`~mjexplore.scenes.team.team_spec`, names prefixed ``robot_{i}/``), that
            see each other (each lidar casts against the others' silhouettes) and collide.

    Attributes:
        model: The compiled ``MjModel``.
        data: Its ``MjData``.
        scene: Paths and facts of the loaded scene (ground truth, start pose).
        profile: The motion profile in force.
        robots: The robots, robot 0 (this object) first.
        robot_collisions: Robot-robot contacts since reset per pair, contacts less than
            ``COLLISION_GAP_S`` apart counting as one.
    """

    def __init__(self, scene: str | os.PathLike | SceneFiles, config: SimConfig | None = None,
                 starts: list | None = None):
        self.config = config or SimConfig()
        if self.config.dynamics == "grid":
            raise UserInputError("dynamics 'grid' runs without MuJoCo: build the world with "
                                 "mjexplore.sim.world.make_world(scene, config).")
        self.scene = scene if isinstance(scene, SceneFiles) else load_scene_files(scene)
        # Checked before a model with that many bodies is built.
        people = self._walkers = people_to_walk(self.config.people, self.scene.ground_truth)
        crowd = people is not None
        if starts is None and not crowd:
            self.model = compile_scene(self.scene)
            prefixes = [""]
            self.starts = [float_pose(self.scene.start)]
        else:
            if starts is None:  # A robot alone among people: the scene's robot, untouched.
                self.starts = [float_pose(self.scene.start)]
                prefixes = [""]
                spec = mujoco.MjSpec.from_file(str(self.scene.xml))
            else:
                self.starts = [float_pose(p) for p in starts]
                prefixes = [robot_prefix(i) for i in range(len(self.starts))]
                spec = team_spec(self.scene.xml, self.starts)
            if crowd:
                assert people is not None
                add_people(spec, people.count, people.radius, people.height)
            try:
                self.model = spec.compile()
            except ValueError as exc:
                raise UserInputError(f"the MJCF made from {str(self.scene.xml)!r} failed to "
                                     f"compile: {exc}. Regenerate the scene with "
                                     "'mjexplore scene-gen'.") from None
        self.data = mujoco.MjData(self.model)
        self.profile = motion_profile(self.config.profile)
        m = self.model
        # Walls are static, so any contact with one involves a robot.
        self._is_wall_geom = (m.geom_bodyid == 0) & (m.geom_group == 0) & (
            m.geom_type != mujoco.mjtGeom.mjGEOM_PLANE)
        dt = m.opt.timestep
        self._sample_every = _steps_per(1.0 / self.config.sample_rate_hz, dt, "sample")
        self._scan_every = _steps_per(1.0 / self.config.resolved_lidar().rate_hz, dt,
                                      "lidar scan")
        self._clearance = None
        if self.config.dynamics == "kinematic":
            if self.scene.ground_truth is None:
                raise UserInputError("the kinematic world needs the scene's ground-truth map.")
            self._clearance = wall_clearance(self.scene.ground_truth)
        self._world_steps = 0
        self._wall_touch = np.zeros(len(prefixes), bool)
        silhouettes = [] if len(prefixes) == 1 else \
            [m.geom(p + SILHOUETTE).id for p in prefixes]
        body_robot = np.full(m.nbody, -1)
        for i, prefix in enumerate(prefixes):
            body_robot[m.body_rootid == m.body(prefix + BASE_BODY).id] = i
        self.geom_robot = body_robot[m.geom_bodyid]
        # The people's mocap slots, in order, and which geoms are theirs.
        count = people.count if crowd and people is not None else 0
        self._person_mocap = np.array([m.body(PERSON.format(i)).mocapid[0]
                                       for i in range(count)], np.int64)
        self._is_person_geom = np.isin(m.geom_bodyid, [m.body(PERSON.format(i)).id
                                                       for i in range(count)])
        self.crowd: Crowd | None = None
        self.robots: list[MujocoRobot] = []
        others = [[g for j, g in enumerate(silhouettes) if j != i] for i in range(len(prefixes))]
        MujocoRobot.__init__(self, self, 0, prefixes[0], others[0])
        self.robots = [self] + [MujocoRobot(self, i, prefixes[i], others[i])
                                for i in range(1, len(prefixes))]
        for r in self.robots[1:]:
            r.robots = self.robots
        for r in self.robots[1:]:  # One tile cache of the walls for all lidars.
            r.lidar.static_scene = self.lidar.static_scene
        self.reset()

    def __len__(self) -> int:
        return len(self.robots)

    def poses(self) -> np.ndarray:
        """(n, 3) ground-truth (x, y, yaw) of every robot's ``base_link``."""
        return np.array([r.pose for r in self.robots])

    # ------------------------------------------------------------------ control

    def reset(self, pose: tuple[float, float, float] | None = None,
              poses: list | None = None) -> LaserScan:
        """Puts the robots at rest at time 0: robot 0 at ``pose`` (default: its start, the
        scene's for a robot alone), or every robot at ``poses``.

        Returns:
            Robot 0's first scan, taken at time 0 (each robot's is its ``latest_scan``).
        """
        m, d = self.model, self.data
        if poses is None:
            poses = [self.starts[0] if pose is None else pose, *self.starts[1:]]
        poses = [float_pose(p) for p in poses]
        if len(poses) != len(self.robots):
            raise ValueError(f"{len(poses)} poses for {len(self.robots)} robots")
        mujoco.mj_resetData(m, d)
        self._world_steps = 0
        for r, p in zip(self.robots, poses):
            r._place(p)
        if len(self._person_mocap):
            assert self._walkers is not None and self.scene.ground_truth is not None
            # Their own stream of the seed: a run without people draws nothing of it.
            self.crowd = new_crowd(self._walkers, self.scene.ground_truth,
                                   self.config.seed, poses)
            self._place_people()
            for r in self.robots:
                r.lidar.people = self.crowd
        mujoco.mj_forward(m, d)
        self.robot_collisions = 0
        self._pair_last: dict[tuple[int, int], float] = {}
        for r in self.robots:
            r._reset_state()
        self._sample_all()
        for r in self.robots:
            r._scan = r.lidar.scan(d, 0.0)
        return self._scan

    def step(self, duration: float) -> list[LaserScan]:
        """Advances simulated time by ``duration`` seconds (rounded to physics steps).

        Returns:
            Robot 0's scans taken during the step, oldest first (:meth:`step_all`: every
            robot's).
        """
        return self.step_all(duration)[0]

    def step_all(self, duration: float) -> list[list[LaserScan]]:
        """Advances simulated time by ``duration`` seconds (rounded to physics steps).

        Returns:
            Each robot's scans taken during the step, oldest first.
        """
        m, d = self.model, self.data
        target = self._world_steps + max(0, round(duration / m.opt.timestep))
        scans: list[list[LaserScan]] = [[] for _ in self.robots]
        while self._world_steps < target:
            steps = self._world_steps
            next_sample = (steps // self._sample_every + 1) * self._sample_every
            next_scan = (steps // self._scan_every + 1) * self._scan_every
            stop = min(next_sample, next_scan, target)
            if self._clearance is None:
                mujoco.mj_step(m, d, nstep=stop - steps)
            else:
                for r in self.robots:
                    r._move_kinematic(stop)
            self._world_steps = stop
            if stop % self._sample_every == 0:
                if self.crowd is not None:
                    walk_crowd(self.crowd, self._sample_every * m.opt.timestep, self.robots)
                    self._place_people()
                self._sample_all()
                for r in self.robots:
                    r._cmd_base = r._cmd
                    r._ramp()
            if stop % self._scan_every == 0:
                mujoco.mj_kinematics(m, d)
                t = self.time
                for r, out in zip(self.robots, scans):
                    r._scan = r.lidar.scan(d, t)
                    out.append(r._scan)
        return scans

    def _place_people(self) -> None:
        """Moves the people's bodies to where the crowd has them."""
        assert self.crowd is not None
        pos = self.data.mocap_pos
        pos[self._person_mocap, :2] = self.crowd.positions
        pos[self._person_mocap, 2] = 0.0

    def _sample_all(self) -> None:
        """Contacts, then every robot's sample (odometry, kinematics, collisions)."""
        if len(self.robots) == 1 and self.crowd is None:
            # A robot alone: its wall contacts only (this runs at every sample: 20 Hz; the
            # kinematic world's are its refused moves).
            if self._clearance is None:
                d = self.data
                ncon = d.ncon
                self._wall_touch[0] = ncon > 0 and bool(
                    self._is_wall_geom[d.contact.geom[:ncon]].any())
            self._sample()
            return
        touching = self._contacts()
        for r in self.robots:
            r._note_teammate(bool(touching[r.index]))
            if self.crowd is not None:
                r._note_people(self._people_touch[r.index], self._people_gap[r.index])
            r._sample()

    def _contacts(self) -> np.ndarray:
        """Which robots touch a teammate now; sets which touch a wall, and counts the
        pairs' collisions."""
        n = len(self.robots)
        teammate = np.zeros(n, bool)
        self._wall_touch[:] = False
        self._people_touch = np.zeros(n, bool)
        self._people_gap = np.full(n, math.inf)  # Body circle to the nearest person, metres.
        pairs: set[tuple[int, int]] = set()
        if self.crowd is not None:
            self._people_touch, self._people_gap = people_contacts(self.crowd, self.robots)
        if self._clearance is not None:
            for r in self.robots:
                if r._kinematic_teammate:
                    teammate[r.index] = True
                    cx, cy = r.body_centre
                    for o in self.robots:
                        ox, oy = o.body_centre
                        if o is not r and math.hypot(cx - ox, cy - oy) < 2 * BODY_RADIUS + 0.01:
                            teammate[o.index] = True
                            pairs.add((min(r.index, o.index), max(r.index, o.index)))
        else:
            d = self.data
            if d.ncon:
                g = d.contact.geom[:d.ncon]
                owner = self.geom_robot[g]
                wall = self._is_wall_geom[g]
                self._wall_touch[owner[:, 0][wall[:, 1] & (owner[:, 0] >= 0)]] = True
                self._wall_touch[owner[:, 1][wall[:, 0] & (owner[:, 1] >= 0)]] = True
                both = (owner >= 0).all(axis=1) & (owner[:, 0] != owner[:, 1])
                for a, b in owner[both]:
                    teammate[[a, b]] = True
                    pairs.add((int(min(a, b)), int(max(a, b))))
        t = self.time
        for pair in pairs:
            if t - self._pair_last.get(pair, -math.inf) > COLLISION_GAP_S:
                self.robot_collisions += 1
            self._pair_last[pair] = t
        return teammate
