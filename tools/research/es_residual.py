"""Does trial and error find a better rule than the prior? Evolution strategies on a linear
residual of pocket_nearest's prior, judged by exploration time on paired layouts.

The policy at a decision takes the valid TER node of greatest ``prior + phi(node) . w``:
``prior`` is gvn_v3's path prior (minus the path cost, 50 m per unit of pocket probability,
1 nat a metre) and ``phi`` the per-node terms of ``dagger_fit``'s linear model
(:func:`v3_prior.node_terms`), scaled by ``SCALES`` so that a unit of ``theta`` moves a
logit by metres that matter (``w = SCALES * theta``). ``theta = 0`` is the prior.

Each iteration draws ``--layouts`` training layouts (the training stream of the recipe's
env: generator seeds below 2**31, never a validation or test layout; with ``--fixed`` the
same ones at every iteration, a deterministic objective) and ``--pairs`` antithetic
perturbations ``+-sigma eps``; every candidate runs every layout (grid world,
deterministic), and the gradient of the mean log exploration time is estimated from the
paired differences (the same layouts for both signs: the layout's own difficulty cancels).
Adam steps ``theta``. The centre and the prior also run the iteration's layouts, so the
log holds the centre's paired ratio to the prior (without ``--fixed``: on layouts it had
not seen before the step).

At the end (and with ``--validate`` every k iterations) the centre runs the recipe's 32
validation layouts beside the prior; ``--test N`` runs N test layouts (seeds from
TEST_SEED_BASE) once, at the end; the prior's episodes there run once and are kept. One
JSON line per iteration goes to ``OUT/log.jsonl``; the state (theta, Adam moments,
iteration, the prior's kept times) to ``OUT/state.json`` after each, so ``--resume`` goes
on.

Usage: python -m tools.research.es_residual --config training/gvn_anchor.yaml --out runs/es/a
    [--iterations 30] [--pairs 6] [--layouts 6] [--fixed] [--sigma 0.5] [--lr 0.1]
    [--validate K] [--test N] [--workers 2] [--resume]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
from pathlib import Path

import numpy as np

from tools.research.v3_prior import load_v3_recipe, node_terms, paired, penalised_time

# Metres of logit per unit of theta, per term of v3_prior.node_terms: gain share,
# heading difference (rad), TER distance (m), frontier flag, pocket probability, cost beyond
# the cheapest (per 10 m), straight-line distance (per 10 m), beyond < 5 m, beyond < 15 m,
# gain when beyond < 15 m.
SCALES = np.array([20.0, 3.0, 1.0, 5.0, 20.0, 3.0, 3.0, 3.0, 3.0, 20.0], np.float32)


class LinearResidualRule:
    """The greedy node of ``prior + node_terms . (SCALES * theta)``, with SB3's ``predict``."""

    def __init__(self, theta: np.ndarray) -> None:
        self.w = (SCALES * np.asarray(theta, np.float32)).astype(np.float32)

    def predict(self, obs, deterministic=True, action_masks=None):
        import torch

        mask = np.asarray(action_masks, bool)
        features = np.asarray(obs["node_features"], np.float32).reshape(1, len(mask), -1)
        terms, prior = node_terms(features, mask[None])
        logits = (prior + terms @ torch.as_tensor(self.w))[0].numpy()
        return int(np.argmax(np.where(mask, logits, -np.inf))), None


_WORKER: dict = {}


def _init(config) -> None:
    from mjexplore.episode.workers import init_episode_worker

    init_episode_worker()
    _WORKER["config"] = config


