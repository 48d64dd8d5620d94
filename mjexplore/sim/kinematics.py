"""Recording the robot's velocity, acceleration and IMU over simulated time."""

from __future__ import annotations

import dataclasses

import numpy as np


class GrowableArray:
    """Row-appendable float array with amortised O(1) appends."""

    def __init__(self, width: int, capacity: int = 1024) -> None:
        self._buf = np.empty((capacity, width))
        self._n = 0

    def append(self, row: tuple[float, ...]) -> None:
        if self._n == len(self._buf):
            self._buf = np.concatenate([self._buf, np.empty_like(self._buf)])
        self._buf[self._n] = row
        self._n += 1

    def clear(self) -> None:
        self._n = 0

    def __len__(self) -> int:
        return self._n

    @property
    def array(self) -> np.ndarray:
        """A view of the filled rows."""
        return self._buf[: self._n]


@dataclasses.dataclass(frozen=True)
class KinematicsLog:
    """Velocity and acceleration of ``base_link`` sampled over simulated time.

    Attributes:
        t: Sample times in seconds.
        linear_velocity: Forward speed in m/s (ground truth, ``base_link`` x axis).
        angular_velocity: Yaw rate in rad/s.
        linear_acceleration: d(linear_velocity)/dt in m/s^2 (central differences).
        angular_acceleration: d(angular_velocity)/dt in rad/s^2.
        cmd_linear: Commanded forward speed after the acceleration limiter, m/s.
        cmd_angular: Commanded yaw rate after the acceleration limiter, rad/s.
        pose: (n, 3) ground-truth (x, y, yaw) of ``base_link`` in the ``map`` frame.
        odom_pose: (n, 3) wheel-odometry (x, y, yaw) of ``base_link`` in the ``odom`` frame.
        imu_gyro: (n, 3) angular velocity in rad/s measured by the IMU, in ``imu_link``
            (axes as ``base_link``'s); None or NaN where there is no IMU (kinematic mode).
            MuJoCo computes sensors at the start of a physics step, so a reading is one
            step (5 ms) older than its sample.
        imu_accel: (n, 3) specific force in m/s^2 (acceleration minus gravity: +9.81 on z
            at rest) measured by the IMU, in ``imu_link``; None or NaN where there is none.
    """

    t: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    linear_acceleration: np.ndarray
    angular_acceleration: np.ndarray
    cmd_linear: np.ndarray
    cmd_angular: np.ndarray
    pose: np.ndarray
    odom_pose: np.ndarray
    imu_gyro: np.ndarray | None = None
    imu_accel: np.ndarray | None = None

    COLUMNS = ("t", "linear_velocity", "angular_velocity", "linear_acceleration",
               "angular_acceleration", "cmd_linear", "cmd_angular", "x", "y", "yaw",
               "odom_x", "odom_y", "odom_yaw", "gyro_x", "gyro_y", "gyro_z", "accel_x",
               "accel_y", "accel_z")

    def as_table(self) -> np.ndarray:
        """(n, 19) array in the order of :attr:`COLUMNS` (NaN IMU columns without an IMU)."""
        missing = np.full((len(self.t), 3), np.nan)
        gyro = missing if self.imu_gyro is None else self.imu_gyro
        accel = missing if self.imu_accel is None else self.imu_accel
        return np.column_stack([self.t, self.linear_velocity, self.angular_velocity,
                                self.linear_acceleration, self.angular_acceleration,
                                self.cmd_linear, self.cmd_angular, self.pose, self.odom_pose,
                                gyro, accel])

    def to_csv(self) -> str:
        """The log as CSV text: a header of :attr:`COLUMNS`, then one row per sample."""
        rows = [",".join(self.COLUMNS)]
        rows += [",".join(f"{v:.6g}" for v in row) for row in self.as_table()]
        return "\n".join(rows) + "\n"

    def path_length(self) -> float:
        """Length of the ground-truth path of ``base_link`` in metres."""
        if len(self.t) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.pose[:, :2], axis=0), axis=1).sum())


class KinematicsRecorder:
    """Collects samples (t, v, omega, v_cmd, omega_cmd, pose, odometry pose, IMU) during a
    run."""

    def __init__(self) -> None:
        self._rows = GrowableArray(17)

    def clear(self) -> None:
        self._rows.clear()

    @property
    def rows(self) -> np.ndarray:
        """A view of the raw samples (t, v, omega, v_cmd, omega_cmd, x, y, yaw, odom x, y,
        yaw, gyro x, y, z, accel x, y, z); valid until the next sample."""
        return self._rows.array

    def record(self, t: float, v: float, omega: float, cmd: tuple[float, float],
               pose: tuple[float, float, float], odom: tuple[float, float, float],
               imu: tuple[float, ...] = (np.nan,) * 6) -> None:
        """Appends one sample: time s, speed m/s, yaw rate rad/s, command (v, omega), true
        pose and odometry pose (x, y, yaw), IMU (gyro rad/s, accelerometer m/s^2)."""
        self._rows.append((t, v, omega, cmd[0], cmd[1], *pose, *odom, *imu))

    def log(self) -> KinematicsLog:
        rows = self._rows.array.copy()
        t = rows[:, 0]

        def derivative(x: np.ndarray) -> np.ndarray:
            return np.gradient(x, t) if len(t) >= 2 else np.zeros_like(x)

        return KinematicsLog(t=t, linear_velocity=rows[:, 1], angular_velocity=rows[:, 2],
                             linear_acceleration=derivative(rows[:, 1]),
                             angular_acceleration=derivative(rows[:, 2]),
                             cmd_linear=rows[:, 3], cmd_angular=rows[:, 4], pose=rows[:, 5:8],
                             odom_pose=rows[:, 8:11], imu_gyro=rows[:, 11:14],
                             imu_accel=rows[:, 14:17])
