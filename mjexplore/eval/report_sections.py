"""The parts of the results report's sections: tables, verdicts and figures made from a
sweep summary's runs (:class:`Section`), which each experiment of the catalogue
(:mod:`mjexplore.eval.experiments`) lists in the order its section shows them."""

from __future__ import annotations

import dataclasses
import types
from pathlib import Path
from typing import Any

import numpy as np

from mjexplore.episode import MILESTONES
from mjexplore.eval.people_report import people_lines
from mjexplore.eval.plots import METHOD_LABELS, kinematics_figure, ratio_figure
from mjexplore.eval.stats import compare_paired
from mjexplore.eval.summaries import KINEMATIC_FIELDS, KINEMATICS_DT, ratio_curve
from mjexplore.eval.sweep import format_mean_std, markdown_table, summary_table
from mjexplore.eval.team_report import team_section

METHOD_ORDER = ("nearest", "pocket_nearest", "pocket_truth", "distance_advantage",
                "pocket_advantage", "explore_lite", "frontier_tsp", "rrt", "potential",
                "cnn", "cnn_v2", "gvn_none", "gvn_naive", "gvn_unmasked", "gvn", "gvn_v2_none",
                "gvn_v2_naive", "gvn_v2_unmasked", "gvn_v2", "gvn_v3_none", "gvn_v3_naive",
                "gvn_v3_unmasked", "gvn_v3", "oracle_2m", "oracle_5m", "oracle_10m", "oracle")
# The paper's claim (Sec. "Comparison with baselines"): gvn is faster than the potential field
# by this range of percentages to the given exploration ratio.
PAPER_SPEEDUP = {"t80_s": (7.0, 11.1), "t985_s": (4.0, 16.2)}
ABLATION_NAMES = {"gvn_none": "no masking (trained and run without)",
                  "gvn_naive": "naive masking (trained with it)",
                  "gvn_unmasked": "masking removed (IAM-trained, run unmasked)",
                  "gvn": "masking (IAM)"}
# The same four variants trained with the v2 and v3 recipes (training/gvn_v2*.yaml, v3*).
ABLATION_NAMES |= {f"gvn_{recipe}{k[3:]}": v for k, v in ABLATION_NAMES.items()
                   for recipe in ("v2", "v3")}
# Experiment -> its IAM method.
ABLATIONS = {"ablation": "gvn", "ablation_v2": "gvn_v2", "ablation_v3": "gvn_v3"}
# The learned explorer held to issue 17's Table 1 target (the v3 recipe's policy).
TARGET_METHOD = "gvn_v3"


@dataclasses.dataclass(frozen=True)
class Section:
    """What the parts of an experiment's section are made from.

    Attributes:
        name: The experiment's name (figure files are named after it).
        summary: Its sweep summary (``mjexplore collect``).
        groups: Its runs by scene, then method (:func:`group_runs`).
        figures: The folder figures are written to.
        rel: That folder as the report links it.
        summaries: Every experiment's summary, for parts that set one beside another.
    """

    name: str
    summary: dict[str, Any]
    groups: dict[str, dict[str, list[dict[str, Any]]]]
    figures: Path
    rel: str
    summaries: dict[str, dict[str, Any]]


def results(s: Section, rename: dict[str, str] | None = None,
            verdict: str | None = None) -> list[str]:
    """Table 1's columns per scene and method, how episodes ended, the masking verdict on
    ``verdict`` (an ablation's IAM method) and the runs the sweep has not finished."""
    lines = [_table(s.groups, rename), "",
             _other_ends(s.groups, rename, s.summary.get("episode")), ""]
    if verdict is not None:
        lines += [masking_verdict(s.groups, verdict), ""]
    note = _unfinished_note(s.summary)
    return lines + ([note, ""] if note else [])


def ablation_results(s: Section) -> list[str]:
    """:func:`results` with the ablation's names and its masking verdict."""
    return results(s, ABLATION_NAMES, ABLATIONS[s.name])


