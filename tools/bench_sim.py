"""Benchmark of the simulator on the office scene; prints one JSON line.

Figures (all in one process on one core, simulated seconds per wall second for RTFs). A
run of the reactive wanderer (closed loop on the lidar) is recorded first; then:
    full_loop_rtf      the simulator's full loop: physics at the model's step, lidar at
                       10 Hz, 20 Hz odometry/kinematics/limiter, and the run's (v, omega)
                       commands sent at 10 Hz through ``Simulator`` (a controller that costs
                       nothing itself);
    with_reactive_controller_rtf  the same with the wanderer computing the commands from
                       each scan (its own numpy work included);
    physics_rtf        the bound: the same wheel controls replayed with ``mj_step`` alone
                       (no lidar, no Python between control periods);
    lidar_scans_per_s  scans of the fast path (one ``mj_multiRay`` per scan) at poses from
                       the run; lidar_rays_per_s is that times the beam count;
    sensor_scans_per_s the bound: the same scan as 360 MuJoCo rangefinder sensors
                       (``mj_sensorPos`` after ``mj_kinematics``), same poses;
    loop_without_lidar_rtf  as full_loop_rtf with scans skipped: the lidar's share;
    full_loop_rtf_lds01  as full_loop_rtf with the LDS-01 lidar model (5 Hz, noise,
                       dropouts, motion skew) instead of the ideal one;
    kinematic_rtf, grid_rtf  as full_loop_rtf in the training worlds: ``dynamics``
                       'kinematic' (MuJoCo lidar, no contact dynamics) and 'grid' (no
                       MuJoCo: the lidar cast on the ground-truth grid);
    exploration_rtf    the whole exploration stack of an evaluation episode (physics,
                       lidar, mapping, topology, navigation, nearest frontier; no MCAP)
                       from the start until the scene is explored (or --episode-seconds,
                       if given, cut it short): what ``mjexplore explore --no-mcap``
                       spends on its episode (issue 16's target: >= 60);
                       exploration_sim_seconds and exploration_end_reason say how far it
                       ran;
    large_office_rtf   the same stack on a generated 100 x 100 m office (``scene-gen office
                       --size 100x100 --seed 0``, 16 times the office's area) over its first
                       600 simulated seconds: whether the cost grows with what changed
                       rather than with the map (target: >= 60, beside exploration_rtf);
    exploration_cpu_rtf, large_office_cpu_rtf  the same two by the process's CPU time
                       (what other load on a shared machine inflates less than the wall
                       time); load_average_1min says how loaded the machine was at the end;
    ratios             full_loop_over_physics, exploration_over_physics,
                       full_loop_over_loop_without_lidar,
                       lds01_over_ideal (full_loop_rtf_lds01 / full_loop_rtf),
                       grid_over_kinematic (grid_rtf / kinematic_rtf) and
                       lidar_over_sensor.

Usage: python tools/bench_sim.py [--scene office] [--seconds 60]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from mjexplore.navigation.wander import WanderController  # noqa: E402
from mjexplore.scenes.canonical import resolve_scene  # noqa: E402
from mjexplore.sim.lidar import lidar_model  # noqa: E402
from mjexplore.sim.simulator import SCAN_SITE, SimConfig, Simulator  # noqa: E402
from mjexplore.sim.world import World, make_world  # noqa: E402

CONTROL_PERIOD = 0.1


def sensor_model(xml: str, num_beams: int) -> mujoco.MjModel:
    """The scene with ``num_beams`` rangefinders on explicit sites at ``base_scan``."""
    spec = mujoco.MjSpec.from_file(xml)
    scan = spec.site(SCAN_SITE)
    body = scan.parent
    for i, a in enumerate(2 * np.pi * np.arange(num_beams) / num_beams):
        # Rangefinders look along the site's +z: rotate +z onto (cos a, sin a, 0).
        quat = np.zeros(4)
        mujoco.mju_euler2Quat(quat, [0.0, math.pi / 2, a], "XYZ")
        site = body.add_site(name=f"beam_{i}", pos=scan.pos, quat=quat)
        sensor = spec.add_sensor(name=f"range_{i}", type=mujoco.mjtSensor.mjSENS_RANGEFINDER,
                                 objtype=mujoco.mjtObj.mjOBJ_SITE, objname=site.name)
        sensor.intprm[0] = 1 << int(mujoco.mjtRayDataField.mjRAYDATA_DIST)  # distance only
    return spec.compile()


def seconds_per_scan(m: mujoco.MjModel, d: mujoco.MjData, poses: list[np.ndarray],
                     scan, repeats: int = 5) -> float:
    """Mean wall time of ``scan()`` after ``mj_kinematics`` at each of ``poses``."""
    t0 = time.perf_counter()
    for _ in range(repeats):
        for q in poses:
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            scan()
    return (time.perf_counter() - t0) / (repeats * len(poses))


def replay_wall(sim: World, twists: list[tuple[float, float]]) -> float:
    """Wall seconds of replaying (v, omega) commands through ``sim`` after a reset."""
    sim.reset()
    t0 = time.perf_counter()
    for v, w in twists:
        sim.command(v, w)
        sim.step(CONTROL_PERIOD)
    return time.perf_counter() - t0


def _timed_run(episode) -> tuple[float, float]:
    """(wall, CPU) seconds of ``episode.run()``; the CPU time is the process's, which a
    shared machine's other load does not inflate as much as the wall time."""
    t0, c0 = time.perf_counter(), time.process_time()
    episode.run()
    return time.perf_counter() - t0, time.process_time() - c0


