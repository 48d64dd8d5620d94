"""The report's multi-robot sections: team sweeps (``bench --robots N``) summarised by
``mjexplore collect``, with the single robot's time beside and issue 37's bars checked.

A team summary's runs carry ``placement`` ('single' for the single robot's baseline runs),
``robots`` and ``revision`` besides the usual keys, and as ``method`` the sweep folder's
method with both (``assign_greedy x2 far``; :func:`~mjexplore.eval.summaries.collect_sweep`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mjexplore.eval.sweep import markdown_table
from mjexplore.eval.team_sweep import TABLE_NOTE, single_ratios, team_table
from mjexplore.explorers.team import TEAM_METHODS

# Issue 37's bars on the office: the best coordination's time to 98.5 % over the single
# robot's, per team size; and the largest merge error with unknown start poses (m, deg).
RATIO_BARS = {2: 0.60, 3: 0.45}
MERGE_BAR = (0.10, 1.0)
# Team methods that are no coordination of their own: the bound and unknown starts.
NOT_COORDINATION = ("oracle",)

Groups = dict[tuple[str, str, str, int], list[tuple[int, dict[str, Any]]]]


def _label(folder: str) -> str:
    """A team run's method as the table names it: the sweep folder's (``+unknown`` kept), a
    naive team's (a single-robot method's folder) as ``naive_METHOD``."""
    return folder if folder.split("+")[0] in TEAM_METHODS else "naive_" + folder


def team_groups(summary: dict[str, Any]) -> tuple[dict[tuple[str, int], dict[str, Any]],
                                                   Groups, dict[tuple, list[str]]]:
    """The single robot's metrics by (scene, seed), the team runs by (scene, placement,
    method, robots), and each group's run revisions."""
    single: dict[tuple[str, int], dict[str, Any]] = {}
    groups: Groups = {}
    revisions: dict[tuple, list[str]] = {}
    for run in summary["runs"]:
        folder = run["method"].rsplit(" ", 2)[0]
        if run.get("robots", 1) == 1:
            single[(run["scene"], run["seed"])] = {**run["metrics"], "explorer": folder}
            key: tuple = (run["scene"], "-", f"single {folder}", 1)
        else:
            key = (run["scene"], run["placement"], _label(folder), run["robots"])
            groups.setdefault(key, []).append((run["seed"], run["metrics"]))
        revisions.setdefault(key, []).append(str(run.get("revision") or "not recorded"))
    return single, groups, revisions


def _coordinated(method: str) -> bool:
    return not (method.startswith("naive_") or "+unknown" in method or
                method in NOT_COORDINATION)


def office_verdict(single, groups: Groups) -> list[str]:
    """Per scene and team size, the best coordination's ratio to the single robot, with
    issue 37's bars on the office; every run explored, robot-robot collisions; the merge
    error with unknown starts."""
    lines = []
    for scene in sorted({k[0] for k in groups}, key=lambda sc: (sc != "office", sc)):
        for robots in sorted({k[3] for k in groups if k[0] == scene}):
            best = None
            for key, runs in groups.items():
                if key[0] != scene or key[3] != robots or not _coordinated(key[2]):
                    continue
                ratios = single_ratios(single, scene, runs)
                if ratios and (best is None or np.mean(ratios) < best[0]):
                    best = float(np.mean(ratios)), key, runs, ratios
            if best is None:
                continue
            ratio, key, runs, ratios = best
            ms = [m for _, m in runs]
            explored = sum(m["end_reason"] == "explored" for m in ms)
            bar = RATIO_BARS.get(robots) if scene == "office" else None
            verdict = "" if bar is None else \
                f"; the bar is <= {bar:.2f}: {'met' if ratio <= bar else 'NOT met'}"
            lines.append(
                f"- {scene}, {robots} robots: the best coordination, {key[2]}, took "
                f"{ratio:.3f} x the single robot's time to 98.5 % (per seed "
                f"{', '.join(f'{r:.3f}' for r in ratios)}{verdict}); {explored} of "
                f"{len(ms)} runs explored; robot-robot collisions "
                f"{sum(m.get('robot_collisions', 0) for m in ms)}, wall collisions "
                f"{sum(m.get('collisions', 0) for m in ms)}.")
    for key, runs in sorted(groups.items()):
        if "+unknown" not in key[2]:
            continue
        ms = [m for _, m in runs]
        merged = [m for m in ms if m.get("merged")]
        errors = [(m["merge_error_m"], m["merge_error_deg"]) for m in merged]
        explored = sum(m["end_reason"] == "explored" for m in ms)
        within = sum(e[0] <= MERGE_BAR[0] and e[1] <= MERGE_BAR[1] for e in errors)
        worst = (f"largest error {max(e[0] for e in errors):.3f} m and "
                 f"{max(e[1] for e in errors):.2f} deg" if errors else "no merge")
        ratios = single_ratios(single, key[0], runs)
        times = ", ".join(f"{m['merge_time_s']:.1f}" for m in merged)
        lines.append(
            f"- Unknown start poses ({key[2]}, {key[3]} robots, {key[1]} starts): "
            f"{len(merged)} of {len(ms)} runs merged their maps ({worst}; {within} within "
            f"the bar of {MERGE_BAR[0]:.2f} m and {MERGE_BAR[1]:.0f} deg), merged after "
            f"{times} s; {explored} of "
            f"{len(ms)} explored to 98.5 %"
            + (f", {np.mean(ratios):.3f} x the single robot's time." if ratios else "."))
    return lines


