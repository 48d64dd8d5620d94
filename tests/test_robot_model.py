"""The robot's MJCF against the constants the code uses, its motors, IMU and friction."""

import math

import mujoco
import numpy as np
import pytest

from mjexplore.errors import UserInputError
from mjexplore.robot import (
    MOTION_PROFILES,
    ROBOT_XML,
    TURTLEBOT3_WAFFLE,
    XM430_W210,
    limit_wheel_speeds,
    motion_profile,
)
from mjexplore.scenes.scene import PHYSICS_TIMESTEP
from mjexplore.sim.simulator import (
    BODY_CENTRE_X,
    BODY_RADIUS,
    WHEEL_ACTUATORS,
    WHEEL_GEOMS,
    WHEEL_JOINTS,
    SimConfig,
    Simulator,
)

SCENE_XML = ROBOT_XML.with_name("scene.xml")
G = TURTLEBOT3_WAFFLE


@pytest.fixture(scope="module")
def robot():
    m = mujoco.MjModel.from_xml_path(str(ROBOT_XML))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)  # base_link at the origin, yaw 0: world xy = base_link xy.
    return m, d


def collision_boxes(m, d):
    """World-frame (lo, hi) corners of the AABB of each collision geom (group 3)."""
    out = []
    for i in np.flatnonzero(m.geom_group == 3):
        centre, half = m.geom_aabb[i, :3], m.geom_aabb[i, 3:]
        rot = d.geom_xmat[i].reshape(3, 3)
        c = d.geom_xpos[i] + rot @ centre
        h = np.abs(rot) @ half
        out.append((c - h, c + h))
    return out


def test_mjcf_geometry_equals_the_robot_constants(robot):
    m, d = robot
    base = m.body("base_link")
    lo = np.min([b[0] for b in collision_boxes(m, d)], axis=0) - base.pos
    hi = np.max([b[1] for b in collision_boxes(m, d)], axis=0) - base.pos
    assert hi[0] - lo[0] == pytest.approx(G.length, abs=1e-9)
    assert hi[1] - lo[1] == pytest.approx(G.width, abs=1e-9)  # Over the wheels: 0.306 m.
    for name, side in zip(("wheel_left_link", "wheel_right_link"), (1, -1)):
        assert m.body(name).pos[1] == pytest.approx(side * G.wheel_separation / 2)
        # The wheel's centre is one radius above the floor the casters stand on.
        assert base.pos[2] + m.body(name).pos[2] == pytest.approx(G.wheel_radius)
    for name in WHEEL_GEOMS:
        rx, ry, rz = m.geom(name).size
        assert (rx, rz) == pytest.approx((G.wheel_radius, G.wheel_radius))
        assert 2 * ry == pytest.approx(G.wheel_width)
    assert tuple(m.site("base_scan").pos) == pytest.approx(G.scan_offset)
    assert tuple(m.site("imu_link").pos) == pytest.approx(G.imu_offset)
    assert m.body_subtreemass[base.id] == pytest.approx(1.8)
    # Every collision geom lies within the footprint circle and the kinematic mode's circle.
    corners = np.array([[x, y] for lo_, hi_ in collision_boxes(m, d)
                        for x in (lo_[0], hi_[0]) for y in (lo_[1], hi_[1])])
    assert np.hypot(*corners.T).max() <= G.footprint_radius
    assert np.hypot(corners[:, 0] - BODY_CENTRE_X, corners[:, 1]).max() <= BODY_RADIUS


def test_wheels_spin_about_their_larger_principal_moment(robot):
    m, _ = robot
    for joint in WHEEL_JOINTS:
        j = m.joint(joint)
        body = j.bodyid[0]
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, m.body_iquat[body])
        inertia = rot.reshape(3, 3) @ np.diag(m.body_inertia[body]) @ rot.reshape(3, 3).T
        axis = j.axis
        assert axis @ inertia @ axis == pytest.approx(m.body_inertia[body].max())


def test_motors_are_the_xm430s(robot):
    m, _ = robot
    for name in WHEEL_ACTUATORS:
        assert tuple(m.actuator(name).forcerange) == (-XM430_W210.stall_torque,
                                                      XM430_W210.stall_torque)
    assert XM430_W210.no_load_speed == pytest.approx(8.06, abs=0.01)  # 77 rpm.
    assert motion_profile("real").max_wheel_speed == XM430_W210.no_load_speed
    # The sim profile's wheels reach its top speed and no more.
    sim = motion_profile("sim")
    assert sim.max_wheel_speed * G.wheel_radius == pytest.approx(sim.max_linear_speed)


def test_the_menagerie_scene_includes_the_robot_file(robot):
    m, _ = robot
    assert '<include file="robot.xml"/>' in SCENE_XML.read_text()
    scene = mujoco.MjModel.from_xml_path(str(SCENE_XML))
    assert scene.opt.timestep == m.opt.timestep == PHYSICS_TIMESTEP
    assert scene.opt.integrator == m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    for i in range(1, m.nbody):
        b = scene.body(m.body(i).name)
        assert np.array_equal(b.pos, m.body_pos[i]) and b.mass == m.body_mass[i]
        assert np.array_equal(scene.geom_size[scene.geom_bodyid == b.id],
                              m.geom_size[m.geom_bodyid == i])


