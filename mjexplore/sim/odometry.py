"""Wheel odometry integrated from the wheel joints, as a robot's encoders would give it.

The pose is dead-reckoned from the change of each wheel's angle between samples (the
integral of the joint velocity), so wheel slip and integration error make it drift from
the ground truth the way a real robot's odometry does.

The simulated robot's geometry is exact, so on its own this odometry drifts only by the
soft contacts' creep (about 0.3 % of the distance). :class:`OdometryErrorConfig` adds a
real robot's errors, in Borenstein and Feng's two classes [1]:

* systematic, drawn once per robot (per seed): the odometry's wheel radii and track width
  differ from the true ones. Three factors, as UMBmark calibrates them [1]: the mean wheel
  radius (a scale error ``E_s``: tyre compression under load), the ratio of the right
  wheel's radius to the left's (``E_d``: unequal tyres) and the track width (``E_b``: the
  wheels touch the floor across their width, not at a point). Left and right radii follow
  from ``E_s`` and ``E_d`` by Borenstein and Feng's equations;
* random (non-systematic: slip, uneven floor): each wheel's travel per sample gets a
  zero-mean Gaussian error whose variance grows with that wheel's travel,
  ``var = k |ds|`` (Chong and Kleeman [2]; Siegwart et al. [3], eq. 5.9). The error is a
  random walk in the distance driven, so it does not depend on the sample rate.
  Thrun et al.'s odometry model [4] (``alpha1..alpha4``) is a filter's motion model with a
  variance in the square of each increment: applied per 20 Hz sample its drift would shrink
  as the rate grows, which is why the generative model here is the per-wheel one.

The ``typical`` magnitudes are this model's assumptions, sized from the robot's dimensions
(Turtlebot3 Waffle: 33 mm wheels, 19 mm tyres, 287 mm track):

* ``E_s``: 1 % (0.33 mm of rubber compression under the 1.8 kg robot);
* ``E_d``: 0.2 % (0.07 mm between the two moulded tyres' radii); its heading error,
  ``E_d / b`` per metre, dominates a straight run: 3.5 % of the distance sideways after
  10 m at one standard deviation, the order of the uncalibrated drifts UMBmark measures [1];
* ``E_b``: 1.5 % (4.3 mm): the contact point anywhere across each 19 mm tyre would give
  2.7 %, a bound;
* ``k``: 1e-6 m (1 mm per metre of a wheel's travel at one standard deviation): over
  10 m the random heading error is 0.9 degrees, below the systematic one, as Borenstein
  and Feng find on smooth indoor floors [1].

Systematic draws are normal, clipped to three standard deviations, so
:meth:`OdometryErrorConfig.straight_drift_bound` is a bound on them.

**Heading from the gyro** (``heading='imu'``): the Turtlebot3's own odometry
(``turtlebot3_node``, ``odometry.use_imu: true`` in its Waffle parameters) takes the
distance from the wheels and the heading from the IMU, whose yaw does not slip when the
wheels skid in a turn. Its gyro (the OpenCR board's MPU-9250, its offsets calibrated at
start-up while the robot stands still) is modelled as the yaw the base really turned
between samples, with three errors (``gyro_*``):

* a scale factor error, drawn per robot: the datasheet's sensitivity tolerance of +-3 %
  taken as three standard deviations (1 %) [5];
* a bias left after the start-up calibration, drawn per robot and constant over an
  episode: 0.005 deg/s (18 deg/h) at one standard deviation, this model's assumption of
  the order of a consumer MEMS gyro's bias instability (an Allan-variance quantity [6]);
* white rate noise, an angle random walk: the datasheet's noise density of
  0.01 (deg/s)/sqrt(Hz) [5].

Its draws come from a stream of their own, so a wheel-heading run's errors are the same
with or without it. The gyro's rate is integrated exactly between samples, as the IMU's
own fusion at its much higher rate would.

References:
    [1] J. Borenstein, L. Feng, "Measurement and correction of systematic odometry errors
        in mobile robots", IEEE Trans. Robotics and Automation 12(6), 1996 (UMBmark).
    [2] K. S. Chong, L. Kleeman, "Accurate odometry and error modelling for a mobile
        robot", IEEE ICRA 1997.
    [3] R. Siegwart, I. Nourbakhsh, D. Scaramuzza, "Introduction to Autonomous Mobile
        Robots", 2nd ed., MIT Press 2011, section 5.2.4.
    [4] S. Thrun, W. Burgard, D. Fox, "Probabilistic Robotics", MIT Press 2005, section 5.4.
    [5] InvenSense, "MPU-9250 Product Specification", PS-MPU-9250A-01 rev. 1.1, 2016,
        table 1 (gyroscope sensitivity scale factor tolerance, rate noise spectral density).
    [6] N. El-Sheimy, H. Hou, X. Niu, "Analysis and modeling of inertial sensors using
        Allan variance", IEEE Trans. Instrumentation and Measurement 57(1), 2008.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.robot import TURTLEBOT3_WAFFLE, RobotGeometry

# Systematic draws are clipped to this many standard deviations.
SYSTEMATIC_CLIP = 3.0
# Mixed into the simulator's seed so the odometry's draws never share the lidar's stream.
ODOMETRY_STREAM = 0x0D0E
# The gyro's own stream: a wheel-heading run draws the same wheel errors without it.
GYRO_STREAM = 0x6F10
# Where the odometry's heading comes from.
HEADINGS = ("wheels", "imu")


@dataclasses.dataclass(frozen=True, kw_only=True)
class OdometryErrorConfig:
    """Magnitudes of the odometry's errors (see the module docstring for their sources).

    Attributes:
        name: The preset these come from ('none', 'typical') or 'custom'.
        wheel_scale_std: Standard deviation of the mean wheel radius's relative error
            (``E_s - 1``), dimensionless.
        wheel_ratio_std: Standard deviation of the right-to-left wheel radius ratio's
            relative error (``E_d - 1``), dimensionless.
        track_std: Standard deviation of the track width's relative error (``E_b - 1``),
            dimensionless.
        slip_variance: ``k``: variance of a wheel's travel error per metre of its travel,
            in m^2/m (metres).
        gyro_scale_std: Standard deviation of the gyro's scale factor error,
            dimensionless (used when the heading comes from the IMU).
        gyro_bias_std: Standard deviation of the gyro's residual bias, rad/s.
        gyro_noise_density: The gyro's rate noise density, rad/s/sqrt(Hz).
    """

    name: str = "custom"
    wheel_scale_std: float = 0.0
    wheel_ratio_std: float = 0.0
    track_std: float = 0.0
    slip_variance: float = 0.0
    gyro_scale_std: float = 0.0
    gyro_bias_std: float = 0.0
    gyro_noise_density: float = 0.0

    def __post_init__(self) -> None:
        values = (self.wheel_scale_std, self.wheel_ratio_std, self.track_std, self.slip_variance,
                  self.gyro_scale_std, self.gyro_bias_std, self.gyro_noise_density)
        if not all(v >= 0 and math.isfinite(v) for v in values):
            raise UserInputError("odometry error magnitudes must be finite and >= 0.")
        if max(self.wheel_scale_std, self.wheel_ratio_std, self.track_std,
               self.gyro_scale_std) * SYSTEMATIC_CLIP >= 0.5:
            raise UserInputError("odometry systematic errors must stay below 1/6 (16.7 %): "
                                 "a larger one is not an odometry error but a wrong robot.")

    @property
    def is_none(self) -> bool:
        """True when the odometry is exact (no error of any kind)."""
        return not any((self.wheel_scale_std, self.wheel_ratio_std, self.track_std,
                        self.slip_variance, self.gyro_scale_std, self.gyro_bias_std,
                        self.gyro_noise_density))

    def gyro_heading_std(self, duration: float) -> float:
        """Standard deviation of the gyro's heading error (radians) after ``duration``
        seconds standing still or driving straight: its bias and its angle random walk
        (the scale error needs a turn)."""
        return math.hypot(self.gyro_bias_std * duration,
                          self.gyro_noise_density * math.sqrt(duration))

    def straight_drift_std(self, distance: float,
                           geometry: RobotGeometry = TURTLEBOT3_WAFFLE) -> tuple[float, float]:
        """Standard deviations of the odometry's error after a straight run, to first order.

        Args:
            distance: Length of the run in metres.
            geometry: The robot (its track width sets the heading error's effect).

        Returns:
            (along-track, cross-track) standard deviations in metres: the scale error and
            the wheels' random travel along; the radius ratio's curvature
            (``E_d / b``: ``distance^2 / 2`` of it) and the random heading walk across.
        """
        b = geometry.wheel_separation
        k = self.slip_variance
        along = math.sqrt((self.wheel_scale_std * distance) ** 2 + k * distance / 2)
        cross = math.sqrt((0.5 * distance ** 2 * self.wheel_ratio_std / b) ** 2 +
                          2 * k / b ** 2 * distance ** 3 / 3)
        return along, cross

    def straight_drift_bound(self, distance: float,
                             geometry: RobotGeometry = TURTLEBOT3_WAFFLE) -> float:
        """Bound on the odometry's position error after a straight run of ``distance``
        metres (its systematic draws are clipped at three standard deviations; the random
        part is bounded at three too, so 0.3 % of robots exceed it), in metres."""
        along, cross = self.straight_drift_std(distance, geometry)
        return SYSTEMATIC_CLIP * math.hypot(along, cross)


ODOMETRY_ERRORS: dict[str, OdometryErrorConfig] = {
    "none": OdometryErrorConfig(name="none"),
    "typical": OdometryErrorConfig(name="typical", wheel_scale_std=0.01, wheel_ratio_std=0.002,
                                   track_std=0.015, slip_variance=1e-6, gyro_scale_std=0.01,
                                   gyro_bias_std=math.radians(0.005),
                                   gyro_noise_density=math.radians(0.01)),
}


def odometry_error_config(spec: str | OdometryErrorConfig) -> OdometryErrorConfig:
    """The error magnitudes of a preset name ('none', 'typical') or a config (as is).

    Raises:
        UserInputError: unknown preset.
    """
    if isinstance(spec, OdometryErrorConfig):
        return spec
    try:
        return ODOMETRY_ERRORS[spec]
    except KeyError:
        raise UserInputError(f"odometry error {spec!r} is unknown: use one of "
                             f"{', '.join(ODOMETRY_ERRORS)}.") from None


class OdometryError:
    """One robot's odometry errors: the systematic factors drawn at construction and the
    random slip of every sample.

    Args:
        config: Error magnitudes.
        rng: Generator for the systematic draws (three normals, at construction) and the
            slip (two normals per update when ``slip_variance`` > 0).

    Attributes:
        left_scale: Odometry's left wheel radius over the true one.
        right_scale: Odometry's right wheel radius over the true one.
        track_scale: Odometry's track width over the true one.
    """

    def __init__(self, config: OdometryErrorConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        e_s, e_d, e_b = 1.0 + np.clip(rng.standard_normal(3), -SYSTEMATIC_CLIP,
                                      SYSTEMATIC_CLIP) * (config.wheel_scale_std,
                                                          config.wheel_ratio_std,
                                                          config.track_std)
        # Borenstein and Feng: D_L = 2 / (E_d + 1) D_a, D_R = 2 / (1 / E_d + 1) D_a.
        self.left_scale = float(e_s * 2.0 / (e_d + 1.0))
        self.right_scale = float(e_s * 2.0 / (1.0 / e_d + 1.0))
        self.track_scale = float(e_b)
        self._k = config.slip_variance

    def wheel_travel(self, d_left: float, d_right: float) -> tuple[float, float]:
        """The odometry's reading of the wheels' travel (metres) from their true travel."""
        d_left *= self.left_scale
        d_right *= self.right_scale
        if self._k > 0:
            n = self.rng.standard_normal(2)
            d_left += float(n[0]) * math.sqrt(self._k * abs(d_left))
            d_right += float(n[1]) * math.sqrt(self._k * abs(d_right))
        return d_left, d_right


def odometry_error(spec: str | OdometryErrorConfig, seed: int) -> OdometryError | None:
    """The odometry errors of a robot: None for exact odometry, else drawn from ``seed``
    (its own stream, apart from the simulator's other draws)."""
    config = odometry_error_config(spec)
    if config.is_none:
        return None
    return OdometryError(config, np.random.default_rng((int(seed), ODOMETRY_STREAM)))


class Gyro:
    """One robot's yaw-rate gyro: its scale factor and bias drawn at construction (clipped
    at three standard deviations), its rate noise at every increment.

    Args:
        config: Error magnitudes (``gyro_*``; all zero: an exact gyro).
        rng: Generator for the two draws and the noise (one normal per increment when
            ``gyro_noise_density`` > 0).

    Attributes:
        scale: The gyro's reading per radian turned.
        bias: Its reading standing still, rad/s.
    """

    def __init__(self, config: OdometryErrorConfig, rng: np.random.Generator) -> None:
        self.rng = rng
        scale, bias = np.clip(rng.standard_normal(2), -SYSTEMATIC_CLIP, SYSTEMATIC_CLIP)
        self.scale = 1.0 + float(scale) * config.gyro_scale_std
        self.bias = float(bias) * config.gyro_bias_std
        self._density = config.gyro_noise_density

    def increment(self, turned: float, dt: float) -> float:
        """The yaw (radians) the gyro integrates over ``dt`` seconds in which the base
        turned by ``turned`` radians."""
        angle = self.scale * turned + self.bias * dt
        if self._density > 0 and dt > 0:
            angle += self._density * math.sqrt(dt) * float(self.rng.standard_normal())
        return angle


def gyro(spec: str | OdometryErrorConfig, seed: int) -> Gyro:
    """The gyro of a robot, its errors drawn from ``seed`` (a stream of their own)."""
    return Gyro(odometry_error_config(spec), np.random.default_rng((int(seed), GYRO_STREAM)))


class WheelOdometry:
    """Differential-drive dead reckoning in the ``odom`` frame.

    Args:
        geometry: Wheel radius and separation used by the odometry (the robot's nominal
            dimensions).
        error: The robot's odometry errors; None for exact odometry.
        gyro: With a gyro the heading is the gyro's (``turtlebot3_node``'s ``use_imu``)
            and :meth:`reset` and :meth:`update` need the base's true yaw; None: the
            heading comes from the wheels.
    """

    def __init__(self, geometry: RobotGeometry = TURTLEBOT3_WAFFLE,
                 error: OdometryError | None = None, gyro: Gyro | None = None) -> None:
        self.geometry = geometry
        self.error = error
        self.gyro = gyro
        self._separation = geometry.wheel_separation * (1.0 if error is None else
                                                        error.track_scale)
        self._pose = (0.0, 0.0, 0.0)
        self._twist = (0.0, 0.0)
        self._last_angles: tuple[float, float] | None = None
        self._last_time = 0.0
        self._last_yaw = 0.0

    @property
    def pose(self) -> np.ndarray:
        """(x, y, yaw) of ``base_link`` in the ``odom`` frame, metres and radians."""
        return np.array(self._pose)

    @property
    def pose_tuple(self) -> tuple[float, float, float]:
        return self._pose

    @property
    def twist(self) -> np.ndarray:
        """(forward speed m/s, yaw rate rad/s) over the last update."""
        return np.array(self._twist)

    def reset(self, wheel_angles: np.ndarray | tuple[float, float], stamp: float,
              pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
              true_yaw: float | None = None) -> None:
        """Starts integrating from ``pose`` with the current wheel angles (radians) and,
        with a gyro, the base's true yaw (radians, any frame)."""
        self._pose = (float(pose[0]), float(pose[1]), float(pose[2]))
        self._twist = (0.0, 0.0)
        self._last_angles = (float(wheel_angles[0]), float(wheel_angles[1]))
        self._last_time = stamp
        if self.gyro is not None:
            self._last_yaw = _required_yaw(true_yaw)

    def update(self, wheel_angles: np.ndarray | tuple[float, float], stamp: float,
               true_yaw: float | None = None) -> None:
        """Integrates the motion since the last update (exact for constant curvature);
        ``true_yaw`` (radians, the frame of :meth:`reset`'s) is what the gyro turns by."""
        assert self._last_angles is not None, "call reset() first"
        left, right = float(wheel_angles[0]), float(wheel_angles[1])
        r = self.geometry.wheel_radius
        d_left = (left - self._last_angles[0]) * r
        d_right = (right - self._last_angles[1]) * r
        self._last_angles = (left, right)
        if self.error is not None:
            d_left, d_right = self.error.wheel_travel(d_left, d_right)
        dt = stamp - self._last_time
        ds = 0.5 * (d_left + d_right)
        if self.gyro is None:
            dtheta = (d_right - d_left) / self._separation
        else:
            true_yaw = _required_yaw(true_yaw)
            dtheta = self.gyro.increment(wrap_angle(true_yaw - self._last_yaw), max(dt, 0.0))
            self._last_yaw = true_yaw
        x, y, yaw = self._pose
        heading = yaw + 0.5 * dtheta
        yaw = (yaw + dtheta + math.pi) % (2 * math.pi) - math.pi
        self._pose = (x + ds * math.cos(heading), y + ds * math.sin(heading), yaw)
        if dt > 0:
            self._twist = (ds / dt, dtheta / dt)
        self._last_time = stamp


def _required_yaw(true_yaw: float | None) -> float:
    if true_yaw is None:
        raise ValueError("odometry with a gyro needs the base's true yaw at every sample")
    return float(true_yaw)


def wheel_odometry(error: str | OdometryErrorConfig, heading: str, seed: int,
                   geometry: RobotGeometry = TURTLEBOT3_WAFFLE) -> WheelOdometry:
    """A robot's odometry: its wheels' errors (``error``, a preset or a config) and, with
    ``heading='imu'`` (else 'wheels'), the heading of its gyro, all drawn from ``seed``."""
    return WheelOdometry(geometry, odometry_error(error, seed),
                         gyro(error, seed) if heading == "imu" else None)


def odom_in_map(origin: np.ndarray, odom: np.ndarray) -> np.ndarray:
    """Composes ``map -> odom`` (x, y, yaw) with poses (n, 3) in ``odom``: poses in ``map``."""
    c, s = math.cos(origin[2]), math.sin(origin[2])
    x = origin[0] + c * odom[:, 0] - s * odom[:, 1]
    y = origin[1] + s * odom[:, 0] + c * odom[:, 1]
    yaw = (odom[:, 2] + origin[2] + math.pi) % (2 * math.pi) - math.pi
    return np.column_stack([x, y, yaw])


def wrap_angle(angle: float) -> float:
    """``angle`` (radians) wrapped into [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def compose_pose(a: tuple[float, float, float] | np.ndarray,
                 b: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """``a`` composed with ``b``: pose ``b`` (x, y, yaw), given in frame ``a``, expressed in
    ``a``'s parent frame (metres, radians)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1],
                     wrap_angle(a[2] + b[2])])


def relative_pose(a: tuple[float, float, float] | np.ndarray,
                  b: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """Pose ``b`` in the frame of pose ``a`` (both in one frame): ``a^-1 b``, so that
    ``compose_pose(a, relative_pose(a, b)) == b``."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[2] - a[2])])