def table1_verdicts(s: Section) -> list[str]:
    """The target method against the best classic, every method paired against
    nearest-frontier, and the paper's claims (gvn against the potential field)."""
    lines = []
    if any(TARGET_METHOD in methods for methods in s.groups.values()):
        lines += [target_verdict(s.groups, TARGET_METHOD), ""]
    lines += _paired_lines(s.groups)
    claims, faster = claims_table(s.groups)
    if faster:
        lines += ["### The paper's claims", "",
                  "gvn's time to 80 % and to 98.5 % against the potential field's (mean "
                  "over the runs that reached the level; (k/n) when fewer did). The paper "
                  "reports gvn 7.0-11.1 % faster to 80 % and 4.0-16.2 % faster to 98.5 %.",
                  "", claims, "", _verdict(s.groups, faster), "",
                  "What differs from the paper's setting, whatever the numbers: " + SETTING, ""]
    return lines


def target_claims(s: Section) -> list[str]:
    """The target method against the best classic and the paper's claims for it."""
    claims, faster = claims_table(s.groups, TARGET_METHOD)
    return [target_verdict(s.groups, TARGET_METHOD), "",
            "The paper's claims, for gvn_v3: its time to 80 % and to 98.5 % against the "
            "potential field's, beside the range the paper reports for its gvn.", "",
            claims, "", _verdict(s.groups, faster, TARGET_METHOD), ""]


def ratio_figures(s: Section) -> list[str]:
    """Fig. 5: the exploration ratio over time per scene, milestones marked."""
    lines = []
    for scene, methods in s.groups.items():
        fig = f"{s.name}_ratio_{scene}.png"
        reached = {m: {level: [r["metrics"][key] for r in runs
                               if r["metrics"][key] is not None]
                       for level, key in MILESTONES}
                   for m, runs in methods.items()}
        ratio_figure({m: [ratio_curve(r) for r in runs] for m, runs in methods.items()},
                     s.figures / fig, f"{scene}: exploration ratio over time",
                     mark_times=reached)
        lines += [f"![{scene}: exploration ratio]({s.rel}/{fig})", ""]
    return lines


def kinematics_figures(s: Section) -> list[str]:
    """Fig. 9: velocity and acceleration over time per scene (runs collected with their
    series)."""
    lines = []
    for scene, methods in s.groups.items():
        with_series = {m: runs for m, runs in methods.items()
                       if all("series" in r["kinematics"] for r in runs)}
        if with_series:
            fig = f"{s.name}_kinematics_{scene}.png"
            kinematics_figure({m: _kinematics_logs(runs) for m, runs in with_series.items()},
                              s.figures / fig, f"{scene}: velocity and acceleration "
                              f"({KINEMATICS_DT} s bin means; mean and min-max over runs)")
            lines += [f"![{scene}: kinematics]({s.rel}/{fig})", ""]
    return lines


def smoothness(s: Section) -> list[str]:
    """Table 3's kinematic fluctuation per method."""
    return ["Kinematic fluctuation per run (then mean +- std over runs):", "",
            smoothness_table(s.groups), ""]


def relative_to_nearest(s: Section, places: str = "scenes") -> list[str]:
    """Each method relative to nearest-frontier, averaged over the ``places``."""
    return [f"Averaged over the {places}, relative to nearest-frontier on the same "
            f"{places[:-1]} (ratios of means; below 1 is faster):", "",
            relative_table(s.groups, places=places), ""]


def paired_with_nearest(s: Section) -> list[str]:
    """Every method paired per seed against nearest-frontier."""
    return _paired_lines(s.groups)


def people(s: Section) -> list[str]:
    """The people benchmark over its crowd sizes (:mod:`mjexplore.eval.people_report`)."""
    return people_lines(s.summaries)


def teams(s: Section) -> list[str]:
    """A team sweep's section (:mod:`mjexplore.eval.team_report`)."""
    return team_section(s.name, s.summary)


def ariadne(s: Section) -> list[str]:
    """ARiADNE's maps: relative and paired tables, the greedy planner's reference paths."""
    note = _unfinished_note(s.summary)
    return [relative_table(s.groups), "", *_paired_lines(s.groups), reference_table(s.summary),
            "", _other_ends(s.groups, episode=s.summary.get("episode")), ""] + \
        ([note, ""] if note else [])