def _episode(job) -> float:
    """Exploration time of one (theta, scene) job, seconds (:func:`penalised_time`)."""
    from mjexplore.learning.evaluation import heldout_episode

    theta, scene = job
    config = _WORKER["config"]
    return penalised_time(heldout_episode(LinearResidualRule(theta), config, scene), config)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="training recipe (YAML)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--iterations", type=int, default=30, help="default: 30")
    parser.add_argument("--pairs", type=int, default=6, help="default: 6")
    parser.add_argument("--layouts", type=int, default=6, help="default: 6")
    parser.add_argument("--sigma", type=float, default=0.5, help="default: 0.5")
    parser.add_argument("--lr", type=float, default=0.1, help="Adam step (default: 0.1)")
    parser.add_argument("--workers", type=int, default=2, help="default: 2")
    parser.add_argument("--validate", type=int, default=0,
                        help="validate every k iterations (default: 0, at the end only)")
    parser.add_argument("--test", type=int, default=0, help="test layouts (default: 0)")
    parser.add_argument("--seed", type=int, default=0, help="default: 0")
    parser.add_argument("--fixed", action="store_true",
                        help="the same --layouts training layouts at every iteration (common "
                             "random numbers: a deterministic objective; default: fresh ones)")
    parser.add_argument("--resume", action="store_true", help="default: off")
    args = parser.parse_args()

    from mjexplore.envs.exploration import procedural_scene

    config = load_v3_recipe(parser, args.config)
    args.out.mkdir(parents=True, exist_ok=True)
    state_path = args.out / "state.json"
    dim = len(SCALES)
    if args.resume and state_path.is_file():
        state = json.loads(state_path.read_text())
    else:
        state = {"theta": [0.0] * dim, "m": [0.0] * dim, "v": [0.0] * dim, "iteration": 0,
                 "args": {k: str(v) for k, v in vars(args).items()}}
    theta = np.array(state["theta"])
    m, v = np.array(state["m"]), np.array(state["v"])
    ctx = mp.get_context("spawn")
    with ctx.Pool(args.workers, initializer=_init, initargs=(config,)) as pool:
        def run(thetas, scenes):
            jobs = [(t, s) for t in thetas for s in scenes]
            out = pool.map(_episode, jobs, chunksize=1)
            return np.array(out).reshape(len(thetas), len(scenes))

        def save():
            tmp = state_path.with_suffix(".tmp")
            tmp.write_text(json.dumps(state))
            os.replace(tmp, state_path)

        def validate(tag, scenes):
            # The prior's episodes are the same at every validation: run once, kept.
            kept = state.setdefault("prior_eval_times", {})
            key = f"{'test' if tag == 'test' else 'validation'}_{len(scenes)}"
            if key in kept:
                times = np.vstack([run([theta], scenes), kept[key]])
            else:
                times = run([theta, np.zeros(dim)], scenes)
                kept[key] = times[1].tolist()
                save()
            row = {"validate": tag, "iteration": state["iteration"], "theta": theta.tolist(),
                   "layouts": len(scenes), **paired(times[0], times[1]),
                   "times": times.tolist()}
            with open(args.out / "log.jsonl", "a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps({k: v for k, v in row.items() if k != "times"}), flush=True)

        while state["iteration"] < args.iterations:
            it = state["iteration"]
            rng = np.random.default_rng([args.seed, it, 1])
            draw = np.random.default_rng([args.seed, 0 if args.fixed else it])
            scenes = [str(procedural_scene(config.env.procedural, draw))
                      for _ in range(args.layouts)]
            eps = rng.standard_normal((args.pairs, dim))
            thetas = [theta + args.sigma * e for e in eps] + [theta - args.sigma * e for e in eps]
            cached = args.fixed and "prior_times" in state
            thetas += [theta] if cached else [theta, np.zeros(dim)]
            times = run(thetas, scenes)
            if cached:  # The prior on the same layouts: the same episodes as before.
                times = np.vstack([times, state["prior_times"]])
            elif args.fixed:
                state["prior_times"] = times[-1].tolist()
            logt = np.log(times)
            plus, minus = logt[:args.pairs], logt[args.pairs:2 * args.pairs]
            d = (minus - plus).mean(1) / 2  # > 0: the + side explores faster.
            grad = (d[:, None] * eps).sum(0) / (args.pairs * args.sigma)
            m = 0.9 * m + 0.1 * grad
            v = 0.999 * v + 0.001 * grad ** 2
            t = it + 1
            step = args.lr * (m / (1 - 0.9 ** t)) / (np.sqrt(v / (1 - 0.999 ** t)) + 1e-8)
            row = {"iteration": it, "theta_before": theta.tolist(),
                   "centre_vs_prior": paired(times[-2], times[-1]),
                   "pair_spread": float(np.abs(d).mean()), "grad": grad.tolist(),
                   "times": times.tolist(), "scenes": scenes}
            theta = theta + step
            state.update(theta=theta.tolist(), m=m.tolist(), v=v.tolist(), iteration=t)
            save()
            with open(args.out / "log.jsonl", "a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps({"iteration": it, "centre_vs_prior": row["centre_vs_prior"],
                              "pair_spread": row["pair_spread"],
                              "theta": np.round(theta, 3).tolist()}), flush=True)
            if args.validate and t % args.validate == 0:
                validate(t, config.eval.scene_list())
        validate("final", config.eval.scene_list())
        if args.test:
            validate("test", config.eval.test_scenes(args.test))


if __name__ == "__main__":
    main()