def pair_verdict(groups: Groups, naive: str = "naive_nearest",
                 assigned: str = "assign_greedy") -> list[str]:
    """The assignment baseline against the naive team over the maps and placements both
    ran (issue 37: it should beat the naive team's time and overlap on average)."""
    pairs = []
    for key, runs in groups.items():
        if key[2] != assigned:
            continue
        other = groups.get((key[0], key[1], naive, key[3]))
        if not other:
            continue
        a = [m for _, m in runs if m.get("t985_s")]
        b = [m for _, m in other if m.get("t985_s")]
        if a and b:
            pairs.append((np.mean([m["t985_s"] for m in a]), np.mean([m["t985_s"] for m in b]),
                          np.mean([m["overlap_ratio"] for m in a]),
                          np.mean([m["overlap_ratio"] for m in b])))
    if not pairs:
        return []
    p = np.array(pairs)
    faster = int((p[:, 0] < p[:, 1]).sum())
    less = int((p[:, 2] < p[:, 3]).sum())
    time_ok = p[:, 0].mean() < p[:, 1].mean()
    overlap_ok = p[:, 2].mean() < p[:, 3].mean()
    return [f"- {assigned} against the naive team ({naive}) over the {len(p)} map and "
            f"placement pairs both ran: time to 98.5 % {p[:, 0].mean():.1f} s against "
            f"{p[:, 1].mean():.1f} s on average (faster on {faster} of {len(p)}), overlap "
            f"{p[:, 2].mean():.3f} against {p[:, 3].mean():.3f} (lower on {less}): the "
            f"assignment {'beats' if time_ok and overlap_ok else 'does NOT beat'} the naive "
            f"team's time and overlap on average"
            + ("" if time_ok and overlap_ok else
               f" ({'time' if time_ok else 'not time'}, "
               f"{'overlap' if overlap_ok else 'not overlap'})") + "."]


def team_section(name: str, summary: dict[str, Any]) -> list[str]:
    """The report's lines for a team experiment (``teams``, ``teams_explore_bench``)."""
    single, groups, revisions = team_groups(summary)
    header, rows = team_table(single, groups)
    lines = [markdown_table(header, rows), "", TABLE_NOTE, ""]
    verdict = office_verdict(single, groups) if name == "teams" else pair_verdict(groups)
    if verdict:
        lines += ["Issue 37's bars on these runs:", "", *verdict, ""]
    def named(revs) -> str:
        return ", ".join(f"`{r[:7]}`" + ("-dirty" if r.endswith("dirty") else "")
                         for r in sorted(set(revs)))

    every = {r for revs in revisions.values() for r in revs}
    if len(every) == 1:
        return lines + [f"Every run was made at revision {named(every)}.", ""]
    rev_rows = [[*key, named(revs)]
                for key, revs in sorted(revisions.items(), key=lambda kv: str(kv[0]))]
    lines += ["Revision of every run, by group:", "",
              markdown_table(["scene", "placement", "method", "robots", "revision"], rev_rows),
              ""]
    return lines


__all__ = ["MERGE_BAR", "RATIO_BARS", "office_verdict", "pair_verdict", "team_groups",
           "team_section"]