def localisation(s: Section) -> list[str]:
    """A sweep whose robot localises itself: its table and the pose error of its estimate."""
    aligned = ("; the aligned RMSE after the rotation and translation that fit the "
               "estimated trajectory best to the true one, the absolute trajectory error "
               "of SLAM benchmarks: the distortion of the trajectory and its map without "
               "the offset of their frame, which IoU counts in full"
               ) if _aligned_column(s.groups) else ""
    return [_table(s.groups), "", _other_ends(s.groups, episode=s.summary.get("episode")), "",
            "Pose error of the robot's estimate (metres; RMSE and maximum over each "
            f"run's scans{aligned}):", "", _pose_table(s.groups), ""]


def beside_ideal(s: Section) -> list[str]:
    """The realistic setting's times beside Table 1's (ideal sensing, true pose)."""
    if "table1" not in s.summaries:
        return []
    return ["Beside the ideal setting (Table 1's runs: ideal lidar, ground-truth "
            "pose):", "", _beside_ideal(s.groups, group_runs(s.summaries["table1"])), ""]


def by_localisation(s: Section) -> list[str]:
    """nearest in the realistic setting by where the robot believes it is (the companion
    sweeps of :data:`LOCALIZATION_RUNS`)."""
    if not LOCALIZATION_RUNS.keys() & s.summaries.keys():
        return []
    return ["nearest with the same sensing, by where the robot believes it is "
            "(the companion sweeps below):", "",
            _by_localization({"scan matching": s.groups} | {
                label: group_runs(s.summaries[name])
                for name, label in LOCALIZATION_RUNS.items() if name in s.summaries}), ""]


def ladder(s: Section) -> list[str]:
    """The ladder of bounds against pocket_nearest (:func:`ladder_lines`)."""
    return ladder_lines(s.groups)


LADDER_BASELINE = "pocket_nearest"


def ladder_lines(groups) -> list[str]:
    """Each method against ``pocket_nearest`` paired per scene and seed: the mean ratio per
    scene ("-" where it did not run), the mean over the scenes it ran on, and the interval
    and faster/slower count of those scenes' seeds pooled."""
    rows = []
    scenes = [s for s, methods in groups.items() if LADDER_BASELINE in methods]
    for method in _ordered({m for s in scenes for m in groups[s]}):
        cells: list[str] = []
        ratios: list[float] = []
        pooled: tuple[list[float], list[float]] = ([], [])
        for scene in scenes:
            mine = {r["seed"]: r["metrics"]["exploration_time_s"]
                    for r in groups[scene].get(method, [])}
            base = {r["seed"]: r["metrics"]["exploration_time_s"]
                    for r in groups[scene][LADDER_BASELINE]}
            seeds = sorted(mine.keys() & base.keys())
            if not seeds:
                cells.append("-")
                continue
            ratios.append(compare_paired([mine[k] for k in seeds],
                                         [base[k] for k in seeds]).mean)
            cells.append(f"{ratios[-1]:.3f}")
            pooled[0].extend(mine[k] for k in seeds)
            pooled[1].extend(base[k] for k in seeds)
        if ratios:
            c = compare_paired(*pooled)
            rows.append([METHOD_LABELS.get(method, method), *cells, str(len(ratios)),
                         f"{np.mean(ratios):.3f}", f"{c.low:.3f}-{c.high:.3f}",
                         f"{c.faster} / {c.slower}"])
    if not rows:
        return []
    return [f"Each method's exploration time over {LADDER_BASELINE}'s, paired per seed: per "
            "scene ('-': not run yet), the mean over the scenes it ran on, and the interval "
            "and faster/slower count of those scenes' seeds pooled:", "",
            markdown_table(["method", *scenes, "scenes", "mean", "95 % interval (pooled)",
                            "faster / slower"], rows), ""]


