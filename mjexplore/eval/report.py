"""The results report: the paper's tables and figures, regenerated from sweep summaries.

``mjexplore report`` reads the summaries that ``mjexplore collect`` wrote (one JSON file per
experiment in ``docs/results/data``) and writes ``docs/results.md`` with its figures in
``docs/results/``. Every number in the report comes from those files; an experiment whose
summary is missing is listed with the command that would make it.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import re
import types
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mjexplore.episode import MILESTONES
from mjexplore.errors import UserInputError
from mjexplore.eval.methods import spec_of_label
from mjexplore.eval.plots import METHOD_LABELS, kinematics_figure, ratio_figure
from mjexplore.eval.stats import compare_paired
from mjexplore.eval.summaries import KINEMATIC_FIELDS, KINEMATICS_DT, ratio_curve, read_summary
from mjexplore.eval.sweep import MEAN_STD_NOTE, format_mean_std, markdown_table, summary_table
from mjexplore.eval.team_report import team_section
from mjexplore.eval.training_record import training_section
from mjexplore.io.atomic import staged_files, write_text_atomic

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
# The team experiments (bench --robots sweeps; their own section, eval/team_report.py).
TEAM_EXPERIMENTS = ("teams", "teams_explore_bench")
# The learned explorer held to issue 17's Table 1 target (the v3 recipe's policy).
TARGET_METHOD = "gvn_v3"


@dataclasses.dataclass(frozen=True)
class Section:
    """What the parts of an experiment's section are made from.

    Attributes:
        name: The experiment's name (figure files are named after it).
        summary: Its sweep summary (``mjexplore collect``).
        groups: Its runs by scene, then method (:func:`_groups`).
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
            "pose):", "", _beside_ideal(s.groups, _groups(s.summaries["table1"])), ""]


def by_localisation(s: Section) -> list[str]:
    """nearest in the realistic setting by where the robot believes it is (the companion
    sweeps of :data:`LOCALIZATION_RUNS`)."""
    if not LOCALIZATION_RUNS.keys() & s.summaries.keys():
        return []
    return ["nearest with the same sensing, by where the robot believes it is "
            "(the companion sweeps below):", "",
            _by_localization({"scan matching": s.groups} | {
                label: _groups(s.summaries[name])
                for name, label in LOCALIZATION_RUNS.items() if name in s.summaries}), ""]


def ladder(s: Section) -> list[str]:
    """The ladder of bounds against pocket_nearest (:func:`ladder_lines`)."""
    return ladder_lines(s.groups)


@dataclasses.dataclass(frozen=True)
class Experiment:
    """One section of the report.

    Attributes:
        name: The summary's file stem in the data folder.
        title: Section heading.
        about: What the experiment is, one paragraph.
        methods: The explorers it compares, in the report's order.
        sweep: The sweep that makes it (then ``mjexplore collect`` of its folder), with
            ``{explorers}`` where the comma-joined methods go.
        parts: What its section shows after the sweep's command, in order: each part makes
            lines (tables, verdicts, figures) from the :class:`Section`.
    """

    name: str
    title: str
    about: str
    methods: tuple[str, ...]
    sweep: str
    parts: tuple[Callable[[Section], list[str]], ...]

    @property
    def command(self) -> str:
        """The sweep's command line (each method by the spec that runs it:
        :func:`~mjexplore.eval.methods.spec_of_label`)."""
        return self.sweep.format(explorers=",".join(spec_of_label(m) for m in self.methods))

    @property
    def with_collect(self) -> str:
        """The sweep's command line, then the collect that files it for the report (with
        ``--merge``: the runs already collected are kept)."""
        if "mjexplore collect" in self.sweep:
            return self.command
        out = re.findall(r"--out (\S+)", self.sweep)[-1]
        return (f"{self.command}; mjexplore collect {out} --experiment {self.name} "
                "--merge")


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


