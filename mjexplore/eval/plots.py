"""Figures in the paper's style: exploration ratio over time (Fig. 5), kinematics (Fig. 9),
and the final map with the trajectory (Fig. 6)."""

from __future__ import annotations

import io
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mjexplore.io.atomic import write_bytes_atomic  # noqa: E402
from mjexplore.maps import GridMap  # noqa: E402

COLOURS = {"gvn": "tab:red", "potential": "tab:blue", "nearest": "tab:green",
           "rrt": "tab:orange", "cnn": "tab:purple", "explore_lite": "tab:brown",
           "frontier_tsp": "tab:cyan", "oracle": "black", "gvn_v2": "tab:olive",
           "gvn_v3": "magenta", "cnn_v2": "tab:gray", "pocket_nearest": "limegreen"}
# A team's robots, in order.
ROBOT_COLOURS = ("tab:green", "tab:red", "tab:blue", "tab:orange", "tab:purple", "tab:brown",
                 "tab:pink", "tab:cyan")
# How a method is named in tables and plots where its name alone would mislead.
METHOD_LABELS = {"oracle": "oracle (ground-truth bound)"}


def _save(fig, path: str | os.PathLike) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())


def resample(curve: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Exploration ratio at ``times`` (held at its last value after the episode ended)."""
    return np.interp(times, curve[:, 0], curve[:, 1], right=curve[-1, 1])


def ratio_figure(curves: dict[str, list[np.ndarray]], path: str | os.PathLike,
                 title: str = "", marks: tuple[float, ...] = (0.80, 0.985),
                 mark_times: dict[str, dict[float, list[float]]] | None = None) -> None:
    """Mean (line) and spread (min-max band) of the exploration ratio over time per method,
    with the mean times to each of ``marks`` shown as dotted lines.

    Args:
        mark_times: Per method and mark, the runs' times to reach it (the runs that did),
            when the curves are too coarse to read them off (resampled summaries); by
            default they are read off the curves.
    """
    fig, ax = plt.subplots(figsize=(7, 4))
    t_end = max(c[-1, 0] for runs in curves.values() for c in runs)
    times = np.linspace(0, t_end, 400)
    for method, runs in curves.items():
        values = np.array([resample(c, times) for c in runs])
        colour = COLOURS.get(method)
        ax.plot(times, values.mean(axis=0), label=METHOD_LABELS.get(method, method),
                color=colour)
        ax.fill_between(times, values.min(axis=0), values.max(axis=0), alpha=0.15, color=colour)
        for level in marks:
            hits = (mark_times[method][level] if mark_times is not None else
                    [c[np.argmax(c[:, 1] >= level), 0] for c in runs if (c[:, 1] >= level).any()])
            if hits:
                ax.axvline(float(np.mean(hits)), color=colour, ls=":", lw=0.8)
    for level in marks:
        ax.axhline(level, color="grey", ls="--", lw=0.6)
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("exploration ratio")
    ax.set_ylim(0, 1.02)
    ax.set_title(title)
    ax.legend(loc="lower right")
    _save(fig, path)


def kinematics_figure(logs: dict[str, list], path: str | os.PathLike, title: str = "") -> None:
    """Linear and angular velocity and acceleration over time per method (mean and spread)."""
    fig, axes = plt.subplots(4, len(logs), figsize=(4 * len(logs), 8), squeeze=False,
                             sharex="col", sharey="row")  # Same scales: methods compare.
    names = [("linear_velocity", "v (m/s)"), ("angular_velocity", "omega (rad/s)"),
             ("linear_acceleration", "a (m/s^2)"), ("angular_acceleration", "alpha (rad/s^2)")]
    for col, (method, runs) in enumerate(logs.items()):
        t_end = min(log.t[-1] for log in runs)
        times = np.linspace(0, t_end, 600)
        for row, (field, label) in enumerate(names):
            values = np.array([np.interp(times, log.t, getattr(log, field)) for log in runs])
            ax = axes[row, col]
            ax.plot(times, values.mean(axis=0), lw=0.6, color=COLOURS.get(method))
            ax.fill_between(times, values.min(axis=0), values.max(axis=0), alpha=0.2,
                            color=COLOURS.get(method))
            if col == 0:
                ax.set_ylabel(label)
            if row == 0:
                ax.set_title(method)
        axes[-1, col].set_xlabel("simulated time (s)")
    fig.suptitle(title)
    _save(fig, path)


def map_figure(grid: GridMap, trajectories: list[np.ndarray], goals: list[np.ndarray],
               path: str | os.PathLike, title: str = "", ter=None) -> None:
    """The final map with each robot's trajectory and goals (one robot: green and blue; a
    team: a colour per robot, its start ringed) and optionally a TER.

    Args:
        trajectories: Per robot, (k, 2) positions (x, y) over time.
        goals: Per robot, (m, 3) decision time and goal (x, y).
    """
    img = np.full(grid.shape, 0.6)
    img[grid.free] = 1.0
    img[grid.occupied] = 0.0
    x0, y0 = grid.origin[:2]
    w, h = grid.size_m
    fig, ax = plt.subplots(figsize=(8, 8 * h / w + 0.5))
    ax.imshow(img, cmap="gray", origin="lower", extent=(x0, x0 + w, y0, y0 + h), vmin=0, vmax=1)
    if ter is not None:
        for a, b in ter.edges:
            ax.plot(*ter.positions[[a, b]].T, color="tab:orange", lw=0.6)
        ax.scatter(ter.positions[:, 0], ter.positions[:, 1], s=6,
                   c=np.where(ter.flags > 0, "tab:blue", "tab:red"))
    team = len(trajectories) > 1
    for i, (xy, chosen) in enumerate(zip(trajectories, goals)):
        colour = ROBOT_COLOURS[i % len(ROBOT_COLOURS)] if team else "lime"
        ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.1 if team else 1.2,
                label=f"robot_{i}" if team else None)
        if team:
            ax.scatter(xy[0, 0], xy[0, 1], s=40, color=colour, marker="o", edgecolor="black",
                       zorder=4)
        if len(chosen):
            ax.scatter(chosen[:, 1], chosen[:, 2], s=8 if team else 10, zorder=3,
                       color=colour if team else "tab:blue", marker="x" if team else "o")
    if team:
        ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    _save(fig, path)


def team_ratio_figure(curve: np.ndarray, robot_curves: list[np.ndarray],
                      path: str | os.PathLike, title: str = "") -> None:
    """A team's exploration ratio over time (black) beside each robot's own coverage
    (what its own scans saw), with the 80, 90 and 98.5 % levels dotted."""
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(curve[:, 0], curve[:, 1], color="black", lw=1.6, label="team")
    for i, c in enumerate(robot_curves):
        if len(c):
            ax.plot(c[:, 0], c[:, 1], color=ROBOT_COLOURS[i % len(ROBOT_COLOURS)], lw=1.0,
                    label=f"robot_{i} (own scans)")
    for level in (0.80, 0.90, 0.985):
        ax.axhline(level, color="grey", lw=0.5, ls=":")
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("exploration ratio")
    ax.set_ylim(0, 1.02)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title)
    _save(fig, path)


def draw_learning_curve(ax, points: list[dict], best: dict | None,
                        lines: dict[str, float]) -> None:
    """A training run's mean validation exploration time (s) per evaluation against the
    decisions trained (``points`` of :func:`mjexplore.eval.learning_curve.learning_curve`),
    the evaluation model selection kept (``best``) starred, and each baseline's mean as a
    horizontal line (``lines``: name -> s)."""
    if points:
        ax.plot([p["steps"] for p in points], [p["mean_exploration_time_s"] for p in points],
                "o-", color="C0", label="policy (mean over layouts)")
    if best is not None:
        ax.plot([best["steps"]], [best["mean_exploration_time_s"]], "*", color="C3",
                markersize=14, label=f"kept ({best['steps']} decisions)")
    styles = {"oracle": ":", "nearest": "-.", "pocket_nearest": "--"}
    for name, value in sorted(lines.items()):
        ax.axhline(value, linestyle=styles.get(name, "--"), color=COLOURS.get(name, "k"),
                   label=f"{name} {value:.0f} s")
    ax.set_xlabel("decisions trained")
    ax.set_title("validation exploration time (s, simulated)")
    if points or lines:
        ax.legend(fontsize=8)


def learning_curve_figure(points: list[dict], lines: dict[str, float], best: dict | None,
                          path: str | os.PathLike, title: str = "") -> None:
    """:func:`draw_learning_curve` alone, as a PNG at ``path``."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    draw_learning_curve(ax, points, best, lines)
    if title:
        ax.set_title(f"{title}: validation exploration time (s, simulated)")
    _save(fig, path)
