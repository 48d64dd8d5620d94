"""The map predictors' quality on one held-out set, at one revision: for each weights file,
and for the three non-learned predictors, the cross-entropy, accuracy, free-space IoU and
calibration error on the unknown cells of the held-out episodes' partial maps, and on those
within 1, 2 and 5 m of a known cell (``--within``); prints one JSON line and writes it to
``--out`` (the report's ``predictor/quality.json``).

The held-out maps are those of a ``train-predictor`` run's folder (``--data``: its
``data/``; every ``validation_every``-th episode of ``--config``), so predictors fitted at
other revisions, or with other training seeds on the same maps, are measured on the same
cells by the same code.

Usage: python tools/predictor_quality.py --data runs/train/predictor/data
    --models seed0=models/map_predictor/predictor.safetensors,seed1=PATH,...
    [--config training/predictor.yaml] [--within 1,2,5]
    --out docs/results/data/predictor/quality.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="a train-predictor run's data/ folder")
    parser.add_argument("--models", required=True, help="LABEL=WEIGHTS,... (predictor files)")
    parser.add_argument("--config", default="training/predictor.yaml")
    parser.add_argument("--within", default="1,2,5",
                        help="also score the unknown cells within each of these distances "
                             "of a known cell, metres (comma-separated; '' for none)")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    import torch

    from mjexplore.errors import UserInputError
    from mjexplore.io.atomic import write_text_atomic
    from mjexplore.io.provenance import file_sha256, git_revision
    from mjexplore.learning.predictor_training import load_predictor_config, load_shards
    from mjexplore.mapping.prediction import BASELINES, MapPredictor, prediction_quality

    torch.set_num_threads(1)
    try:
        models = dict(item.split("=", 1) for item in args.models.split(","))
        config = load_predictor_config(args.config)
        _, held = load_shards(config, Path(args.data))
        predictors = {label: MapPredictor(path) for label, path in models.items()}
    except (UserInputError, ValueError, OSError) as exc:
        print(f"predictor_quality: {exc} (--models takes LABEL=PATH,...)", file=sys.stderr)
        raise SystemExit(2) from None
    maps = [(channels, part["truth"]) for part in held for channels in part["inputs"]]
    within = [float(r) for r in args.within.split(",") if r]
    predicted = {label: [p(c) for c, _ in maps] for label, p in predictors.items()}
    predicted.update({name: [predict(c) for c, _ in maps]
                      for name, predict in BASELINES.items()})

    def quality(name: str, within_m: float | None = None) -> dict:
        return prediction_quality(((q, c, t) for q, (c, t) in zip(predicted[name], maps)),
                                  within_m=within_m)

    result = {
        "revision": git_revision(), "config": args.config,
        "held_episodes": len(held), "held_maps": len(maps),
        "models": {label: {"weights_sha256": file_sha256(Path(models[label])),
                           "fitted_at": p.provenance.get("git_revision"),
                           "training_seed": (p.provenance.get("config") or {}).get("seed"),
                           **quality(label)}
                   for label, p in predictors.items()},
        "baselines": {name: quality(name) for name in BASELINES},
        # Near what is known: the cells a planner on the prediction reaches first.
        "within_m": {f"{r:g}": {name: quality(name, r) for name in predicted}
                     for r in within},
    }
    write_text_atomic(Path(args.out), json.dumps(result, indent=1) + "\n")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
