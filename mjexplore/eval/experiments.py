"""The experiments of the results report: what each compares, the sweep that makes it, and
the parts of its section (:mod:`mjexplore.eval.report_sections`)."""

from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Callable

from mjexplore.eval.methods import spec_of_label
from mjexplore.eval.report_sections import (
    Section,
    ablation_results,
    ariadne,
    beside_ideal,
    by_localisation,
    kinematics_figures,
    ladder,
    localisation,
    paired_with_nearest,
    people,
    ratio_figures,
    relative_to_nearest,
    results,
    smoothness,
    table1_verdicts,
    target_claims,
    teams,
)


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


# The people benchmark's methods: every classic explorer, the pocket rule, the recommended
# learned one.
PEOPLE_METHODS = ("nearest", "explore_lite", "frontier_tsp", "rrt", "potential",
                  "distance_advantage", "pocket_nearest", "gvn_v3")


def _people_sweep(count: int) -> str:
    """The bench command of the people benchmark's crowd of ``count`` (0: nobody). The cap
    is an hour: rrt on the office outlasts Table 1's half hour even without people."""
    crowd = f" --people {count}" if count else ""
    return (f"mjexplore bench --scenes office,maze --explorers {{explorers}} --seeds 5{crowd} "
            f"--max-time 3600 --workers 2 --out runs/people{count}")


def _people_experiment(count: int) -> Experiment:
    return Experiment(
        f"people_{count}", f"Among {count} people",
        f"The people benchmark's runs among {count} pedestrians (full physics; the office "
        "and the maze; social-force walkers, mocap bodies the lidar sees and the robot can "
        "touch; docs/guide/people.md), in Table 1's columns.",
        PEOPLE_METHODS,
        _people_sweep(count) + f"; mjexplore collect runs/people{count} --experiment "
        f"people_{count}",
        parts=(results,))


# The team experiments (bench --robots sweeps; their own section, eval/team_report.py).
TEAM_EXPERIMENTS = ("teams", "teams_explore_bench")
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
    Experiment("people", "People in the building: exploring among pedestrians",
               "Every classic explorer, pocket_nearest and the recommended learned one (gvn_v3) on"
               " the office and the maze with 0, 5, 10 and 20 people walking between random goals "
               "(full physics, 5 seeds, an hour's cap; the people of a seed are the same for every"
               " method). Returns from people are left out of the map and the people a scan sees "
               "are obstacles in the robot's costmap; a robot whose way only people block waits, "
               "and a velocity check slows or stops it before it comes within 0.1 m of one "
               "(docs/guide/people.md). Each crowd size is a sweep of its own; the sections after "
               "this one give each in Table 1's columns.",
               PEOPLE_METHODS,
               "; ".join([_people_sweep(0)] + [_people_sweep(n) for n in (5, 10, 20)] +
                         ["mjexplore collect runs/people0 --experiment people"] +
                         [f"mjexplore collect runs/people{n} --experiment people_{n}"
                          for n in (5, 10, 20)]),
               parts=(people,)),
    *(_people_experiment(n) for n in (5, 10, 20)),
)
