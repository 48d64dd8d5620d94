"""Exports the policy of a training checkpoint as safetensors weights, or (--onnx) the actor
of a weights file as an ONNX model.

Usage: python tools/export_policy.py runs/train/gvn/checkpoints/step_000012288.pt \
           models/gvn_paper/policy.safetensors
       python tools/export_policy.py --onnx models/gvn_paper/policy.safetensors gvn_policy.onnx

The ONNX model takes the decision's observation arrays (flat, batch first, in the order of
its ``observation_keys`` metadata) and the boolean ``action_mask``, and returns the masked
action logits and the greedy action (see mjexplore/policies/onnx_export.py). Prints one
JSON line; bad input (a missing or damaged source, an OUT whose suffix is not the format
written, an OUT that cannot be written) gets a one-line error and exit code 2, and nothing is
written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import check_output_file


def _check_out(args: argparse.Namespace) -> None:
    """Refuses an OUT whose suffix is not the format written, or that cannot be written."""
    suffix = Path(args.out).suffix.lower()
    if args.onnx and suffix != ".onnx":
        raise UserInputError(f"{args.out!r}: --onnx writes an ONNX model: give OUT ending in "
                             ".onnx.")
    if not args.onnx and suffix != ".safetensors":
        hint = (" To get an ONNX model, export the weights first, then run --onnx on them."
                if suffix == ".onnx" else "")
        raise UserInputError(f"{args.out!r}: a checkpoint exports as policy weights: give OUT "
                             f"ending in .safetensors.{hint}")
    check_output_file(args.out, "OUT")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", help="training checkpoint (.pt), or with --onnx a policy "
                        "weights file (.safetensors)")
    parser.add_argument("out", help="weights file to write (.safetensors), or with --onnx "
                        "the model (.onnx)")
    parser.add_argument("--onnx", action="store_true",
                        help="export the actor of a weights file as an ONNX model")
    parser.add_argument("--git-revision", default=None,
                        help="the revision the run was started from, if the checkpoint "
                        "records another")
    args = parser.parse_args()
    try:
        _check_out(args)
        if args.onnx:
            if args.git_revision is not None:
                raise UserInputError("--git-revision applies to checkpoint exports; an ONNX "
                                     "export keeps the weights file's provenance.")
            if args.source.endswith(".pt"):
                raise UserInputError(f"{args.source!r} is a checkpoint: export its weights "
                                     "first (python tools/export_policy.py CHECKPOINT "
                                     "policy.safetensors), then --onnx policy.safetensors.")
            from mjexplore.policies.onnx_export import export_onnx

            props = export_onnx(args.source, args.out)
            print(json.dumps({"out": args.out, "kind": props["kind"],
                              "weights_sha256": props["weights_sha256"],
                              "inputs": json.loads(props["observation_keys"]) + ["action_mask"],
                              "outputs": ["masked_logits", "action"]}))
            return 0
        from mjexplore.learning.checkpoints import export_checkpoint

        provenance = export_checkpoint(args.source, args.out, args.git_revision)
    except UserInputError as exc:
        print(f"export_policy: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = " or ".join(repr(str(f)) for f in (exc.filename, exc.filename2) if f) or "a file"
        print(f"export_policy: error: cannot use {where}: {exc.strerror or exc}: check that "
              "path (a file in the way, permissions, a read-only filesystem) or choose another.",
              file=sys.stderr)
        return 2
    print(json.dumps({"out": args.out, "num_timesteps": provenance["num_timesteps"],
                      "git_revision": provenance["git_revision"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
