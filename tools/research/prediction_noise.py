"""How good must a prediction be for ``predicted_drive`` to pay? The explorer on the truth at
the predictor's 0.2 m cells, with a share of those cells flipped at random (free <-> wall),
against ``pocket_nearest`` on the same layouts; prints one JSON line.

Each episode is a layout of the config's evaluation (``tools/ladder.py``'s episodes: the
grid world for the v3 recipe). The prediction at each decision is the truth's free share of
each 0.2 m cell, and with ``flip`` > 0 each cell's share is replaced by one minus it with
that probability (drawn afresh at each decision, seeded per episode): the salt-and-pepper
error of a predictor with accuracy about 1 - ``flip``. ``flip`` 0 separates what the coarse
cells cost from what the errors cost. With ``--fixed`` the flipped cells are drawn once per
episode and stay flipped (until mapped): errors as many, but the same at every decision, so
the plan does not change for them.

Rows go to ``OUT/rows.jsonl`` (resumed at the same revision), the summary (each setting's
paired ratio to pocket_nearest) to ``OUT/summary.json`` and stdout.

Usage: python -m tools.research.prediction_noise --out runs/prediction_noise
    [--flips 0,0.05,0.1] [--fixed] [--layouts validation:8] [--workers 1]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from tools.ladder import _layouts, episode_row, run_ladder

BASELINE = "pocket_nearest"


def _noisy_truth(flip: float, fixed: bool):
    """A ``predicted_drive`` whose prediction is the coarse truth, ``flip`` of it flipped
    (the same cells all episode when ``fixed``)."""
    from mjexplore.explorers.predicted_tour import PredictedDrive, free_probability
    from mjexplore.mapping.prediction import block_shares, block_size
    from mjexplore.maps import is_free

    class NoisyTruthDrive(PredictedDrive):
        def __init__(self) -> None:
            super().__init__(source="inpainting")  # Replaced below: no predictor loaded.
            self.name = f"coarse_truth_{'fixed' if fixed else 'flip'}{flip:g}"

        def reset(self, rng: np.random.Generator) -> None:
            super().reset(rng)
            self._rng = np.random.default_rng(0)
            self._flipped: np.ndarray | None = None

        def free_probability(self, state):
            truth = state.ground_truth
            k = block_size(truth)
            share = block_shares(is_free(truth.data), k)
            if flip:
                if self._flipped is None or not fixed:
                    self._flipped = self._rng.random(share.shape) < flip
                share = np.where(self._flipped, 1.0 - share, share)
            return free_probability(state.grid, lambda channels: share)

    return NoisyTruthDrive()


def _explorer(method: str):
    from mjexplore.explorers import make_explorer

    if method == BASELINE:
        return make_explorer(method)
    setting = method.removeprefix("coarse_truth_")  # flipF or fixedF
    fixed = setting.startswith("fixed")
    return _noisy_truth(float(setting.removeprefix("fixed" if fixed else "flip")), fixed)


def _episode(job: tuple[str, str, str, str]) -> dict:
    return episode_row(job, _explorer)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="training/gvn_v3.yaml")
    parser.add_argument("--layouts", default="validation:8",
                        help="validation:N (the first N), validation, unseen:N or test:N")
    parser.add_argument("--flips", default="0,0.05,0.1")
    parser.add_argument("--fixed", action="store_true",
                        help="flip the same cells at every decision of an episode")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    from mjexplore.learning.train_config import load_train_config

    config = load_train_config(args.config)
    scenes = _layouts(config, args.layouts)
    kind = "fixed" if args.fixed else "flip"
    methods = [BASELINE] + [f"coarse_truth_{kind}{float(f):g}" for f in args.flips.split(",")]
    print(json.dumps(run_ladder(Path(args.out), args.config, args.layouts, scenes, methods,
                                BASELINE, args.workers, _episode)))


if __name__ == "__main__":
    main()