EVAL_SCENES = "loop_with_corridor,maze,office"
EXPLORE_BENCH = ",".join(f"../shared/data/explore_bench/{m}.yaml" for m in (
    "corner", "corridor", "loop", "loop_with_corridor", "room", "room_with_corner"))
EXPERIMENTS = (
    Experiment("table1", "Table 1 and Fig. 5: the three evaluation scenes",
               "Every method on the paper's evaluation scenes (sim profile: 0.5 m/s, 6 m lidar, "
               "full MuJoCo physics); seeds vary the start pose and the sensor noise. "
               "explore_lite is the port of ROS's m-explore, frontier_tsp a global "
               "tour over the known map's frontiers (TARE/FUEL style). The oracle is the "
               "ground-truth bound: it plans on the true map a set of viewpoints that see "
               "the target ratio and an OR-Tools tour through them, re-solved at each "
               "decision (a strong reference for how fast the map can be seen, not a proven "
               "optimum). gvn is the policy of the paper's recipe (training/gvn.yaml), "
               "gvn_v3 that of the v3 recipe (training/gvn_v3.yaml; see its section below).",
               ("nearest", "explore_lite", "frontier_tsp", "rrt", "potential", "cnn", "gvn",
                "gvn_v3", "oracle"),
               f"mjexplore bench --scenes {EVAL_SCENES} --explorers {{explorers}} --seeds 10 "
               "--workers 2 --out runs/table1",
               parts=(results, table1_verdicts, ratio_figures, smoothness, relative_to_nearest)),
    Experiment("gvn_v2", "The v2 recipe on the evaluation scenes",
               "The v2 recipe's policy (training/gvn_v2.yaml: time-to-explore reward, path "
               "costs and reachability per node, a residual on the nearest-node rule; "
               "trained in the grid world on generated layouts, selected on held-out ones) "
               "beside nearest-frontier, the potential field and the CNN baseline trained "
               "with the same recipe and budget (training/cnn_v2.yaml), run by the same "
               "revision in full physics on Table 1's scenes.",
               ("nearest", "potential", "cnn_v2", "gvn_v2"),
               f"mjexplore bench --scenes {EVAL_SCENES} --explorers {{explorers}} --seeds 10 "
               "--workers 2 --out runs/gvn_v2",
               parts=(results, relative_to_nearest)),
    Experiment("gvn_v3", "The v3 recipe on the evaluation scenes",
               "The v3 recipe's policy (training/gvn_v3.yaml: the v2 recipe with each "
               "frontier node's predicted pocket, the probability that the unseen free space "
               "behind it is below 0.5 m^2, from a predictor trained by supervision on "
               "generated layouts, training/pockets.yaml; the actor is a residual on "
               "nearest-frontier that counts such nodes 50 m farther per unit of "
               "probability) beside nearest-frontier, the potential field and the v2 "
               "policy, run by the same revision in full physics on Table 1's scenes.",
               ("nearest", "potential", "gvn_v2", "gvn_v3"),
               f"mjexplore bench --scenes {EVAL_SCENES} --explorers {{explorers}} --seeds 10 "
               "--workers 2 --out runs/gvn_v3",
               parts=(results, relative_to_nearest, target_claims)),
    Experiment("ablation", "Table 2: invalid action masking",
               "The ablation of the paper's Table 2 on the loop and maze scenes: "
               "policies trained without masking (all TER nodes valid), with naive masking "
               "(masked sampling, unmasked gradient), with IAM; and the IAM policy run without "
               "its mask (masking removed).",
               ("gvn_none", "gvn_naive", "gvn_unmasked", "gvn"),
               "mjexplore bench --scenes loop_with_corridor,maze --explorers {explorers} "
               "--seeds 5 --workers 2 --out runs/ablation",
               parts=(ablation_results,)),
    Experiment("ablation_v2", "Table 2 under the v2 recipe",
               "The same ablation with policies trained by the v2 recipe (training/gvn_v2.yaml "
               "and its masking variants gvn_v2_naive.yaml and gvn_v2_none.yaml: the same "
               "reward, layouts, seed and budget: each policy's weights after the same "
               "number of decisions), on the loop and maze "
               "scenes. With every TER node valid, the nearest-node prior the "
               "v2 actor starts from favours the node with the shortest path from the "
               "robot, usually one within zeta of where it stands: such a goal is reached at "
               "once and the next decision follows at the next control period.",
               ("gvn_v2_none", "gvn_v2_naive", "gvn_v2_unmasked", "gvn_v2"),
               "mjexplore bench --scenes loop_with_corridor,maze --explorers {explorers} "
               "--seeds 5 --workers 2 --out runs/ablation_v2",
               parts=(ablation_results,)),
    Experiment("ablation_v3", "Table 2 under the v3 recipe",
               "The same ablation with policies trained by the v3 recipe (training/gvn_v3.yaml "
               "and its masking variants gvn_v3_naive.yaml and gvn_v3_none.yaml: the same "
               "reward, pocket predictor, layouts, seed and budget, and the same model "
               "selection: each policy's weights at the held-out evaluation after 8,192 "
               "decisions), on the loop and maze scenes.",
               ("gvn_v3_none", "gvn_v3_naive", "gvn_v3_unmasked", "gvn_v3"),
               "mjexplore bench --scenes loop_with_corridor,maze --explorers {explorers} "
               "--seeds 5 --workers 2 --out runs/ablation_v3",
               parts=(ablation_results,)),
    Experiment("lobby_real", "Table 3 and Fig. 9: the real-robot setting",
               "The paper's robot experiment in simulation: the 17.5 x 4 m lobby with the real "
               "profile (0.18 m/s, 1.8 rad/s, 5 m lidar; decisions event-driven, as "
               "everywhere).",
               ("nearest", "potential", "gvn", "gvn_v3"),
               "mjexplore bench --scenes lobby --explorers {explorers} --profile real --seeds 5 "
               "--workers 2 --out runs/lobby_real",
               parts=(results, ratio_figures, kinematics_figures, smoothness, paired_with_nearest)),
    Experiment("realistic", "Sensing and localisation as on the real robot",
               "Every method on the evaluation scenes as in Table 1 but with the Turtlebot3's "
               "LDS-01 lidar (5 Hz, 1 degree, 0.12-3.5 m, 3.5 % range noise, dropouts, "
               "motion skew), typical odometry error (wheel radius and track width off, "
               "slip) and the robot localising itself by scan matching: mapping, navigation, "
               "goals and the end of the episode all use its estimate. The exploration ratio "
               "is measured from the same scans at the true poses; IoU compares the robot's "
               "own map with the ground truth, so its distortion shows. The time cap "
               "is 3600 s (with the LDS-01's 3.5 m range nearest needs about 1700 s for the "
               "office even at the true pose: \"Realistic sensing at the true pose\" below). "
               "The oracle plans its paths on the ground-truth "
               "map from the robot's estimated pose, so here it measures the localisation "
               "more than a bound.",
               ("nearest", "explore_lite", "frontier_tsp", "rrt", "potential", "cnn", "gvn",
                "gvn_v3", "oracle"),
               f"mjexplore bench --scenes {EVAL_SCENES} --explorers {{explorers}} --seeds 5 "
               "--lidar-model lds01 --odometry-error typical --localization scan_matching "
               "--max-time 3600 --workers 2 --out runs/realistic",
               parts=(localisation, beside_ideal, by_localisation)),
    Experiment("realistic_truth", "Realistic sensing at the true pose",
               "nearest with the realistic setting's LDS-01 and odometry error, but mapping, "
               "navigating and ending the episode at the true pose: what a perfect localiser "
               "would give (the IoU the realistic runs are measured against).", ("nearest",),
               f"mjexplore bench --scenes {EVAL_SCENES} --explorers {{explorers}} --seeds 5 "
               "--lidar-model lds01 --odometry-error typical --localization ground_truth "
               "--max-time 3600 --workers 2 --out runs/realistic_truth",
               parts=(results,)),
    Experiment("realistic_odometry", "Realistic sensing with odometry alone",
               "nearest with the realistic setting's LDS-01 and odometry error, the robot "
               "dead-reckoning its pose from the wheel odometry (no scan matching): how much "
               "worse it gets without localisation.", ("nearest",),
               f"mjexplore bench --scenes {EVAL_SCENES} --explorers {{explorers}} --seeds 5 "
               "--lidar-model lds01 --odometry-error typical --localization odometry "
               "--max-time 3600 --workers 2 --out runs/realistic_odometry",
               parts=(localisation,)),
    Experiment("realistic_imu", "Realistic sensing with the gyro's heading",
               "nearest in the realistic setting (LDS-01, typical odometry error, scan "
               "matching) with the odometry's heading from the IMU's gyro, as the real "
               "Turtlebot3's own odometry takes it (turtlebot3_node's use_imu): the wheels "
               "give the distance, the gyro (scale, bias and noise of its class, "
               "sim/odometry.py) the heading; the localiser estimates the gyro's bias and "
               "takes a wall into its field after fewer returns and each scan's "
               "information at a quarter (min_density 0.5, scan_correlation 4: the gyro "
               "heading's settings).",
               ("nearest",),
               f"mjexplore bench --scenes {EVAL_SCENES} --explorers {{explorers}} --seeds 5 "
               "--lidar-model lds01 --odometry-error typical --odometry-heading imu "
               "--localization scan_matching --max-time 3600 --workers 2 "
               "--out runs/realistic_imu",
               parts=(localisation,)),
    Experiment("explore_bench", "Generalisation: the Explore-Bench maps",
               "The six Explore-Bench maps (ROS map_server maps imported as MJCF, 7 m lidar), "
               "which no policy was trained on.",
               ("nearest", "explore_lite", "frontier_tsp", "rrt", "potential", "cnn", "cnn_v2",
                "gvn", "gvn_v2", "gvn_v3", "oracle"),
               f"mjexplore bench --scenes {EXPLORE_BENCH} --explorers {{explorers}} --seeds 2 "
               "--lidar-range 7 --workers 2 --out runs/explore_bench",
               parts=(results, functools.partial(relative_to_nearest, places="maps"),
                      paired_with_nearest)),
    Experiment("teams", "Several robots: the evaluation scenes",
               "Teams of 2 and 3 robots on the office (full physics, the CLI's defaults: 6 m "
               "lidar with 0.01 m noise, target 98.5 %), and of 2 robots on "
               "loop_with_corridor and the maze; robot 0 where the single "
               "robot of the same seed starts and the others drawn 1-3 m around it; each "
               "seed's single robot (nearest) beside. assign_greedy: frontier regions "
               "assigned greedily by path cost; naive_nearest: every robot runs nearest on "
               "the shared map; oracle: the ground-truth oracle's viewpoints split into "
               "min-max routes (the bound); +unknown: unknown start poses, each robot mapping "
               "in its own frame until its map is merged into the team's by matching "
               "(docs/guide/teams.md).",
               ("nearest x1 single", "assign_greedy x2 drawn", "assign_greedy+unknown x2 drawn",
                "nearest x2 drawn", "oracle x2 drawn", "assign_greedy x3 drawn",
                "oracle x3 drawn"),
               "mjexplore bench --scenes office --robots 2 --explorers "
               "assign_greedy,nearest,oracle --seeds 5 --workers 1 --out runs/office2; "
               "mjexplore bench --scenes office --robots 2 --unknown-starts --explorers "
               "assign_greedy --seeds 5 --workers 1 --out runs/office2; mjexplore bench "
               "--scenes office --robots 3 --explorers assign_greedy,oracle --seeds 5 "
               "--workers 1 --out runs/office3; mjexplore bench --scenes "
               "loop_with_corridor,maze --robots 2 --explorers assign_greedy,nearest --seeds 3 "
               "--workers 1 --out runs/office2; mjexplore collect runs/office3 --experiment "
               "teams; mjexplore collect runs/office2 --experiment teams --merge",
               parts=(teams,)),
    Experiment("teams_explore_bench", "Several robots: the Explore-Bench maps",
               "Two robots on the six Explore-Bench maps (7 m lidar, full physics) "
               "from the benchmark's close and far placements, the naive team (nearest) "
               "against greedy frontier assignment, and the single robot (nearest, from the "
               "map's own start) beside.",
               ("nearest x1 single", "nearest x2 close", "nearest x2 far",
                "assign_greedy x2 close", "assign_greedy x2 far"),
               f"mjexplore bench --scenes {EXPLORE_BENCH} --lidar-range 7 --robots 2 --starts "
               "close,far --explorers nearest,assign_greedy --seeds 3 --workers 1 "
               "--out runs/eb2; mjexplore collect runs/eb2 --experiment teams_explore_bench",
               parts=(teams,)),
    Experiment("ladder", "The ladder of bounds: what knowing more of the layout is worth",
               "Explorers that differ only in what they know, on Table 1's scenes in full "
               "physics: pocket_nearest (the learned pocket classifier on "
               "nearest-frontier); pocket_truth, the same rule with the true pockets; "
               "distance_advantage (Ericson et al. 2025) alone and on the pocket prior "
               "(pocket_advantage); oracle_2m/5m/10m, the oracle's planner given the truth "
               "within r of the mapped cells and driving on it; the oracle, given all of it "
               "(docs/guide/prediction.md).",
               ("nearest", "pocket_nearest", "pocket_truth", "distance_advantage",
                "pocket_advantage", "oracle_2m", "oracle_5m", "oracle_10m", "oracle"),
               f"mjexplore bench --scenes {EVAL_SCENES} --explorers {{explorers}} --seeds 10 "
               "--workers 2 --out runs/ladder",
               parts=(results, ladder)),
    Experiment("ariadne", "Generalisation: the ARiADNE test maps",
               "ARiADNE's 100 test maps at 0.1 m per pixel (64 x 48 m) with an 8 m lidar, which "
               "no policy was trained on. Path lengths are set beside the greedy planner's, "
               "measured in ARiADNE's own environment (its travel in pixels x 0.1 m). The "
               "completion tests differ: ARiADNE's greedy run stops when its graph has no "
               "utility left (99.9 % of the free pixels seen on average), an mjexplore episode "
               "at 98.5 % of the observable free space; the last 1.5 % costs path.",
               ("nearest", "explore_lite", "frontier_tsp", "rrt", "potential", "cnn", "cnn_v2",
                "gvn", "gvn_v2", "gvn_v3", "oracle"),
               "for f in ../shared/data/ariadne_test/img_*.png; do mjexplore scene-gen "
               "--from-map $f --resolution 0.1 --out runs/ariadne_scenes/$(basename $f .png); "
               "done; mjexplore bench --scenes $(ls -d runs/ariadne_scenes/* | paste -sd,) "
               "--explorers {explorers} --seeds 1 --lidar-range 8 --workers 2 "
               "--out runs/ariadne",
               parts=(ariadne,)),
)


