"""The ladder of bounds: what each kind of knowledge of the unseen map is worth, measured by
explorers that differ only in what they know, on the same held-out generated layouts in a
training config's evaluation world (the grid world for the v3 recipe); prints one JSON line.

Each method (``--methods``, any classic explorer's name: ``mjexplore explore --explorer``)
drives the same episodes (layout, start, seed and settings of the config's evaluation, as
``heldout_episode`` lays them out). The default ladder:

* ``nearest``, ``pocket_nearest`` (the learned pocket classifier on nearest-frontier);
* ``pocket_truth``: the same rule with the true pockets (a perfect pocket classifier);
* ``distance_advantage`` alone and on the pocket prior (``pocket_advantage``);
* ``oracle_2m``, ``oracle_5m``, ``oracle_10m``: the oracle's planner given the truth within
  r of the mapped cells (perfect prediction up to r);
* ``oracle``: the whole truth.

Rows (one per episode: layout, method, simulated exploration time, end reason, revision) are
appended to ``OUT/rows.jsonl`` as they finish, and a rerun skips the episodes it has at the
current revision; ``OUT/summary.json`` holds each method's mean and its paired ratio to
``--baseline`` per layout (mean, bootstrap 95 % interval, faster/slower,
:func:`mjexplore.eval.stats.compare_paired`), over the layouts every method finished.

Layouts: ``validation`` (the config's model-selection layouts; ``validation:N`` the first N),
``unseen:N`` (N after them) or ``test:N`` (N with the test generator seeds, apart from every
choice).

Usage: python tools/ladder.py --out runs/ladder/validation [--config training/gvn_v3.yaml]
    [--layouts validation] [--methods nearest,pocket_nearest,...] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
from pathlib import Path

import numpy as np

LADDER = ("nearest", "pocket_nearest", "pocket_truth", "distance_advantage", "pocket_advantage",
          "oracle_2m", "oracle_5m", "oracle_10m", "oracle")


def _init() -> None:
    from mjexplore.episode.workers import init_episode_worker

    init_episode_worker()


def _episode(job: tuple[str, str, str, str]) -> dict:
    from mjexplore.explorers import make_explorer

    return episode_row(job, make_explorer)


def episode_row(job: tuple[str, str, str, str], make) -> dict:
    """The row of one episode: ``job`` is (config path, method, layout, revision), and
    ``make(method)`` builds the explorer."""
    from mjexplore.episode import Episode
    from mjexplore.learning.evaluation import heldout_env
    from mjexplore.learning.train_config import load_train_config

    config_path, method, scene, revision = job
    config = load_train_config(config_path)
    env = heldout_env(config, scene)
    env.reset(seed=config.eval.seed)
    ep = env.episode
    metrics = Episode(ep.scene, make(method), ep.sim.config.seed, ep.config).run().metrics
    return {"scene": scene, "method": method, "time": metrics["exploration_time_s"],
            "end_reason": metrics["end_reason"], "revision": revision}


def _layouts(config, which: str) -> tuple[str, ...]:
    kind, _, count = which.partition(":")
    if kind == "validation" and (not count or count.isdigit()):
        scenes = tuple(config.eval.scene_list())
        return scenes[:int(count)] if count else scenes
    if kind in ("unseen", "test") and count.isdigit():
        return (config.eval.unseen_scenes if kind == "unseen" else config.eval.test_scenes)(
            int(count))
    raise SystemExit(f"--layouts {which!r}: use validation, validation:N (the first N), "
                     "unseen:N or test:N")


def summarise(rows: list[dict], methods: list[str], baseline: str) -> dict:
    """Per method: layouts, episodes explored, mean time and the paired ratio to
    ``baseline`` over the layouts every method finished."""
    from mjexplore.eval.stats import compare_paired

    by = {(r["method"], r["scene"]): r for r in rows}
    scenes = sorted({r["scene"] for r in rows})
    common = [s for s in scenes if all((m, s) in by for m in methods)]
    out: dict = {"layouts": len(common), "baseline": baseline,
                 "revisions": sorted({r["revision"] for r in rows})}
    base = [by[(baseline, s)]["time"] for s in common]
    for m in methods:
        times = [by[(m, s)]["time"] for s in common]
        entry = {"time_s": round(float(np.mean(times)), 1) if times else None,
                 "explored": sum(by[(m, s)]["end_reason"] == "explored" for s in common)}
        if times:
            paired = compare_paired(times, base)
            entry.update(ratio=round(paired.mean, 3), low=round(paired.low, 3),
                         high=round(paired.high, 3), faster=paired.faster,
                         slower=paired.slower)
        out[m] = entry
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="training/gvn_v3.yaml")
    parser.add_argument("--layouts", default="validation")
    parser.add_argument("--methods", default=",".join(LADDER))
    parser.add_argument("--baseline", default="pocket_nearest")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    from mjexplore.errors import UserInputError
    from mjexplore.explorers import explorer_class
    from mjexplore.learning.train_config import load_train_config

    methods = [m for m in args.methods.split(",") if m]
    try:
        for m in methods:
            explorer_class(m)
    except UserInputError as exc:
        print(f"ladder: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    if args.baseline not in methods:
        print(f"ladder: --baseline {args.baseline!r} is not among --methods", file=sys.stderr)
        raise SystemExit(2)
    scenes = _layouts(load_train_config(args.config), args.layouts)
    print(json.dumps(run_ladder(Path(args.out), args.config, args.layouts, scenes, methods,
                                args.baseline, args.workers, _episode)))


def run_ladder(out: Path, config: str, layouts_drawn: str, scenes, methods: list[str],
               baseline: str, workers: int, episode) -> dict:
    """Runs ``episode((config, method, scene, revision))`` for each method and scene not in
    ``out/rows.jsonl`` at this revision (``workers`` processes), appending its row as it
    finishes, then writes and returns the summary (:func:`summarise`)."""
    from mjexplore.io.provenance import git_revision

    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.jsonl"
    revision = git_revision()
    rows = [json.loads(line) for line in rows_path.open()] if rows_path.exists() else []
    rows = [r for r in rows if r["revision"] == revision]
    done = {(r["method"], r["scene"]) for r in rows}
    jobs = [(config, m, s, revision) for s in scenes for m in methods if (m, s) not in done]
    with mp.get_context("spawn").Pool(workers, initializer=_init) as pool, \
            rows_path.open("a") as log:
        for row in pool.imap_unordered(episode, jobs):
            rows.append(row)
            log.write(json.dumps(row) + "\n")
            log.flush()
            print(f"{len(rows)}/{len(scenes) * len(methods)} {row['method']} "
                  f"{Path(row['scene']).name} {row['time']:.1f} s", file=sys.stderr, flush=True)
    summary = {"config": config, "layouts_drawn": layouts_drawn,
               **summarise(rows, methods, baseline)}
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1) + "\n")
    tmp.replace(out / "summary.json")
    return summary


if __name__ == "__main__":
    main()
