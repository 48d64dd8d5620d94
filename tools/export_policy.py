"""Exports the policy of a training checkpoint as safetensors weights.

Usage: python tools/export_policy.py runs/train/gvn/checkpoints/step_000012288.pt \
           training/gvn_policy.safetensors
"""

from __future__ import annotations

import argparse
import json

from mjexplore.training import export_checkpoint


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("out")
    parser.add_argument("--git-revision", default=None,
                        help="the revision the run was started from, if the checkpoint "
                        "records another")
    args = parser.parse_args()
    provenance = export_checkpoint(args.checkpoint, args.out, args.git_revision)
    print(json.dumps({"out": args.out, "num_timesteps": provenance["num_timesteps"],
                      "git_revision": provenance["git_revision"]}))


if __name__ == "__main__":
    main()
