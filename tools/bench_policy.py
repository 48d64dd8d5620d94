"""CPU latency of one policy decision: torch against the ONNX export run with onnxruntime.

For the shipped GVN and CNN policies, records the observations and action masks of the
first decisions of an episode (kinematic dynamics, the policy choosing), exports the actor
to ONNX, and times the masked logits and greedy action of each recorded decision, one at a
time (batch 1), in torch (the SB3 policy's own actor: ``torch.set_num_threads(1)``) and in
onnxruntime (``intra_op_num_threads=1``), after one warm-up round. Checks that both pick
the same actions. Prints one JSON line: median and p99 latency per decision (ms) of each,
and the median speed-up of onnxruntime over torch (above 1: onnxruntime is faster).

Usage: python tools/bench_policy.py [--scene maze] [--decisions 20] [--rounds 20]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

KINDS = ("gvn", "cnn")


def _latencies_ms(decide, count: int, rounds: int) -> np.ndarray:
    for i in range(count):  # Warm-up: allocations, onnxruntime's first-run planning.
        decide(i)
    times = []
    for _ in range(rounds):
        for i in range(count):
            t = time.perf_counter()
            decide(i)
            times.append(time.perf_counter() - t)
    return 1e3 * np.array(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="maze", help="scene the decisions are recorded in")
    parser.add_argument("--decisions", type=int, default=20, help="decisions recorded")
    parser.add_argument("--rounds", type=int, default=20, help="timed passes over them")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    from mjexplore.policies.models import DEFAULT_MODEL
    from mjexplore.policies.models import MODELS_DIR as MODELS
    from mjexplore.policies.onnx_export import (
        OnnxActor,
        export_onnx,
        record_decisions,
        torch_actor_logits,
    )
    from mjexplore.policies.weights import load_policy

    out: dict = {"scene": args.scene, "threads": 1}
    with tempfile.TemporaryDirectory() as scratch:
        for kind in KINDS:
            weights = MODELS / DEFAULT_MODEL[kind] / "policy.safetensors"
            obs, masks = record_decisions(weights, args.decisions, args.scene)
            count = len(masks)
            single = [({k: v[i:i + 1] for k, v in obs.items()}, masks[i:i + 1])
                      for i in range(count)]
            policy, _ = load_policy(weights)
            export_onnx(weights, Path(scratch) / f"{kind}.onnx")
            actor = OnnxActor(Path(scratch) / f"{kind}.onnx", threads=1)

            def torch_decide(i: int, policy=policy, single=single) -> int:
                return int(torch_actor_logits(policy, *single[i]).argmax())

            def onnx_decide(i: int, actor=actor, single=single) -> int:
                return int(actor(*single[i])[1][0])

            same = all(torch_decide(i) == onnx_decide(i) for i in range(count))
            t = _latencies_ms(torch_decide, count, args.rounds)
            o = _latencies_ms(onnx_decide, count, args.rounds)
            out.update({
                f"{kind}_decisions": count,
                f"{kind}_same_actions": same,
                f"{kind}_torch_median_ms": round(float(np.median(t)), 3),
                f"{kind}_torch_p99_ms": round(float(np.percentile(t, 99)), 3),
                f"{kind}_onnxruntime_median_ms": round(float(np.median(o)), 3),
                f"{kind}_onnxruntime_p99_ms": round(float(np.percentile(o, 99)), 3),
                f"{kind}_speedup_median": round(float(np.median(t) / np.median(o)), 2),
            })
    print(json.dumps(out))


if __name__ == "__main__":
    main()
