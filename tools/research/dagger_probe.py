"""Does the imitation warm start alone (before any PPO) beat the GVN's prior? Same layouts.

Runs a training config's warm start (:func:`mjexplore.learning.imitation.warm_start`: plain
cloning of the oracle, then its DAgger rounds) on a fresh policy in this process, one torch
thread, saves the weights, then runs whole episodes of the config's training env on the first
``--layouts`` of its **validation** layouts (``eval.scene_list()``: model selection's, generator
seeds ``2**31 + i``; never the test layouts after them, ``eval.unseen_scenes``) with each mode of
``mjexplore probe-policy``:

* ``policy``: the warm-started policy, its most probable valid action;
* ``prior``: the prior alone (v3: nearest node by path, ``policy.prior_pocket_m`` metres more
  per unit of pocket probability: the rule ``pocket_nearest`` ships as an explorer);
* ``greedy``: the nearest node by path;
* ``untrained``: the same network before the warm start (its residual near zero);
* ``expert``: the imitated expert itself, the oracle's ``expert_choice`` among the same valid
  nodes at every decision (the teacher imitation copies, in this action space);
* ``expert_via``: a variant teacher: the valid node minimising the ground-truth path from the
  robot to the node plus from the node to the first viewpoint of the oracle's tour
  (``expert_choice`` takes the node nearest that viewpoint, however far from the robot);
* ``expert_tour``: the oracle's one-step lookahead (``expert_lookahead``): the valid node
  minimising the path to it plus an open tour from it over the plan's viewpoints it leaves
  needed;
* a classic explorer's name (``oracle``, ...): that explorer on the same episode.

Prints one JSON line: the warm start's report (rounds, wall and CPU seconds), per mode the mean
exploration time (simulated s) and how many episodes explored, and per pair ``policy`` against
each other mode the paired per-layout ratio of exploration times (mean, bootstrap 95 %
interval over layouts, layouts faster / slower).

Usage: python -m tools.research.dagger_probe --config training/gvn_dagger.yaml
    --out runs/dagger_probe [--layouts 16] [--modes policy,prior,greedy,untrained,expert]
    [--workers 2] [--weights runs/dagger_probe/policy_warm.safetensors  (skip the warm start)]
"""

from __future__ import annotations

import argparse
import functools
import json
import multiprocessing as mp
import time
from pathlib import Path

from mjexplore.eval.probe import episode_row, probe_config, probe_episode


def _warm_start(config_path: str, out: Path) -> tuple[Path, Path, dict]:
    """Fresh and warm-started weights of the config's policy (seeded as training seeds it),
    and the warm start's report."""
    import torch

    from mjexplore.config import to_dict
    from mjexplore.learning.imitation import warm_start
    from mjexplore.learning.policy_network import fresh_policy, network_kwargs
    from mjexplore.learning.train_config import load_train_config
    from mjexplore.learning.training import seed_everything
    from mjexplore.policies.registry import layout_of
    from mjexplore.policies.weights import save_policy_weights

    config = load_train_config(config_path)
    torch.set_num_threads(1)
    seed_everything(config.seed)
    policy = fresh_policy(config)
    out.mkdir(parents=True, exist_ok=True)
    provenance = {"config": to_dict(config), "recipe": config_path}
    args = (config.kind, network_kwargs(config), layout_of(config.kind, config.env))
    fresh = out / "policy_untrained.safetensors"
    save_policy_weights(fresh, policy, *args, {**provenance, "num_timesteps": 0})
    wall, cpu = time.perf_counter(), time.process_time()
    report = warm_start(policy, config.env, config.imitation, config.seed)
    report["probe_wall_s"] = round(time.perf_counter() - wall, 1)
    report["probe_cpu_s"] = round(time.process_time() - cpu, 1)
    warm = out / "policy_warm.safetensors"
    save_policy_weights(warm, policy, *args,
                        {**provenance, "num_timesteps": 0, "imitation": report})
    (out / "warm_start.json").write_text(json.dumps(report, indent=2) + "\n")
    return fresh, warm, report


def _safe(oracle, rule, gain_m, state, candidates, mask, obs) -> int:
    """``expert_safeM``'s choice: the prior's node unless the lookahead's best is ``gain_m``
    metres shorter (path plus tour)."""
    baseline = int(rule.predict(obs, action_masks=mask)[0])
    return oracle.expert_lookahead(state, candidates, mask, baseline=baseline, gain_m=gain_m)


def _via(oracle, state, candidates, mask) -> int:
    """``expert_via``'s choice (see the module docstring)."""
    import numpy as np

    plan = oracle.replan(state)
    if plan:
        target = oracle.views.points[plan[0]]
        d = oracle.graph.distance_matrix(np.vstack([state.pose[:2], target, candidates]))
        cost = np.where(mask, d[0, 2:] + d[1, 2:], np.inf)
        if np.isfinite(cost).any():
            return int(np.argmin(cost))
    return oracle.expert_choice(state, candidates, mask)


