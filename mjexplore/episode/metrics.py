"""An episode's metrics: the paper's (ET, PL, IoU, exploration ratio) and more, all in
simulated time."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from mjexplore.mapping.metrics import iou
from mjexplore.maps import GridMap
from mjexplore.sim.kinematics import KinematicsLog


def first_time_at(curve: np.ndarray, level: float) -> float | None:
    """First time (s) at which the ratio curve reaches ``level``, or None."""
    hit = np.flatnonzero(curve[:, 1] >= level)
    return round(float(curve[hit[0], 0]), 3) if len(hit) else None


# Exploration ratios whose first times are metrics (the paper's Fig. 5), and their keys.
MILESTONES = ((0.80, "t80_s"), (0.985, "t985_s"))
# Those of a team's metrics.
TEAM_MILESTONES = ((0.80, "t80_s"), (0.90, "t90_s"), (0.985, "t985_s"))


def episode_metrics(curve: np.ndarray, log: KinematicsLog, final_iou: float,
                    collisions: int, end_reason: str) -> dict[str, Any]:
    """The paper's metrics from an episode's records (all times simulated).

    Keys: ``iou``; ``exploration_ratio`` (final); ``exploration_time_s`` (ET: time at the
    end of the episode); ``path_length_m`` (PL: length of the true path of ``base_link``);
    ``odometry_path_length_m``; ``t80_s`` and ``t985_s`` (first times the ratio reaches
    0.80 and 0.985, None if never); ``collisions``; ``end_reason``; ``mean_speed_mps``.
    """
    odom = log.odom_pose[:, :2]
    t_end = float(curve[-1, 0])
    path = log.path_length()
    return {
        "iou": round(final_iou, 5),
        "exploration_ratio": round(float(curve[-1, 1]), 5),
        "exploration_time_s": round(t_end, 3),
        "path_length_m": round(path, 3),
        "odometry_path_length_m": round(
            float(np.linalg.norm(np.diff(odom, axis=0), axis=1).sum()), 3),
        **{key: first_time_at(curve, level) for level, key in MILESTONES},
        "collisions": int(collisions),
        "end_reason": end_reason,
        "mean_speed_mps": round(path / t_end, 4) if t_end > 0 else 0.0,
    }


# A robot slower than these stands still (m/s, rad/s).
STOPPED_SPEED = (0.02, 0.05)


def people_metrics(robot: Any, crowd: Any, log: KinematicsLog) -> dict[str, Any]:
    """A robot's figures among people: ``people``, how many walked; ``people_collisions``
    (robot-person contacts, those less than 0.5 s apart as one); ``people_min_distance_m``
    (the least gap between the robot's bounding circle and a person, sampled at 20 Hz;
    negative: they touched); ``time_stopped_s`` (simulated time the robot stood still,
    slower than ``STOPPED_SPEED``); ``people_goals_reached``."""
    dt = np.diff(log.t, prepend=log.t[:1])
    still = (np.abs(log.linear_velocity) < STOPPED_SPEED[0]) & \
        (np.abs(log.angular_velocity) < STOPPED_SPEED[1])
    gap = robot.people_min_distance
    return {"people": len(crowd), "people_collisions": int(robot.people_collisions),
            "people_min_distance_m": round(float(gap), 3) if np.isfinite(gap) else None,
            "time_stopped_s": round(float(dt[still].sum()), 3),
            "people_goals_reached": int(crowd.goals_reached)}


def pose_errors(estimated: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Position errors of an estimated trajectory, as is and after the rigid alignment that
    fits it best to the truth.

    The aligned error is the absolute trajectory error of SLAM benchmarks (Sturm et al.,
    "A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012: least-squares
    rotation and translation, Umeyama's closed form in 2-D): what stays once the estimate's
    frame (a heading error at the start turns the whole map) is set aside, i.e. the
    distortion of the trajectory and of the map built along it.

    Args:
        estimated: (n, 2) estimated (x, y) of ``base_link`` in ``map``, metres.
        truth: (n, 2) the true positions at the same instants.

    Returns:
        ``pose_error_rmse_m``, ``pose_error_max_m`` and ``pose_error_aligned_rmse_m``
        (metres; all 0 without samples).
    """
    estimated = np.asarray(estimated, np.float64).reshape(-1, 2)
    truth = np.asarray(truth, np.float64).reshape(-1, 2)
    if len(truth) == 0:
        return {"pose_error_rmse_m": 0.0, "pose_error_max_m": 0.0,
                "pose_error_aligned_rmse_m": 0.0}
    raw = np.hypot(*(estimated - truth).T)
    est_c, truth_c = estimated - estimated.mean(0), truth - truth.mean(0)
    u, _, vt = np.linalg.svd(truth_c.T @ est_c)
    flip = np.diag([1.0, np.sign(np.linalg.det(u @ vt))])  # A rotation, never a reflection.
    aligned = np.hypot(*(est_c @ (u @ flip @ vt).T - truth_c).T)
    return {"pose_error_rmse_m": round(float(np.sqrt(np.mean(raw ** 2))), 4),
            "pose_error_max_m": round(float(raw.max()), 4),
            "pose_error_aligned_rmse_m": round(float(np.sqrt(np.mean(aligned ** 2))), 4)}


class KnownCounter:
    """Exploration ratio kept up to date from the cells the mapper reports as changed."""

    def __init__(self, reference: GridMap) -> None:
        self.ref_known = reference.known.reshape(-1)
        self.total = int(self.ref_known.sum())
        self.known = np.zeros(self.ref_known.shape, bool)
        self.count = 0

    def update(self, state: np.ndarray, changed: np.ndarray, cols: int) -> float:
        if len(changed):
            flat = changed[:, 0] * cols + changed[:, 1]
            new = state.reshape(-1)[flat] >= 0
            ref = self.ref_known[flat]
            self.count += int((new & ref).sum() - (self.known[flat] & ref).sum())
            self.known[flat] = new
        return self.count / self.total