def _ordered(names) -> list[str]:
    return sorted(names, key=lambda m: (METHOD_ORDER.index(m) if m in METHOD_ORDER else 99, m))


def _groups(summary: dict[str, Any]) -> dict[str, dict[str, list[dict[str, Any]]]]:
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


def build_report(data_dir: str | os.PathLike, out: str | os.PathLike,
                 figures_dir: str | os.PathLike | None = None) -> Path:
    """Writes the report and its figures from the summaries in ``data_dir``.

    Args:
        data_dir: Folder of ``EXPERIMENT.json`` summaries (``mjexplore collect``).
        out: The markdown file to write (``docs/results.md``).
        figures_dir: Where figures go; default ``OUT_STEM/`` beside ``out``. Stills that
            ``collect --stills`` copied there are linked.

    Returns:
        The path of the report.

    Raises:
        UserInputError: A summary is damaged, or named for no experiment the report knows.
    """
    out = Path(out)
    data = Path(data_dir)
    known = {exp.name for exp in EXPERIMENTS}
    unknown = sorted(p.name for p in data.glob("*.json") if p.stem not in known)
    if unknown:
        raise UserInputError(f"{', '.join(unknown)} in {str(data)!r}: not an experiment the "
                             f"report knows ({', '.join(sorted(known))}); rename or remove.")
    summaries = {exp.name: read_summary(data / f"{exp.name}.json") for exp in EXPERIMENTS
                 if (data / f"{exp.name}.json").is_file()}
    final = Path(figures_dir) if figures_dir is not None else out.with_suffix("")
    # The figures are made aside and moved in only when the whole report is made: a failure
    # leaves the figures and report of the last run as they were.
    with staged_files(final) as figures:
        lines = _report_lines(summaries, data, out, figures, os.path.relpath(final, out.parent))
        write_text_atomic(out, "\n".join(lines))
    return out