def test_the_menagerie_scene_steps_under_random_commands_without_warnings():
    sim = Simulator(SCENE_XML)
    rng = np.random.default_rng(0)
    for _ in range(100):
        sim.command(rng.uniform(-0.5, 0.5), rng.uniform(-1.8, 1.8))
        sim.step(0.1)
    assert sim.warnings() == {} and sim.is_upright and not sim.physics_fault
    assert sim.kinematics().path_length() > 1.0


def test_limit_wheel_speeds_keeps_curvature():
    limit = XM430_W210.no_load_speed
    assert limit_wheel_speeds(0.1, 0.5, limit) == (0.1, 0.5)  # Within the limit: unchanged.
    v, w = limit_wheel_speeds(0.18, 1.8, limit)
    assert w / v == pytest.approx(1.8 / 0.18)
    fastest = (abs(v) + abs(w) * G.wheel_separation / 2) / G.wheel_radius
    assert fastest == pytest.approx(limit)
    v, w = limit_wheel_speeds(-0.5, 0.0, limit)
    assert (v, w) == pytest.approx((-limit * G.wheel_radius, 0.0))


@pytest.mark.parametrize("profile", list(MOTION_PROFILES))
def test_per_wheel_limits_hold_in_a_hard_turn_at_full_speed(box_room, profile):
    folder, _ = box_room
    p = motion_profile(profile)
    sim = Simulator(folder, SimConfig(profile=profile))
    sim.reset((3.2, 2.2, 0.0))
    dofs = [sim.model.joint(j).dofadr[0] for j in WHEEL_JOINTS]
    wheel = []
    for k in range(60):  # 1.5 s left at full speed, then 1.5 s right.
        sim.command(p.max_linear_speed, p.max_angular_speed * (1 if k < 30 else -1))
        sim.step(0.05)
        wheel.append(np.abs(sim.data.qvel[dofs]).max())
    log = sim.kinematics()
    half, r = G.wheel_separation / 2, G.wheel_radius
    setpoint = (np.abs(log.cmd_linear) + np.abs(log.cmd_angular) * half) / r
    assert setpoint.max() <= p.max_wheel_speed + 1e-9
    assert setpoint.max() == pytest.approx(p.max_wheel_speed)  # The turn asks for more.
    assert max(wheel) <= 1.03 * p.max_wheel_speed  # The wheels follow within servo lag.
    # At the end, the command has the asked curvature, scaled to the wheel limit.
    assert log.cmd_angular[-1] / log.cmd_linear[-1] == pytest.approx(
        -p.max_angular_speed / p.max_linear_speed)
    dt = np.diff(log.t)  # The acceleration limits still hold.
    assert (np.abs(np.diff(log.cmd_linear)) / dt).max() <= p.max_linear_accel + 1e-6
    assert (np.abs(np.diff(log.cmd_angular)) / dt).max() <= p.max_angular_accel + 1e-6
    assert sim.warnings() == {}


def test_imu_reads_gravity_and_yaw_rate(box_room):
    folder, _ = box_room
    sim = Simulator(folder)
    sim.reset((3.2, 2.2, 0.0))
    sim.step(1.0)
    log = sim.kinematics()
    assert log.imu_accel[-1] == pytest.approx([0.0, 0.0, 9.81], abs=0.01)  # At rest.
    assert np.abs(log.imu_gyro[-1]).max() < 1e-3
    sim.command(0.0, 1.5)
    sim.step(3.0)
    log = sim.kinematics()
    w = log.angular_velocity[-1]
    assert log.imu_gyro[-1][2] == pytest.approx(w, rel=1e-3)
    # Turning in place about base_link, the IMU 0.032 m behind it feels w^2 r forward.
    assert log.imu_accel[-1][0] == pytest.approx(w ** 2 * -G.imu_offset[0], rel=0.1)
    table = log.as_table()
    assert table.shape[1] == len(log.COLUMNS) == 19
    assert np.array_equal(table[:, -6:-3], log.imu_gyro)
    kinematic = Simulator(folder, SimConfig(dynamics="kinematic"))
    kinematic.step(0.5)
    assert np.isnan(kinematic.kinematics().imu_gyro).all()  # No dynamics, no IMU.


def test_wheel_friction_is_a_parameter(box_room):
    folder, _ = box_room
    slips = {}
    for mu in (1.0, 0.1):
        sim = Simulator(folder, SimConfig(wheel_friction=mu))
        assert sim.model.geom(WHEEL_GEOMS[0]).friction[0] == mu
        sim.reset((1.0, 2.2, 0.0))
        dofs = [sim.model.joint(j).dofadr[0] for j in WHEEL_JOINTS]
        slip = []
        for target, duration in [(0.5, 0.6), (0.0, 0.4)] * 2:  # Go and stop at 2.5 m/s^2.
            sim.command(target, 0.0)
            for _ in range(round(duration / 0.01)):
                sim.step(0.01)
                slip.append(sim.data.qvel[dofs].mean() * G.wheel_radius - sim.velocity[0])
        slips[mu] = np.abs(slip).max()
    # Gazebo's 0.1 cannot transmit 2.5 m/s^2: the wheels spin or lock.
    assert slips[1.0] < 0.05 and slips[0.1] > 0.2
    with pytest.raises(UserInputError, match="wheel_friction"):
        SimConfig(wheel_friction=0.0)


def test_profiles_ask_for_no_more_than_their_wheels():
    for p in MOTION_PROFILES.values():
        assert p.max_linear_speed / G.wheel_radius <= p.max_wheel_speed + 1e-9
        assert math.isfinite(p.max_wheel_speed)