@dataclasses.dataclass
class TeamEpisodeResult:
    """What a team episode produced.

    Attributes:
        metrics: The team's metrics, with ``per_robot`` (a list of dicts).
        ratio_curve: (n, 2) time (s) and the team's exploration ratio after each scan.
        robot_curves: Each robot's (m, 2) time and own coverage ratio.
        kinematics: Each robot's kinematics log.
        grid: The final shared map.
        goals: Each robot's (m, 3) decision time and goal.
        starts: The robots' start poses.
    """

    metrics: dict[str, Any]
    ratio_curve: np.ndarray
    robot_curves: list[np.ndarray]
    kinematics: list[KinematicsLog]
    grid: GridMap
    goals: list[np.ndarray]
    starts: list[tuple[float, float, float]]


def team_result(episode: Any) -> TeamEpisodeResult:
    """What a team's ``episode`` (an :class:`~mjexplore.episode.engine.Episode` of N > 1
    robots) produced: the team's metrics, with map merging's when the starts were unknown.

    Metrics beside a single robot's: the robots' summed and longest path, robot-robot
    collisions, Explore-Bench's overlap ratio (the robots' own explored areas summed over
    the team's, less one: 0 when no cell was seen by two robots, 1 when each saw
    everything), the times to 80, 90 and 98.5 %, and per robot its path, coverage (what its
    own scans saw), collisions, decisions, waits and yields (and its pose errors with a
    localiser).
    """
    team = episode.team
    curve = np.array(episode.curve).reshape(-1, 2)
    grid = episode.mapper.grid
    counter = episode.counter
    world = episode.world
    logs = [r.kinematics() for r in world.robots]
    paths = [log.path_length() for log in logs]
    t_end = float(curve[-1, 0]) if len(curve) else 0.0
    own_known = [c.count for c in team.own_counters]
    t = episode.time
    per_robot = []
    for a, log, path, known in zip(team.agents, logs, paths, own_known):
        odom = log.odom_pose[:, :2]
        wait = a.wait_time + (t - a.waiting_since if a.waiting_since is not None else 0.0)
        idle = a.idle_time + (t - a.idle_since if a.idle_until is not None else 0.0)
        per_robot.append({
            "robot": a.sim.name,
            "start": [round(v, 4) for v in episode.starts[a.index]],
            "path_length_m": round(path, 3),
            "odometry_path_length_m": round(
                float(np.linalg.norm(np.diff(odom, axis=0), axis=1).sum()), 3),
            "coverage": round(known / counter.total, 5),
            "collisions": int(a.sim.collisions),
            "robot_contacts": int(a.sim.robot_contacts),
            "decisions": len(a.goals),
            "fallbacks": a.fallbacks,
            "reoffers": a.reoffers,
            "given_up": a.blacklist.reasons(),
            "waits": a.waits,
            "wait_time_s": round(wait, 3),
            "yields": a.yields,
            "idle_time_s": round(max(idle, 0.0), 3),
            "state": a.retired or ("idle" if a.idle_until is not None else "exploring"),
            "mean_speed_mps": round(path / t_end, 4) if t_end > 0 else 0.0,
        })
        if a.localizer is not None:  # Its estimate against its true pose, per scan.
            positions = np.array(a._positions, np.float64).reshape(-1, 4)
            per_robot[-1].update(pose_errors(positions[:, :2], positions[:, 2:]))
        crowd = getattr(world, "crowd", None)
        if crowd is not None:
            per_robot[-1].update(people_metrics(a.sim, crowd, log))
    metrics: dict[str, Any] = {
        "robots": len(team.agents),
        "iou": round(iou(grid, episode.reference), 5),
        "exploration_ratio": round(float(curve[-1, 1]), 5) if len(curve) else 0.0,
        "exploration_time_s": round(t_end, 3),
        **{key: first_time_at(curve, level) for level, key in TEAM_MILESTONES},
        "path_length_m": round(float(sum(paths)), 3),
        "max_path_length_m": round(float(max(paths)), 3),
        "overlap_ratio": round(sum(own_known) / max(counter.count, 1) - 1.0, 5),
        "collisions": int(sum(r.collisions for r in world.robots)),
        "robot_collisions": int(world.robot_collisions),
        "end_reason": episode.end_reason or "running",
        "decisions": sum(len(a.goals) for a in team.agents),
        "waits": sum(a.waits for a in team.agents),
        "yields": sum(a.yields for a in team.agents),
        "masked_returns": episode.bodies.masked_returns,
        "localization": episode.config.localization,
        "per_robot": per_robot,
    }
    if getattr(world, "crowd", None) is not None:
        metrics["people"] = len(world.crowd)
        metrics["people_collisions"] = sum(r["people_collisions"] for r in per_robot)
    if episode.merging is not None:
        metrics.update(episode.merging.metrics(counter))
    explorer = team.agents[0].explorer
    sha = getattr(explorer, "weights_sha256", None)  # A learned explorer's weights.
    if sha is not None:
        metrics["policy"] = explorer.policy_name
        metrics["weights_sha256"] = sha
    return TeamEpisodeResult(
        metrics, curve, [np.array(c).reshape(-1, 2) for c in team.own_curves], logs,
        GridMap(grid.data.copy(), grid.resolution, grid.origin),
        [np.array(a.goals).reshape(-1, 3) for a in team.agents], list(episode.starts))