def _large_office_rtf(seconds: float) -> tuple[float, float]:
    """(wall, CPU) real-time factors of nearest's first ``seconds`` on a generated 100 x 100
    m office."""
    import tempfile
    from pathlib import Path

    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.scenes.generate import generate_scene
    from mjexplore.scenes.scene import load_scene_files, write_scene

    with tempfile.TemporaryDirectory() as tmp:
        write_scene(generate_scene("office", 100.0, 100.0, 0), Path(tmp) / "scene")
        scene = load_scene_files(Path(tmp) / "scene")
        episode = Episode(scene, make_explorer("nearest"), 0, EpisodeConfig(max_time=seconds))
        wall, cpu = _timed_run(episode)
        return round(episode.sim.time / wall, 1), round(episode.sim.time / cpu, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds")
    parser.add_argument("--episode-seconds", type=float, default=None,
                        help="cap on the exploration episode's simulated seconds (default: "
                             "until explored, at most the episode's usual 1800 s)")
    args = parser.parse_args()
    scene = resolve_scene(args.scene)
    sim = Simulator(scene)
    controller = WanderController(rng=np.random.default_rng(0))
    n_periods = int(round(args.seconds / CONTROL_PERIOD))

    # Warm up the lidar tiles the run will visit, so that their one-off build is not timed.
    t0 = time.perf_counter()
    commands, poses, twists = [], [], []
    for _ in range(n_periods):
        v, w = controller(sim.latest_scan, sim.pose)
        sim.command(v, w)
        sim.step(CONTROL_PERIOD)
    tile_build_s = time.perf_counter() - t0

    sim.reset()
    controller = WanderController(rng=np.random.default_rng(0))
    t0 = time.perf_counter()
    for _ in range(n_periods):
        v, w = controller(sim.latest_scan, sim.pose)
        sim.command(v, w)
        sim.step(CONTROL_PERIOD)
        twists.append((v, w))
        commands.append(sim.data.ctrl.copy())
        poses.append(sim.data.qpos.copy())
    controller_wall = time.perf_counter() - t0
    sim_seconds = sim.time
    path_m = sim.kinematics().path_length()

    full_wall = replay_wall(sim, twists)

    m, d = sim.model, sim.data
    steps = int(round(CONTROL_PERIOD / m.opt.timestep))
    mujoco.mj_resetData(m, d)
    d.qpos[:] = poses[0]
    t0 = time.perf_counter()
    for ctrl in commands:
        d.ctrl[:] = ctrl
        mujoco.mj_step(m, d, nstep=steps)
    physics_wall = time.perf_counter() - t0

    # The same commands through the Simulator with scans skipped: what the lidar costs.
    sim.lidar.scan = lambda data, stamp, last=sim.latest_scan: last  # type: ignore[method-assign]
    no_lidar_wall = replay_wall(sim, twists)
    del sim.lidar.scan

    # The same commands with the LDS-01 model; the first pass builds its lidar tiles.
    lds01 = Simulator(scene, SimConfig(lidar=lidar_model("lds01")))
    replay_wall(lds01, twists)
    lds01_wall = replay_wall(lds01, twists)

    # The same commands in the training worlds (the first pass builds tiles / compiles).
    world_walls = {}
    for dynamics in ("kinematic", "grid"):
        world = make_world(scene, SimConfig(dynamics=dynamics))
        replay_wall(world, twists)
        world_walls[dynamics] = replay_wall(world, twists)

    # The whole exploration stack (physics, lidar, mapping, topology, navigation, nearest
    # frontier), no MCAP: a user's evaluation episode, whole (the map, the GVD and the
    # plans grow as it goes, so its first minutes alone would flatter it).
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer

    episode_config = EpisodeConfig() if args.episode_seconds is None else \
        EpisodeConfig(max_time=args.episode_seconds)
    episode = Episode(scene, make_explorer("nearest"), 0, episode_config)
    exploration_wall, exploration_cpu = _timed_run(episode)
    exploration_seconds = episode.sim.time

    large_office_rtf, large_office_cpu_rtf = _large_office_rtf(600.0)

    sample = poses[:: max(1, len(poses) // 200)]
    lidar_s = seconds_per_scan(m, d, sample, lambda: sim.lidar.scan(d, 0.0))
    sm = sensor_model(str(sim.scene.xml), sim.lidar.config.num_beams)
    sd = mujoco.MjData(sm)
    first = sm.sensor_adr[sm.sensor("range_0").id]  # After the robot's IMU sensors.
    beams = slice(first, first + sim.lidar.config.num_beams)
    sensor_s = seconds_per_scan(sm, sd, sample, lambda: mujoco.mj_sensorPos(sm, sd))
    max_diff = 0.0
    for q in sample[:20]:  # Both paths must read the same ranges.
        d.qpos[:] = q
        sd.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_kinematics(sm, sd)
        mujoco.mj_sensorPos(sm, sd)
        fast = sim.lidar.cast(d).copy()
        ok = (fast >= 0) & (fast < sim.lidar.config.range_max)
        max_diff = max(max_diff,
                       float(np.abs(fast[ok] - sd.sensordata[beams][ok]).max(initial=0.0)))

    n_walls = int(sim.lidar.static_scene.geom_ids.size)
    result = {
        "scene": args.scene,
        "sim_seconds": round(sim_seconds, 3),
        "path_m": round(path_m, 2),
        "wall_boxes": n_walls,
        "full_loop_rtf": round(sim_seconds / full_wall, 1),
        "physics_rtf": round(sim_seconds / physics_wall, 1),
        "exploration_rtf": round(exploration_seconds / exploration_wall, 1),
        "exploration_sim_seconds": round(exploration_seconds, 1),
        "large_office_rtf": large_office_rtf,
        "exploration_cpu_rtf": round(exploration_seconds / exploration_cpu, 1),
        "large_office_cpu_rtf": large_office_cpu_rtf,
        "load_average_1min": round(os.getloadavg()[0], 2),
        "exploration_end_reason": episode.end_reason,
        "exploration_over_physics": round(
            (exploration_seconds / exploration_wall) / (sim_seconds / physics_wall), 3),
        "full_loop_over_physics": round(physics_wall / full_wall, 3),
        "with_reactive_controller_rtf": round(sim_seconds / controller_wall, 1),
        "loop_without_lidar_rtf": round(sim_seconds / no_lidar_wall, 1),
        "full_loop_over_loop_without_lidar": round(no_lidar_wall / full_wall, 3),
        "full_loop_rtf_lds01": round(sim_seconds / lds01_wall, 1),
        "lds01_over_ideal": round(full_wall / lds01_wall, 3),
        "kinematic_rtf": round(sim_seconds / world_walls["kinematic"], 1),
        "grid_rtf": round(sim_seconds / world_walls["grid"], 1),
        "grid_over_kinematic": round(world_walls["kinematic"] / world_walls["grid"], 2),
        "lidar_scans_per_s": round(1.0 / lidar_s, 1),
        "lidar_rays_per_s": round(sim.lidar.config.num_beams / lidar_s),
        "sensor_scans_per_s": round(1.0 / sensor_s, 1),
        "lidar_over_sensor": round(sensor_s / lidar_s, 2),
        "lidar_vs_sensor_max_abs_diff_m": max_diff,
        "lidar_tiles_built": len(sim.lidar.static_scene._tiles),
        "first_run_with_tile_builds_s": round(tile_build_s, 3),
        "physics_timestep_s": m.opt.timestep,
        "mujoco": mujoco.__version__,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