def _ordered(names) -> list[str]:
    return sorted(names, key=lambda m: (METHOD_ORDER.index(m) if m in METHOD_ORDER else 99, m))


def group_runs(summary: dict[str, Any]) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """Runs by scene (in first-seen order) then method (in METHOD_ORDER), seeds sorted."""
    by_scene: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for run in summary["runs"]:
        by_scene.setdefault(run["scene"], {}).setdefault(run["method"], []).append(run)
    return {scene: {m: sorted(methods[m], key=lambda r: r["seed"])
                    for m in _ordered(methods)} for scene, methods in by_scene.items()}


def _table(groups, rename=None) -> str:
    rename = rename or METHOD_LABELS
    header, rows = summary_table({(scene, rename.get(m, m)): [r["metrics"] for r in runs]
                                  for scene, methods in groups.items()
                                  for m, runs in methods.items()})
    return markdown_table(header, rows)


def _aligned_column(*sweeps) -> list[tuple[str, str]]:
    """[(metric, column label)] of the aligned pose error when a run of the sweeps' groups
    has it (runs from before it existed do not), else []."""
    if any("pose_error_aligned_rmse_m" in r["metrics"] for groups in sweeps
           for methods in groups.values() for runs in methods.values() for r in runs):
        return [("pose_error_aligned_rmse_m", "pose RMSE aligned (m)")]
    return []


def _pose_table(groups) -> str:
    columns = [("pose_error_rmse_m", "pose RMSE (m)"),
               ("pose_error_max_m", "pose max (m)")] + _aligned_column(groups)
    rows = [[scene, METHOD_LABELS.get(m, m), len(runs)] +
            [format_mean_std([r["metrics"].get(key) for r in runs]) for key, _ in columns]
            for scene, methods in groups.items() for m, runs in methods.items()]
    return markdown_table(["scene", "method", "runs"] + [label for _, label in columns], rows)


def _explored(runs: list[dict[str, Any]]) -> str:
    """'k/n': runs that reached the target ratio, of all."""
    explored = sum(r["metrics"]["end_reason"] == "explored" for r in runs)
    return f"{explored}/{len(runs)}"


def _beside_ideal(groups, ideal) -> str:
    """Explored runs, ET and IoU of each (scene, method) here and in the ideal setting."""
    rows = []
    for scene, methods in groups.items():
        for m, runs in methods.items():
            row = [scene, METHOD_LABELS.get(m, m)]
            for runs_ in (runs, ideal.get(scene, {}).get(m, [])):
                row += [_explored(runs_),
                        format_mean_std([r["metrics"]["exploration_time_s"] for r in runs_]),
                        format_mean_std([r["metrics"]["iou"] for r in runs_])]
            rows.append(row)
    return markdown_table(["scene", "method", "explored", "ET (s)", "IoU", "ideal: explored",
                           "ideal: ET (s)", "ideal: IoU"], rows)


# The realistic setting's companion sweeps: nearest with the same sensing, localised
# otherwise.
LOCALIZATION_RUNS = {"realistic_truth": "ground truth", "realistic_odometry": "odometry",
                     "realistic_imu": "scan matching, gyro heading"}


def _by_localization(settings: dict[str, dict], method: str = "nearest") -> str:
    """Explored runs, ET, IoU and pose error of ``method`` on each scene under each
    localisation (``settings``: label -> the sweep's groups)."""
    rows = []
    scenes = dict.fromkeys(scene for groups in settings.values() for scene in groups)
    columns = [("exploration_time_s", "ET (s)"), ("iou", "IoU"),
               ("pose_error_rmse_m", "pose RMSE (m)")] + _aligned_column(*settings.values())
    for scene in scenes:
        for label, groups in settings.items():
            runs = groups.get(scene, {}).get(method, [])
            if not runs:
                continue
            rows.append([scene, label, _explored(runs)] + [
                format_mean_std([r["metrics"].get(key) for r in runs]) for key, _ in columns])
    return markdown_table(["scene", "localisation", "explored"] +
                          [label for _, label in columns], rows)