def _job(job: tuple[str, str, str, int, str]) -> dict:
    """One episode: the ``expert*`` modes here, every other mode by
    :func:`~mjexplore.eval.probe.probe_episode`."""
    config_path, weights, mode, seed, scene = job
    if not mode.startswith("expert"):
        return probe_episode(job)
    import numpy as np
    import torch

    from mjexplore.explorers import make_explorer
    from mjexplore.explorers.oracle import lookahead_expert
    from mjexplore.learning.evaluation import NearestNodeRule, heldout_env

    torch.set_num_threads(1)
    config = probe_config(config_path, weights)
    env = heldout_env(config, scene)
    oracle = lookahead_expert() if mode == "expert_tour" else make_explorer("oracle")
    oracle.reset(np.random.default_rng(seed))
    if mode.startswith("expert_safe"):  # expert_safeM: the prior unless M metres shorter.
        choose = functools.partial(_safe, oracle, NearestNodeRule(config.policy.prior_pocket_m),
                                   float(mode.removeprefix("expert_safe")))
    else:
        answer = {"expert": oracle.expert_choice, "expert_tour": oracle.expert_lookahead,
                  "expert_via": functools.partial(_via, oracle)}[mode]

        def choose(state, candidates, mask, obs):
            del obs
            return answer(state, candidates, mask)
    obs, info = env.reset(seed=seed)
    done = info["end_reason"] is not None
    while not done:
        action = choose(env.episode.decision_state(), env.decisions.action_positions(),
                        env.action_masks(), obs=obs)
        if action < 0:
            break
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    return episode_row(mode, seed, scene, None, env.episode.result().metrics)


def _paired(mine: list[float], theirs: list[float], rng) -> dict:
    """Mean per-layout ratio mine / theirs, its bootstrap 95 % interval, wins and losses."""
    import numpy as np

    ratio = np.asarray(mine) / np.asarray(theirs)
    boot = rng.choice(ratio, (10_000, len(ratio))).mean(1)
    return {"ratio": round(float(ratio.mean()), 3),
            "ci95": [round(float(q), 3) for q in np.quantile(boot, [0.025, 0.975])],
            "faster": int((ratio < 1).sum()), "slower": int((ratio > 1).sum())}


def main() -> None:
    import numpy as np

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="training YAML with an imitation block")
    parser.add_argument("--out", required=True, help="folder for the weights and the report")
    parser.add_argument("--weights", help="warm-started weights to probe (skips the warm start)")
    parser.add_argument("--layouts", type=int, default=16,
                        help="the first this many validation layouts")
    parser.add_argument("--modes", default="policy,prior,greedy,untrained,expert")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    modes = [m for m in args.modes.split(",") if m]
    out = Path(args.out)
    if args.weights:
        warm, fresh, report = args.weights, out / "policy_untrained.safetensors", None
    else:
        fresh, warm, report = _warm_start(args.config, out)
        print(json.dumps({"warm_start": report}), flush=True)
    evaluation = probe_config(args.config, str(warm)).eval
    scenes = evaluation.scene_list()[:args.layouts]
    labels, jobs = [], []
    for scene in scenes:
        for mode in modes:
            weights, run = (fresh, "policy") if mode == "untrained" else (warm, mode)
            labels.append(mode)
            jobs.append((args.config, str(weights), run, evaluation.seed, scene))
    wall = time.perf_counter()
    with mp.get_context("spawn").Pool(args.workers) as pool:
        rows = pool.map(_job, jobs, chunksize=1)
    times = {m: [] for m in modes}
    explored = dict.fromkeys(modes, 0)
    for mode, row in zip(labels, rows, strict=True):
        times[mode].append(row["exploration_time_s"])
        explored[mode] += row["explored"]
    rng = np.random.default_rng(0)
    figures = {"config": args.config, "weights": str(warm),
               "layouts": f"validation (eval.scene_list()) 0..{len(scenes) - 1}",
               "eval_wall_s": round(time.perf_counter() - wall, 1),
               "mean_exploration_time_s": {m: round(float(np.mean(t)), 1)
                                           for m, t in times.items()},
               "explored": explored,
               "per_layout_s": {m: [round(x, 1) for x in t] for m, t in times.items()}}
    if "policy" in modes:
        figures["policy_vs"] = {m: _paired(times["policy"], times[m], rng)
                                for m in modes if m != "policy"}
    if report is not None:
        figures["warm_start"] = {k: v for k, v in report.items() if k != "rounds"}
    out.mkdir(parents=True, exist_ok=True)
    (out / "probe.json").write_text(json.dumps(figures, indent=2) + "\n")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
