"""Training curves of a run folder: episode return and length (TensorBoard scalars) and the
held-out evaluation (eval.csv), as one PNG and one JSON line of the last values.

Usage: python tools/plot_training.py runs/train/gvn docs/training_gvn.png
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from mjexplore.io.atomic import write_bytes_atomic  # noqa: E402


def scalars(run: Path) -> dict[str, list[tuple[int, float]]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, list[tuple[int, float]]] = {}
    for folder in sorted((run / "tb").glob("*")):
        acc = EventAccumulator(str(folder))
        acc.Reload()
        for tag in acc.Tags()["scalars"]:
            out.setdefault(tag, []).extend((e.step, e.value) for e in acc.Scalars(tag))
    return {k: sorted(v) for k, v in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("out", type=Path)
    args = parser.parse_args()
    s = scalars(args.run)
    evals = []
    if (args.run / "eval.csv").is_file():
        with open(args.run / "eval.csv") as f:
            evals = list(csv.DictReader(f))
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for ax, tag, label in ((axes[0], "rollout/ep_rew_mean", "episode return"),
                           (axes[1], "rollout/ep_len_mean", "decisions per episode")):
        if tag in s:
            steps, values = zip(*s[tag])
            ax.plot(steps, values)
        ax.set_xlabel("decision steps")
        ax.set_title(label)
    if evals:
        for scene in sorted({e["scene"] for e in evals}):
            rows = [e for e in evals if e["scene"] == scene]
            axes[2].plot([int(e["steps"]) for e in rows],
                         [float(e["exploration_time_s"]) for e in rows], "o-", label=scene)
        axes[2].legend()
    axes[2].set_xlabel("decision steps")
    axes[2].set_title("held-out exploration time (s, simulated)")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    write_bytes_atomic(args.out, buf.getvalue())
    last = {tag: round(v[-1][1], 3) for tag, v in s.items() if tag.startswith("rollout/")}
    last["steps"] = max((v[-1][0] for v in s.values()), default=0)
    last["evaluations"] = [{k: e[k] for k in ("steps", "scene", "exploration_time_s",
                                               "path_length_m", "end_reason")} for e in evals]
    print(json.dumps(last))


if __name__ == "__main__":
    main()