def _lingering_rule(episode: dict) -> str:
    """What ``lingering`` meant under the runs' episode settings: since ``linger_strikes``
    exists, that many goals in a row given up for lingering on one spot."""
    nav = episode.get("navigator") or {}
    spot = f"{nav.get('linger_time', 60.0):g} s within {nav.get('linger_radius', 0.5):g} m"
    strikes = episode.get("linger_strikes")
    return spot if strikes is None else f"{strikes} goals in a row given up after {spot} each"


def _other_ends(groups, rename=None, episode: dict | None = None) -> str:
    """The runs that ended before the target ratio, by end reason (``episode``: the
    summary's episode settings, for what ``lingering`` meant)."""
    rename = rename or METHOD_LABELS
    parts = []
    ended: set[str] = set()
    for scene, methods in groups.items():
        for m, runs in methods.items():
            reasons = [r["metrics"]["end_reason"] for r in runs
                       if r["metrics"]["end_reason"] != "explored"]
            ended.update(reasons)
            if reasons:
                counts = ", ".join(f"{reason} x{reasons.count(reason)}"
                                   for reason in sorted(set(reasons)))
                parts.append(f"{scene} / {rename.get(m, m)}: {counts}")
    if not parts:
        return "Every run reached the target ratio."
    rule = _lingering_rule(episode or {})
    lost = ("; lost: the robot's estimate off its own map or inside a wall"
            if "lost" in ended else "")
    return (f"Runs that ended before the target ratio (lingering: {rule}; "
            f"no_frontiers: none left reachable{lost}; time_limit: the cap): " +
            "; ".join(parts) + ".")


def _unfinished_note(summary: dict[str, Any]) -> str | None:
    """The planned episodes the tables lack: failed ones and those never run."""
    unfinished = summary.get("unfinished") or {}
    parts = []
    for key, what in (("failed", "failed (an error)"),
                      ("not_run", "not run (the sweep was stopped first)")):
        runs = unfinished.get(key) or []
        if runs:
            listed = ", ".join(f"{r['scene']} / {r['method']} / seed {r['seed']}"
                               for r in runs[:10])
            more = f" and {len(runs) - 10} more" if len(runs) > 10 else ""
            parts.append(f"{len(runs)} {what}: {listed}{more}")
    return ("Planned episodes missing from the tables: " + "; ".join(parts) + ".") if parts \
        else None


def _mean_level_time(runs: list[dict[str, Any]], key: str) -> tuple[float | None, int]:
    times = [r["metrics"].get(key) for r in runs]
    reached = [t for t in times if t is not None]
    return (float(np.mean(reached)) if reached else None), len(reached)


def _reached(n: int, runs: list) -> str:
    return "" if n == len(runs) else f" ({n}/{len(runs)})"


def claims_table(groups, method: str = "gvn") -> tuple[str, list[bool]]:
    """``method``'s speed-up over the potential field to 80 % and 98.5 % per scene, beside
    the paper's range for gvn; returns the markdown and, per (scene, level), whether it is
    faster."""
    header = ["scene", "level", f"{method} (s)", "potential (s)", f"{method} faster by",
              "paper", "agrees"]
    rows, faster = [], []
    for scene, methods in groups.items():
        if method not in methods or "potential" not in methods:
            continue
        for key, label in (("t80_s", "80 %"), ("t985_s", "98.5 %")):
            g, ng = _mean_level_time(methods[method], key)
            p, npot = _mean_level_time(methods["potential"], key)
            lo, hi = PAPER_SPEEDUP[key]
            if g is None or p is None:
                rows.append([scene, label, "-", "-", "-", f"{lo}-{hi} %", "no data"])
                continue
            gain = 100.0 * (p - g) / p
            verdict = "yes" if lo <= gain <= hi else ("faster, by more" if gain > hi else
                                                       "faster, by less" if gain > 0 else "no")
            rows.append([scene, label, f"{g:.1f}{_reached(ng, methods[method])}",
                         f"{p:.1f}{_reached(npot, methods['potential'])}", f"{gain:+.1f} %",
                         f"{lo}-{hi} %", verdict])
            faster.append(gain > 0)
    return markdown_table(header, rows), faster


