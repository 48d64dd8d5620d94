"""The report's people benchmark: explorers among 0, 5, 10 and 20 pedestrians.

Each crowd size is a sweep of its own (``bench --people N``; a summary mixes no settings):
the experiment ``people`` holds the runs without people and :data:`CROWDS` names the
experiments of the others. :func:`people_lines` sets them side by side per scene and method:
how many runs explored, the exploration time and its ratio to the same seed's run without
people (paired), the static-map IoU and its change, robot-person contacts, the least gap to
a person and the time the robot stood still; then the issue's checks on them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mjexplore.eval.sweep import format_mean_std, markdown_table

# Crowd size -> the experiment whose summary holds its runs (0: the section's own).
CROWDS = {0: "people", 5: "people_5", 10: "people_10", 20: "people_20"}
# Largest loss of static-map IoU at 10 people against the runs without (issue 51).
IOU_BAR = 0.05

Runs = dict[str, dict[str, list[dict[str, Any]]]]  # scene -> method -> runs


def crowd_runs(summaries: dict[str, dict[str, Any]]) -> dict[int, Runs]:
    """The runs of each crowd size whose summary exists, by scene and method."""
    out: dict[int, Runs] = {}
    for count, name in CROWDS.items():
        if name not in summaries:
            continue
        groups: Runs = {}
        for run in summaries[name]["runs"]:
            groups.setdefault(run["scene"], {}).setdefault(run["method"], []).append(run)
        out[count] = groups
    return out


def _by_seed(runs: list[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    return {int(r["seed"]): r["metrics"] for r in runs}


def _ratios(runs: list[dict[str, Any]], alone: list[dict[str, Any]], key: str) -> list[float]:
    """Per seed both ran: ``key`` among people over ``key`` without (where both have it)."""
    mine, base = _by_seed(runs), _by_seed(alone)
    return [mine[s][key] / base[s][key] for s in sorted(mine.keys() & base.keys())
            if mine[s].get(key) and base[s].get(key)]


def _iou_changes(runs: list[dict[str, Any]], alone: list[dict[str, Any]]) -> list[float]:
    mine, base = _by_seed(runs), _by_seed(alone)
    return [mine[s]["iou"] - base[s]["iou"] for s in sorted(mine.keys() & base.keys())
            if mine[s].get("iou") is not None and base[s].get("iou") is not None]


def _mean(values: list[float], digits: int = 3) -> str:
    return f"{np.mean(values):.{digits}f}" if values else "-"


def people_table(crowds: dict[int, Runs]) -> tuple[list[str], list[list[Any]]]:
    """Per scene, method and crowd size: runs, explored, ET, x the seed's run without
    people, IoU, its change, contacts, the least gap and the time stood still."""
    header = ["scene", "method", "people", "runs", "explored", "ET (s)", "x no people",
              "IoU", "IoU change", "contacts", "least gap (m)", "stood still (s)"]
    rows = []
    alone = crowds.get(0, {})
    scenes = list(dict.fromkeys(sc for groups in crowds.values() for sc in groups))
    for scene in scenes:
        methods = list(dict.fromkeys(m for groups in crowds.values()
                                     for m in groups.get(scene, {})))
        for method in methods:
            base = alone.get(scene, {}).get(method, [])
            for count in sorted(crowds):
                runs = crowds[count].get(scene, {}).get(method)
                if not runs:
                    continue
                ms = [r["metrics"] for r in runs]
                gaps = [m["people_min_distance_m"] for m in ms
                        if m.get("people_min_distance_m") is not None]
                rows.append([
                    scene, method, count, len(ms),
                    sum(m["end_reason"] == "explored" for m in ms),
                    format_mean_std([m.get("exploration_time_s") for m in ms]),
                    "1" if count == 0 else _mean(_ratios(runs, base, "exploration_time_s")),
                    format_mean_std([m.get("iou") for m in ms]),
                    "-" if count == 0 else _mean(_iou_changes(runs, base), 4),
                    "-" if count == 0 else sum(int(m.get("people_collisions", 0)) for m in ms),
                    f"{min(gaps):.3f}" if gaps else "-",
                    "-" if count == 0 else format_mean_std(
                        [m.get("time_stopped_s") for m in ms], digits=1)])
    return header, rows


def people_checks(crowds: dict[int, Runs]) -> list[str]:
    """The issue's checks: every run explored, contacts counted, IoU within
    :data:`IOU_BAR` of the runs without people at 10 people, what 20 people cost."""
    lines = []
    every = [(count, r) for count, groups in crowds.items() for methods in groups.values()
             for runs in methods.values() for r in runs]
    if not every:
        return []
    unexplored = [r for _, r in every if r["metrics"]["end_reason"] != "explored"]
    lines.append(f"- Explored: {len(every) - len(unexplored)} of {len(every)} runs"
                 + ("." if not unexplored else ": not " + ", ".join(
                     f"{r['scene']}/{r['method']}/seed{r['seed']} "
                     f"({r['metrics']['end_reason']})" for r in unexplored[:8])
                    + (" ..." if len(unexplored) > 8 else "") + "."))
    contacts = sum(int(r["metrics"].get("people_collisions", 0)) for c, r in every if c)
    among = sum(1 for c, _ in every if c)
    lines.append(f"- Robot-person contacts: {contacts} over the {among} runs among people.")
    alone = crowds.get(0, {})
    for count, verb in ((10, "IoU"), (20, "time")):
        if count not in crowds or not alone:
            continue
        per_method = []
        for scene, methods in crowds[count].items():
            for method, runs in methods.items():
                base = alone.get(scene, {}).get(method, [])
                if verb == "IoU":
                    changes = _iou_changes(runs, base)
                    if changes:
                        per_method.append((scene, method, float(np.mean(changes))))
                else:
                    ratios = _ratios(runs, base, "exploration_time_s")
                    if ratios:
                        per_method.append((scene, method, float(np.mean(ratios))))
        if not per_method:
            continue
        if verb == "IoU":
            worst = min(per_method, key=lambda t: t[2])
            held = sum(abs(v) <= IOU_BAR for _, _, v in per_method)
            lines.append(f"- Static-map IoU at 10 people against the same seeds without: "
                         f"within {IOU_BAR} for {held} of {len(per_method)} scene and method "
                         f"pairs (the largest loss {-worst[2]:.4f}, {worst[1]} on "
                         f"{worst[0]}).")
        else:
            values = [v for _, _, v in per_method]
            lines.append(f"- 20 people cost {100 * (np.mean(values) - 1):.0f} % in "
                         f"exploration time on average over the {len(values)} scene and "
                         f"method pairs (paired per seed; from {min(values):.2f}x to "
                         f"{max(values):.2f}x).")
    return lines


def people_lines(summaries: dict[str, dict[str, Any]]) -> list[str]:
    """The benchmark's table and checks, from the summaries of :data:`CROWDS`."""
    crowds = crowd_runs(summaries)
    if not crowds:
        return []
    header, rows = people_table(crowds)
    missing = [str(c) for c in CROWDS if c not in crowds]
    lines = [markdown_table(header, rows), "",
             "ET: mean +- std of the exploration time; 'x no people' and 'IoU change': "
             "against the run of the same scene, method and seed without people, averaged "
             "over the seeds; contacts: robot-person contacts (those less than 0.5 s apart "
             "as one); least gap: between the robot's bounding circle and a person's disc, "
             "over the runs.", ""]
    if missing:
        lines += [f"Crowd sizes not collected yet: {', '.join(missing)}.", ""]
    checks = people_checks(crowds)
    return lines + (["The issue's checks on these runs:", "", *checks, ""] if checks else [])


__all__ = ["CROWDS", "IOU_BAR", "crowd_runs", "people_checks", "people_lines", "people_table"]
