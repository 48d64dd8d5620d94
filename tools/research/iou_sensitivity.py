"""How much IoU a rigid offset of an otherwise perfect map costs; prints one JSON line.

Runs nearest once with the LDS-01 (motion skew off, so each scan is posed by its own
stamp) and ground-truth localisation, keeps its scans, and maps them again with every pose
moved by one rigid transform of the whole ``map`` frame: a translation along x, or a turn
about the start. The map is as good as the lidar makes it, only its frame is off, which is
what an early heading error of a localiser does to a map (see ``pose_error_aligned_rmse_m``
in metrics.json). ``iou`` is the episode's metric (the mean of the free and the occupied
IoU, 5 cm cells); ``iou_drop`` each offset's loss against the unmoved map of the same run.

Usage: python -m tools.research.iou_sensitivity [--scene loop_with_corridor] [--seed 0]
    [--max-time 3600]
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

SHIFTS_M = (0.01, 0.02, 0.05)
TURNS_DEG = (0.05, 0.1, 0.2, 0.5)


class _Scans:
    """An episode observer that keeps every scan."""

    def __init__(self) -> None:
        self.scans = []

    def on_scan(self, episode, scan) -> None:
        self.scans.append(scan)

    def on_decision(self, episode, state) -> None:
        pass

    def on_step(self, episode) -> None:
        pass


def remapped_iou(episode, scans, shift: float, turn: float) -> float:
    """IoU of ``scans`` mapped at their true poses moved by ``shift`` metres along x and
    turned by ``turn`` radians about the scene's start."""
    from mjexplore.mapping.metrics import iou
    from mjexplore.mapping.occupancy import MapperConfig, OccupancyMapper

    gt = episode.scene.ground_truth
    mapper = OccupancyMapper.like(gt, MapperConfig(resolution=gt.resolution))
    x0, y0 = episode.scene.start[:2]
    c, s = math.cos(turn), math.sin(turn)
    for scan in scans:
        x, y, yaw = scan.pose
        mapper.integrate(scan, np.array([x0 + c * (x - x0) - s * (y - y0) + shift,
                                         y0 + s * (x - x0) + c * (y - y0), yaw + turn]))
    return iou(mapper.grid, episode.reference)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="loop_with_corridor")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-time", type=float, default=3600.0,
                        help="the episode's time cap, simulated seconds")
    args = parser.parse_args()
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.episode.nearest import NearestFrontier
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.sim.lidar import lidar_model
    from mjexplore.sim.simulator import SimConfig

    scans = _Scans()
    config = EpisodeConfig(max_time=args.max_time, localization="ground_truth",
                           sim=SimConfig(lidar=lidar_model("lds01", motion_skew=False)))
    episode = Episode(resolve_scene(args.scene), NearestFrontier(), args.seed, config,
                      observer=scans)
    metrics = episode.run().metrics
    base = remapped_iou(episode, scans.scans, 0.0, 0.0)
    out = {"scene": args.scene, "seed": args.seed, "scans": len(scans.scans),
           "episode_iou": metrics["iou"], "iou": round(base, 4)}
    for shift in SHIFTS_M:
        out[f"iou_drop_shift_{shift * 100:g}cm"] = round(
            base - remapped_iou(episode, scans.scans, shift, 0.0), 4)
    for turn in TURNS_DEG:
        out[f"iou_drop_turn_{turn:g}deg"] = round(
            base - remapped_iou(episode, scans.scans, 0.0, math.radians(turn)), 4)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