SETTING = (
    "(1) budget: the shipped policies trained on 2 CPU cores for the decision steps named "
    "above, where the paper used 16 rollout processes (and states no training length); (2) "
    "scale: the procedural training layouts are 12-28 x 10-20 m, so the 24 x 24 m loop and "
    "the 20 x 20 m maze are within the training distribution's scale and the 40 x 25 m "
    "office is beyond it; (3) the policies train in the "
    "kinematic mode and are evaluated in full MuJoCo physics; (4) the potential field and "
    "the nearest frontier are mjexplore's implementations of refs. [7] and [6], which drive "
    "with the same planner and controller as gvn: only the choice of goals differs.")


def _ratio_of_means(runs: list[dict[str, Any]], baseline: list[dict[str, Any]],
                    key: str) -> float:
    """Mean of ``key`` over ``runs`` divided by its mean over ``baseline``."""
    return float(np.mean([r["metrics"][key] for r in runs]) /
                 np.mean([r["metrics"][key] for r in baseline]))


def _verdict(groups, faster: list[bool], method: str = "gvn") -> str:
    """One sentence per method pair the paper ranks: how ``method`` fares against the
    others."""
    parts = [f"{method} is faster than the potential field on {sum(faster)} of the "
             f"{len(faster)} (scene, level) pairs above."]
    for other in ("potential", "nearest"):
        pairs = [(ms[method], ms[other]) for ms in groups.values()
                 if method in ms and other in ms]
        if pairs:
            et = [_ratio_of_means(g, o, "exploration_time_s") for g, o in pairs]
            pl = [_ratio_of_means(g, o, "path_length_m") for g, o in pairs]
            parts.append(f"Averaged over the {len(pairs)} scenes, {method}'s ET is "
                         f"{np.mean(et):.2f}x and its PL {np.mean(pl):.2f}x {other}'s.")
    return " ".join(parts)


def _kinematics_logs(runs: list[dict[str, Any]]) -> list[types.SimpleNamespace]:
    logs = []
    for run in runs:
        series = run["kinematics"]["series"]
        values = {f: np.asarray(series[f]) for f in KINEMATIC_FIELDS}
        t = (np.arange(len(values["linear_velocity"])) + 0.5) * series["dt"]
        logs.append(types.SimpleNamespace(t=t, **values))
    return logs


def smoothness_table(groups) -> str:
    """Mean over runs of each run's kinematic fluctuation statistics, per scene and method."""
    names = (("linear_velocity_std", "std v (m/s)"), ("angular_velocity_rms", "rms omega (rad/s)"),
             ("linear_acceleration_rms", "rms a (m/s^2)"),
             ("angular_acceleration_rms", "rms alpha (rad/s^2)"))
    rows = [[scene, METHOD_LABELS.get(m, m)]
            + [format_mean_std([r["kinematics"]["stats"][k] for r in runs]) for k, _ in names]
            for scene, methods in groups.items() for m, runs in methods.items()]
    return markdown_table(["scene", "method"] + [label for _, label in names], rows)


def relative_table(groups, baseline: str = "nearest", places: str = "maps") -> str:
    """Per method, its ET and PL over ``baseline``'s on the same scene, averaged over scenes
    where both ran (ratios of means; < 1 is better)."""
    rows = []
    methods = _ordered({m for ms in groups.values() for m in ms})
    for m in methods:
        et, pl, n = [], [], 0
        for ms in groups.values():
            if m in ms and baseline in ms:
                et.append(_ratio_of_means(ms[m], ms[baseline], "exploration_time_s"))
                pl.append(_ratio_of_means(ms[m], ms[baseline], "path_length_m"))
                n += sum(r["metrics"]["end_reason"] == "explored" for r in ms[m])
        if et:
            runs = sum(len(ms[m]) for ms in groups.values() if m in ms and baseline in ms)
            rows.append([METHOD_LABELS.get(m, m), len(et), f"{n}/{runs}", f"{np.mean(et):.3f}",
                         f"{np.mean(pl):.3f}"])
    return markdown_table(["method", places, "explored", f"ET / {baseline} ET",
                           f"PL / {baseline} PL"], rows)