def _report_lines(summaries: dict[str, dict[str, Any]], data: Path, out: Path, figures: Path,
                  rel: str) -> list[str]:
    """The report's lines; its figures are written into ``figures``, linked as ``rel``."""
    lines = ["# Results: mjexplore's reproduction of the EMExplorer experiments", "",
             "Generated by `mjexplore report` from the sweep summaries in "
             f"`{os.path.relpath(data, out.parent)}/` (made by `mjexplore collect` from the "
             "sweeps named in each section); do not edit by hand. Times are simulated "
             "seconds, lengths metres. " + MEAN_STD_NOTE + " ET is when the episode ended: for a "
             "run that stopped before 98.5 % it is shorter than a full exploration, so read it "
             "with the explored count and T98.5.", ""]
    missing = []
    for exp in EXPERIMENTS:
        if exp.name not in summaries:
            missing.append(exp)
            continue
        summary = summaries[exp.name]
        groups = _groups(summary)
        lines += [f"## {exp.title}", "", exp.about, "", "Sweep:", "", "```bash",
                  summary.get("command") or exp.command, "```", "", what_ran(summary), ""]
        policies = {m: rec for m, rec in (summary.get("policies") or {}).items() if rec}
        used = summary.get("run_weights") or {}
        if policies:
            lines += ["Policies: " + ", ".join(
                f"{m} trained for {rec['num_timesteps']:,} decision steps (weights sha256 "
                f"`{rec['sha256']}`)" for m, rec in policies.items()) + ".", ""]
            stale = {m: used[m] for m, rec in policies.items() if used.get(m) and
                     used[m] != [rec["sha256"]]}
            if stale:  # The runs name their weights: say so when they are not these.
                lines += ["The runs used other weights than the shipped ones: " + ", ".join(
                    f"{m} {', '.join(f'`{h}`' for h in hashes)}"
                    for m, hashes in stale.items()) + ".", ""]
        section = Section(exp.name, summary, groups, figures, rel, summaries)
        for part in exp.parts:
            lines += part(section)
        ran = {m for methods in groups.values() for m in methods}
        absent = tuple(m for m in exp.methods if m not in ran)
        if absent and "{explorers}" in exp.sweep:
            lines += [f"Not in this sweep yet: {', '.join(absent)}. Add them with "
                      f"`{dataclasses.replace(exp, methods=absent).with_collect}`, then rerun "
                      "the report.", ""]
        elif absent:
            lines += [f"Not in this sweep yet: {', '.join(absent)} (the commands above make "
                      "them).", ""]
        stills = summary.get("stills") or {}
        if stills:
            method = summary.get("stills_method", "gvn")
            lines += [f"### Fig. 6: {method}'s final maps", "",
                      "Seed 0 on each scene: the map at the end, the trajectory and the TER.", ""]
            lines += [f"![{scene}: final map, trajectory and TER]({rel}/{still})"
                      for scene, still in stills.items()] + [""]
    lines += training_section(data, figures, rel)
    lines += revisions_section(summaries)
    if missing:
        lines += ["## Not yet run", "", "Run the sweep and collect it, then `mjexplore report`:",
                  ""]
        for exp in missing:
            lines += [f"- **{exp.title}** ({exp.name}): `{exp.with_collect}`"]
        lines.append("")
    return lines