# The classic planners a learned explorer is judged against (the oracle is a bound, not one).
CLASSIC_METHODS = ("nearest", "pocket_nearest", "explore_lite", "frontier_tsp", "rrt",
                   "potential")


def paired_table(groups, method: str) -> str | None:
    """``method``'s exploration time against the best classic planner on each scene (the
    lowest mean ET among :data:`CLASSIC_METHODS` there), paired per seed: mean of the
    per-seed ratios, bootstrap 95 % interval, seeds faster/slower and the sign test's p; a
    last row pools every scene's seeds. None where ``method`` ran beside no classic."""
    rows: list[list[str]] = []
    pooled: tuple[list[float], list[float]] = ([], [])
    for scene, methods in groups.items():
        classics = [m for m in CLASSIC_METHODS if m in methods]
        if method not in methods or not classics:
            continue
        best = min(classics, key=lambda m: np.mean(
            [r["metrics"]["exploration_time_s"] for r in methods[m]]))
        mine = {r["seed"]: r["metrics"]["exploration_time_s"] for r in methods[method]}
        theirs = {r["seed"]: r["metrics"]["exploration_time_s"] for r in methods[best]}
        seeds = sorted(mine.keys() & theirs.keys())
        if not seeds:
            continue
        a, b = [mine[s] for s in seeds], [theirs[s] for s in seeds]
        pooled[0].extend(a)
        pooled[1].extend(b)
        rows.append(_paired_row(scene, f"{METHOD_LABELS.get(best, best)} (of "
                                f"{len(classics)})", compare_paired(a, b)))
    if not rows:
        return None
    if len(rows) > 1:
        every = _paired_row("all", "each scene's best", compare_paired(*pooled))
        # Scenes of one seed each (ARiADNE's maps) say little one by one: the pool alone.
        rows = [every] if all(r[2] == 1 for r in rows) else rows + [every]
    return markdown_table(["scene", "best classic", "seeds", f"{method} ET / best ET",
                           "95 % interval", "faster / slower", "sign test p"], rows)


def _paired_row(scene: str, best: str, c) -> list:
    return [scene, best, len(c.ratios), f"{c.mean:.3f}", f"{c.low:.3f}-{c.high:.3f}",
            f"{c.faster}/{c.slower}", f"{c.p_value:.3g}"]


def _variant(method: str) -> str:
    """A masking variant's name without its explanation ('naive masking')."""
    return ABLATION_NAMES.get(method, method).split(" (")[0]


def masking_verdict(groups, iam: str) -> str:
    """Whether IAM (method ``iam``) is the best masking variant on each scene: the variant
    with the most runs that reached the target ratio, then the lowest mean ET, is best. A
    lead smaller than the larger of the two runs' standard deviations is called
    inconclusive."""
    parts, best_on = [], 0
    scenes = [s for s, methods in groups.items() if iam in methods and len(methods) > 1]
    for scene in scenes:
        # Per variant: (-runs explored, mean ET, std ET); sorting puts the best first.
        stats = {}
        for m, runs in groups[scene].items():
            times = [r["metrics"]["exploration_time_s"] for r in runs]
            stats[m] = (-sum(r["metrics"]["end_reason"] == "explored" for r in runs),
                        float(np.mean(times)), float(np.std(times)))
        order = sorted(stats, key=lambda m: stats[m][:2])
        first, second = order[0], order[1]
        (explored1, et1, std1), (explored2, et2, std2) = stats[first], stats[second]
        close = explored1 == explored2 and et2 - et1 < max(std1, std2)
        doubt = " (within the runs' spread: not conclusive)" if close else ""
        if first == iam:
            best_on += 1
            parts.append(f"on {scene} IAM is best: {et1:.1f} s against "
                         f"{_variant(second)}'s {et2:.1f} s{doubt}")
        else:
            parts.append(f"on {scene} IAM is not best: {_variant(first)} "
                         f"is ({et1:.1f} s against IAM's {stats[iam][1]:.1f} s, "
                         f"ranked {order.index(iam) + 1} of {len(order)}){doubt}")
    if not scenes:
        return "IAM did not run beside another variant: no verdict."
    overall = ("IAM is best on every scene" if best_on == len(scenes) else
               "IAM is not best on any scene" if best_on == 0 else
               f"IAM is best on {best_on} of {len(scenes)} scenes")
    return (f"Is IAM best? {overall} (best: the most runs that reached 98.5 %, then the "
            f"lowest mean ET): " + "; ".join(parts) + ".")