def what_ran(summary: dict[str, Any]) -> str:
    """What a summary's runs are, from the runs themselves: how many, per scene and method,
    the world, the time cap, lidar, localisation and target, and the revisions."""
    runs = summary["runs"]
    per = Counter((r["scene"], r["method"]) for r in runs)
    low, high = min(per.values()), max(per.values())
    each = f"{low} run{'s' if low > 1 else ''}" if low == high else f"{low} to {high} runs"
    episode = summary.get("episode") or {}
    sim = episode.get("sim") or {}
    lidar = sim.get("lidar") or {}
    facts = [f"{len(runs)} runs: {each} of each of {len(per)} scene and method pairs",
             f"{sim.get('dynamics', 'physics')} world",
             f"{sim.get('profile', 'sim')} profile"]
    if lidar:
        facts.append(f"{lidar.get('model', 'ideal')} lidar to {lidar['range_max']:g} m")
    if "max_time" in episode:
        facts.append(f"time cap {episode['max_time']:g} s")
    if "target_ratio" in episode:
        facts.append(f"target {100 * episode['target_ratio']:g} %")
    facts.append(f"localisation {episode.get('localization', 'ground_truth')}")
    revisions = summary.get("run_revisions") or ["not recorded"]
    facts.append("revision " + ", ".join(f"`{r[:7]}`" for r in revisions))
    return "Ran: " + "; ".join(facts) + "."


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