def reference_table(summary: dict[str, Any]) -> str:
    """Path lengths on the ARiADNE maps beside the greedy reference (metres)."""
    ref = {Path(r["map"]).stem: r for r in summary.get("reference") or []}
    by_method: dict[str, list[tuple[dict[str, Any], dict[str, Any]]]] = {}
    for run in summary["runs"]:
        if run["scene"] in ref and run.get("resolution"):
            by_method.setdefault(run["method"], []).append((run, ref[run["scene"]]))
    rows = []
    for m in _ordered(by_method):
        pairs = by_method[m]
        explored = [(r, g) for r, g in pairs if r["metrics"]["end_reason"] == "explored"]
        pl = [r["metrics"]["path_length_m"] for r, _ in explored]
        greedy = [g["travel"] * r["resolution"] for r, g in explored]
        ratio = np.asarray(pl) / np.asarray(greedy) if pl else np.array([])
        rows.append([METHOD_LABELS.get(m, m), len(pairs), len(explored),
                     format_mean_std([r["metrics"]["exploration_time_s"] for r, _ in explored]),
                     format_mean_std(pl), format_mean_std(greedy),
                     f"{np.mean(ratio):.3f} (median {np.median(ratio):.3f})" if len(ratio)
                     else "-"])
    return markdown_table(["method", "maps", "explored", "ET (s)", "PL (m)",
                           "greedy PL (m), same maps", "PL / greedy PL"], rows)


def _paired_lines(groups) -> list[str]:
    """The paired comparison of the learned explorer with the best classic, if both ran."""
    table = paired_table(groups, TARGET_METHOD)
    if table is None:
        return []
    return [f"{TARGET_METHOD} against the best classic planner of each scene "
            f"({', '.join(CLASSIC_METHODS)}, those that ran), paired per seed (ratios of "
            "exploration times; the interval resamples the seeds; the sign test counts the "
            "seeds it was faster and slower on). The best is picked on these same runs, "
            "which favours the classics most where a scene has few seeds:", "", table, ""]


def target_verdict(groups, method: str, limit: float = 0.90) -> str:
    """Whether ``method`` meets issue 17's Table 1 target on these scenes: every run
    explored, below both nearest-frontier and the potential field on every scene, and its
    exploration time averaged over the scenes at most ``limit`` x the better of the two."""
    ratios, below_both, explored, runs = [], [], 0, 0
    for methods in groups.values():
        if not {method, "nearest", "potential"} <= methods.keys():
            continue
        mine = methods[method]
        explored += sum(r["metrics"]["end_reason"] == "explored" for r in mine)
        runs += len(mine)
        others = [_ratio_of_means(mine, methods[o], "exploration_time_s")
                  for o in ("nearest", "potential")]
        ratios.append(max(others))  # Against the better (faster) of the two.
        below_both.append(max(others) < 1.0)
    if not ratios:
        return f"No scene has {method}, nearest and potential together."
    mean = float(np.mean(ratios))
    met = explored == runs and all(below_both) and mean <= limit
    return (f"{method} explored {explored} of {runs} runs; its exploration time is below both "
            f"nearest-frontier's and the potential field's on {sum(below_both)} of "
            f"{len(ratios)} scenes, and averaged over the scenes {mean:.3f} x the better of "
            f"the two on each (target: every run, every scene, <= {limit:.2f}): "
            f"{'met' if met else 'not met'}.")