def _run_key(summary: dict[str, Any], run: dict[str, Any]) -> tuple:
    """What decides a run's episode: scene, method, seed, map resolution, weights and the
    sweep's episode settings (as JSON, so that equal settings compare equal)."""
    return (run["scene"], run["method"], run["seed"], run.get("resolution"),
            run["metrics"].get("weights_sha256"),
            json.dumps(summary.get("episode"), sort_keys=True))


def revisions_section(summaries: dict[str, dict[str, Any]]) -> list[str]:
    """Which code revision each experiment's runs came from (as each run's folder recorded
    it), and, where two experiments ran at different revisions, whether the runs they share
    (the same scene, method, seed, weights and episode settings) came out the same."""
    rows, singles = [], {}
    for name, summary in summaries.items():
        revisions = summary.get("run_revisions") or []
        rows.append([name, str(len(summary["runs"])),
                     ", ".join(f"`{r[:7]}`" for r in revisions) or "not recorded"])
        if len(revisions) == 1:
            singles[name] = revisions[0]
    lines = ["## Revisions", "",
             "The code revision each experiment's runs recorded (`git_revision` in each run "
             "folder's config.json; `-dirty` would mark a tree with uncommitted changes).", "",
             markdown_table(["experiment", "runs", "revision"], rows), ""]
    checks = []
    names = list(singles)  # In the report's order.
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if singles[a] == singles[b]:
                continue
            runs_b = {_run_key(summaries[b], r): r["metrics"] for r in summaries[b]["runs"]}
            shared = [(r["metrics"], runs_b[k]) for r in summaries[a]["runs"]
                      if (k := _run_key(summaries[a], r)) in runs_b]
            if shared:
                same = sum(x == y for x, y in shared)
                checks.append(f"{a} (`{singles[a][:7]}`) and {b} (`{singles[b][:7]}`) share "
                              f"{len(shared)} runs: {same} of them identical in every metric.")
    if checks:
        lines += ["Runs of the same episode (scene, method, seed, weights and settings) in "
                  "experiments made at different revisions:", ""]
        lines += [f"- {c}" for c in checks] + [""]
    return lines


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


__all__ = ["EXPERIMENTS", "build_report", "claims_table", "masking_verdict",
           "revisions_section", "target_verdict"]
