"""Decision throughput of the learning loop, in full physics and in the training mode, and
the cost of PPO's update.

Runs the shipped GVN policy as the explorer for whole episodes (two worker processes, one
per core) on the evaluation scenes, once with full MuJoCo contact dynamics and once in the
kinematic training mode (training/gvn.yaml's episode settings), and times the parts of each
decision: physics (simulator stepping without the lidar), lidar, mapping, topology
(incremental GVD updates between decisions plus the TER build at the decision), navigation
(planning and control) and the network (policy inference; also the training-time forward
of one observation, which re-encodes the raw episodic memory: the episode's last ten TERs).

Then one round of training/gvn.yaml as ``mjexplore train`` runs it, starting from the
shipped weights: one rollout (n_steps decisions on each of n_envs worker envs) and PPO's
update on it (n_epochs over shuffled minibatches: forward, backward and optimizer steps),
each timed per collected decision; in the grid world (``train_decisions_per_s``) and, in
the same run, in the kinematic world training/gvn.yaml names
(``train_decisions_per_s_kinematic``; ``grid_over_kinematic`` their ratio, issue 16's
target 6, with train_decisions_per_s >= 100), and the grid world's with four envs on the
two cores (``train_decisions_per_s_4envs``, ``four_envs_over_two``: the same rollout size,
two envs per core). Then the same round of the recipe trained
now, training/gvn_v2.yaml as it stands (v2 network with global attention, a critic with
its own encoder, minibatches of consecutive decisions): ``v2_*``. Prints one JSON line.

Target (issue 5): topology + policy at most 8 ms per decision; ARiADNE's own environment
spends about 390 ms per decision on this machine. Target (issue 16): the update at most
10 ms per decision.

The shipped recipe (the one ``--explorer gvn``'s default model was trained with,
training/gvn_v3.yaml): one round as ``mjexplore train`` runs it, end to end (rollout and
update), with 2 envs (``recipe_decisions_per_s``) and with 1, 2 and 4
(``recipe_decisions_per_s_by_envs``), the env's CPU time per decision
(``env_ms_per_decision``: the rollout's wall time over its decisions, times the envs, at
one env per core) and the update's wall time per decision (``update_ms_per_decision``;
``update_cpu_ms_per_decision`` its CPU time, all threads, which other work on the machine
disturbs far less), with the 1-minute load average at the end (``load_average``).
The baseline in the same run is the same round with the workers' thread pools left at
their defaults (``recipe_decisions_per_s_default_threads``: what training ran before its
workers were held to one thread each). ``--recipe-only`` measures just that, and
``--n-envs N`` the recipe with N envs (a bigger machine), beside its baseline.

``--overlap`` measures instead ``ppo.overlap`` (each update overlapped with the next
rollout's collection, :mod:`mjexplore.learning.overlap_ppo`) against the same recipe
without it, in the same run: ``--rollouts`` rollouts and updates as ``mjexplore train``
runs them (fresh weights, one fresh process each, the two alternated ``--repeats`` times),
of the shipped recipe or ``--recipe``. The figure is the steady state: decisions per second
from the first update's start to the last one's (one collection and one update per rollout
in that window, overlapped or not; the first collection and the last update, which nothing
overlaps, lie outside it): ``sequential_decisions_per_s``, ``overlap_decisions_per_s`` and
their ratio ``overlap_speedup``, beside each mode's mean collection and update wall seconds,
the update thread's CPU seconds, and the 1-minute load average before and after (a machine
others use gives the envs' and the update's threads less than a core each).

Usage: python tools/bench_train.py [--scenes loop_with_corridor,maze] [--max-time 300]
       python tools/bench_train.py --recipe-only [--n-envs 15] [--device auto]
       python tools/bench_train.py --overlap [--recipe training/gvn_long.yaml]
           [--rollouts 3] [--repeats 1] [--n-steps 64] [--n-envs 2]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import json
import multiprocessing as mp
import time
from collections import defaultdict

from mjexplore.io.provenance import REPO
from mjexplore.policies.models import MODELS_DIR

ARIADNE_MS_PER_DECISION = 390.0
TRAINING = REPO / "training"


def _timed(counters, key, fn):
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            counters[key] += time.perf_counter() - t
    return wrapper


def run(job: tuple[str, str, float]) -> dict:
    scene, mode, max_time = job
    import torch

    torch.set_num_threads(1)
    from mjexplore.config import load_yaml_config
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.learning.train_config import TrainConfig
    from mjexplore.policies.gvn_explorer import GvnExplorer
    from mjexplore.scenes.canonical import resolve_scene

    train_config = load_yaml_config(TrainConfig, TRAINING / "gvn.yaml")
    if mode == "training":
        config = train_config.env.episode
    else:
        config = EpisodeConfig()
    config = dataclasses.replace(config, max_time=max_time)
    explorer = GvnExplorer("gvn_paper")
    episode = Episode(resolve_scene(scene), explorer, 0, config)
    c: dict[str, float] = defaultdict(float)
    sim, lidar = episode.sim, episode.sim.lidar
    lidar.scan = _timed(c, "lidar", lidar.scan)
    sim.step = _timed(c, "sim_step", sim.step)
    episode.mapper.integrate = _timed(c, "mapping", episode.mapper.integrate)
    episode.tracker.observe = _timed(c, "gvd", episode.tracker.observe)
    episode.tracker.ter = _timed(c, "ter", episode.tracker.ter)
    episode.navigator.update = _timed(c, "navigation", episode.navigator.update)
    explorer.logits = _timed(c, "policy", explorer.logits)
    t0 = time.perf_counter()
    result = episode.run()
    wall = time.perf_counter() - t0
    decisions = max(result.metrics["decisions"], 1)
    # The training-time forward (raw memory re-encoded) of the last decision's observation.
    obs = {k: torch.as_tensor(v)[None] for k, v in explorer.decisions.observation().items()}
    with torch.no_grad():
        t = time.perf_counter()
        for _ in range(10):
            explorer.policy.evaluate_actions(obs, torch.zeros(1, dtype=torch.long))
        c["training_forward"] = (time.perf_counter() - t) / 10 * decisions
    physics = c["sim_step"] - c["lidar"]
    return {"scene": scene, "mode": mode, "wall_s": wall, "decisions": decisions,
            "sim_time_s": result.metrics["exploration_time_s"],
            "physics": physics, "lidar": c["lidar"], "mapping": c["mapping"],
            "topology": c["gvd"] + c["ter"], "ter": c["ter"], "navigation": c["navigation"],
            "policy": c["policy"], "training_forward": c["training_forward"]}


def ppo_round(dynamics: str, n_envs: int | None = None) -> dict[str, float]:
    """One rollout and one PPO update of training/gvn.yaml from the shipped weights, its
    episodes in the world ``dynamics`` names (the grid world with training/gvn_v2.yaml's
    scan schedule, ``scan_travel``): wall seconds of each and the decisions collected.
    ``n_envs`` replaces the config's envs, each collecting a share of the same rollout."""
    from mjexplore.learning.train_config import load_train_config
    from mjexplore.learning.training import ppo_round as timed_round
    from mjexplore.policies.weights import load_policy

    config = load_train_config(TRAINING / "gvn.yaml")
    travel = load_train_config(TRAINING / "gvn_v2.yaml").env.episode.sim.scan_travel
    episode = config.env.episode
    sim = dataclasses.replace(episode.sim, dynamics=dynamics,
                              scan_travel=travel if dynamics == "grid" else None)
    config = dataclasses.replace(config, env=dataclasses.replace(config.env, episode=(
        dataclasses.replace(episode, sim=sim))))
    if n_envs is not None:
        rollout = config.ppo.n_steps * config.n_envs
        config = dataclasses.replace(config, n_envs=n_envs, ppo=dataclasses.replace(
            config.ppo, n_steps=rollout // n_envs))

    def load_shipped(model) -> None:
        shipped, _ = load_policy(MODELS_DIR / "gvn_paper" / "policy.safetensors", "gvn")
        model.policy.load_state_dict(shipped.state_dict())

    return timed_round(config, model_setup=load_shipped)


def _rate(round_: dict[str, float]) -> float:
    """Decisions per second of wall time of a PPO round (rollout and update)."""
    return round_["decisions"] / (round_["rollout_s"] + round_["update_s"])


def v2_round() -> dict[str, float]:
    """One rollout and PPO update of training/gvn_v2.yaml as it stands (fresh weights)."""
    from mjexplore.learning.train_config import load_train_config
    from mjexplore.learning.training import ppo_round as timed_round

    return timed_round(load_train_config(TRAINING / "gvn_v2.yaml"))


def recipe_round(n_envs: int, default_threads: bool = False, device: str = "auto",
                 n_steps: int | None = None) -> dict[str, float]:
    """One round of the shipped recipe with ``n_envs`` envs (``n_steps`` decisions each,
    default the recipe's); with ``default_threads`` the workers keep their libraries'
    default thread pools."""
    from unittest import mock

    from mjexplore.episode import workers
    from mjexplore.learning import training, vec_envs
    from mjexplore.learning.train_config import load_train_config
    from mjexplore.policies.models import DEFAULT_MODEL

    config = load_train_config(TRAINING / f"{DEFAULT_MODEL['gvn']}.yaml")
    config = dataclasses.replace(config, n_envs=n_envs, ppo=dataclasses.replace(
        config.ppo, n_steps=n_steps or config.ppo.n_steps))
    with contextlib.ExitStack() as stack:
        stack.enter_context(workers.thread_environment(None))
        if default_threads:
            # Envs built as before there were workers of their own (no thread limits).
            stack.enter_context(mock.patch.object(
                vec_envs, "env_maker",
                lambda env, own_process, report=None: functools.partial(
                    vec_envs.ExplorationEnv, env)))
            stack.enter_context(mock.patch.object(vec_envs, "single_thread_children",
                                                  contextlib.nullcontext))
        return training.ppo_round(config, device=device)


def _fresh(*args, round_=recipe_round) -> dict[str, float]:
    """``round_`` (default :func:`recipe_round`) in a fresh process: each round starts its
    own workers (and forkserver), so that one round's thread settings cannot reach
    another's."""
    from concurrent.futures import ProcessPoolExecutor

    # Not a multiprocessing.Pool: its daemonic workers may not start the envs' workers.
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
        return pool.submit(round_, *args).result()


def overlap_round(recipe: str, overlap: bool, rollouts: int, device: str,
                  n_steps: int | None = None, n_envs: int | None = None) -> dict[str, float]:
    """``rollouts`` rollouts and updates of ``recipe`` (a path under the repository) as
    ``mjexplore train`` runs them (its torch threads per phase), with ``ppo.overlap`` set to
    ``overlap``, ``n_envs`` envs and ``n_steps`` decisions per env (default the recipe's):
    the decisions of a rollout, the wall seconds from the first update's start to the last
    one's and of the whole run, the mean wall seconds of a collection and of an update, and
    the update's CPU seconds on its own thread (with one torch thread, all of them: what its
    wall time exceeds it by, it waited for a core or for the GIL)."""
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    from mjexplore.episode import workers
    from mjexplore.learning import training
    from mjexplore.learning.train_config import load_train_config
    from mjexplore.learning.vec_envs import make_vec_env

    config = load_train_config(REPO / recipe)
    config = dataclasses.replace(config, n_envs=n_envs or config.n_envs, ppo=dataclasses.replace(
        config.ppo, overlap=overlap, n_steps=n_steps or config.ppo.n_steps))
    collections: list[tuple[float, float]] = []
    updates: list[tuple[float, float, float]] = []

    class Phases(BaseCallback):
        def _on_rollout_start(self) -> None:
            training.set_phase_threads(config, updating=False)
            self.start = time.perf_counter()

        def _on_rollout_end(self) -> None:
            training.set_phase_threads(config, updating=True)
            collections.append((self.start, time.perf_counter()))

        def _on_step(self) -> bool:
            return True

    with workers.thread_environment(None):
        venv = make_vec_env(config, config.seed)
    try:
        model = training.make_model(config, venv, config.seed, device=device)
        train = model.train

        def timed_train() -> None:  # In the update thread with overlap.
            start, cpu = time.perf_counter(), time.thread_time()
            train()
            updates.append((start, time.perf_counter(), time.thread_time() - cpu))

        model.train = timed_train
        torch.set_num_threads(config.torch_threads)
        decisions = config.ppo.n_steps * config.n_envs
        start = time.perf_counter()
        model.learn(rollouts * decisions, callback=Phases())
        wall = time.perf_counter() - start
    finally:
        training.set_phase_threads(config, updating=False)
        venv.close()
    return {"decisions": decisions, "n_envs": config.n_envs,
            "steady_s": updates[-1][0] - updates[0][0], "wall_s": wall,
            "collect_s": sum(b - a for a, b in collections) / rollouts,
            "update_s": sum(b - a for a, b, _ in updates) / rollouts,
            "update_thread_cpu_s": sum(c for _, _, c in updates) / rollouts}


def overlap_figures(recipe: str, rollouts: int, repeats: int, device: str,
                    n_steps: int | None = None, n_envs: int | None = None) -> dict[str, object]:
    """``ppo.overlap``'s figures against the same recipe without it (see the module
    docstring). A first short round fills numba's compile caches."""
    import os

    if rollouts < 2:
        raise SystemExit("--rollouts must be >= 2: the steady state lies between the first "
                         "update's start and the last one's")
    load_before = os.getloadavg()[0]
    _fresh(recipe, False, 1, device, 32, n_envs, round_=overlap_round)
    runs: dict[bool, list[dict[str, float]]] = {False: [], True: []}
    for _ in range(repeats):
        for overlap in (False, True):
            runs[overlap].append(_fresh(recipe, overlap, rollouts, device, n_steps, n_envs,
                                        round_=overlap_round))
    out: dict[str, object] = {"recipe": recipe, "rollouts": rollouts, "repeats": repeats,
                              "n_envs": runs[False][0]["n_envs"],
                              "decisions_per_rollout": runs[False][0]["decisions"]}
    rates = {}
    for overlap, name in ((False, "sequential"), (True, "overlap")):
        rs = runs[overlap]
        rates[overlap] = sum((rollouts - 1) * r["decisions"] for r in rs) / sum(
            r["steady_s"] for r in rs)
        out[f"{name}_decisions_per_s"] = round(rates[overlap], 2)
        out[f"{name}_decisions_per_s_each"] = [
            round((rollouts - 1) * r["decisions"] / r["steady_s"], 2) for r in rs]
        out[f"{name}_end_to_end_decisions_per_s"] = round(
            sum(rollouts * r["decisions"] for r in rs) / sum(r["wall_s"] for r in rs), 2)
        for phase in ("collect_s", "update_s", "update_thread_cpu_s"):
            out[f"{name}_{phase}"] = round(sum(r[phase] for r in rs) / len(rs), 2)
    out.update(overlap_speedup=round(rates[True] / rates[False], 2), cores=os.cpu_count(),
               load_average_before=round(load_before, 2),
               load_average_after=round(os.getloadavg()[0], 2))
    return out


def recipe_figures(n_envs: list[int], device: str,
                   n_steps: int | None = None) -> dict[str, object]:
    """The shipped recipe's figures (see the module docstring). A first short round fills
    numba's compile caches, so that no measured round pays for compiling."""
    import os

    cores = os.cpu_count() or 1
    _fresh(1, False, device, 64)
    base = _fresh(n_envs[0], True, device, n_steps)
    by_envs, main = {}, None
    for n in n_envs:
        r = _fresh(n, False, device, n_steps)
        by_envs[str(n)] = round(_rate(r), 2)
        if main is None:
            main = (n, r)
    n, r = main
    env_ms = r["rollout_s"] / r["decisions"] * 1e3 * min(n, cores)
    return {"recipe": "training/gvn_v3.yaml", "recipe_envs": n,
            "recipe_decisions_per_s": by_envs[str(n)],
            "recipe_decisions_per_s_default_threads": round(_rate(base), 2),
            "threads_speedup": round(_rate(r) / _rate(base), 2),
            "env_ms_per_decision": round(env_ms, 2),
            "update_ms_per_decision": round(r["update_s"] / r["decisions"] * 1e3, 2),
            "update_cpu_ms_per_decision": round(r["update_cpu_s"] / r["decisions"] * 1e3, 2),
            "recipe_decisions_per_s_by_envs": by_envs, "cores": cores,
            "load_average": round(os.getloadavg()[0], 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="loop_with_corridor,maze")
    parser.add_argument("--max-time", type=float, default=300.0,
                        help="simulated seconds per episode")
    parser.add_argument("--recipe-only", action="store_true",
                        help="measure only the shipped recipe's training throughput")
    parser.add_argument("--n-envs", type=int, default=None,
                        help="the recipe with this many envs (default: 2, then 1 and 4)")
    parser.add_argument("--device", default="auto", help="the learner's torch device")
    parser.add_argument("--n-steps", type=int, default=None,
                        help="decisions per env in the recipe's round (default: the recipe's)")
    parser.add_argument("--overlap", action="store_true",
                        help="measure only ppo.overlap against the same recipe without it")
    parser.add_argument("--recipe", default=None,
                        help="with --overlap: the recipe (default: the shipped one's)")
    parser.add_argument("--rollouts", type=int, default=3,
                        help="with --overlap: rollouts and updates per measured run")
    parser.add_argument("--repeats", type=int, default=1,
                        help="with --overlap: runs of each mode, alternated")
    args = parser.parse_args()
    if args.overlap:
        from mjexplore.policies.models import DEFAULT_MODEL

        recipe = args.recipe or f"training/{DEFAULT_MODEL['gvn']}.yaml"
        print(json.dumps(overlap_figures(recipe, args.rollouts, args.repeats, args.device,
                                         args.n_steps, args.n_envs)))
        return
    envs = [args.n_envs] if args.n_envs else [2, 1, 4]
    if args.recipe_only:
        print(json.dumps(recipe_figures(envs, args.device, args.n_steps)))
        return
    scenes = [s for s in args.scenes.split(",") if s]
    out: dict[str, float | str] = {}
    for mode in ("physics", "training"):
        jobs = [(s, mode, args.max_time) for s in scenes]
        t = time.perf_counter()
        with mp.get_context("spawn").Pool(2) as pool:
            rows = pool.map(run, jobs)
        wall = time.perf_counter() - t
        n = sum(r["decisions"] for r in rows)
        busy = sum(r["wall_s"] for r in rows)
        cores = min(2, len(jobs))
        out[f"{mode}_decisions_per_s_2cores"] = round(n / max(busy / cores, 1e-9), 2)
        out[f"{mode}_rtf_per_core"] = round(sum(r["sim_time_s"] for r in rows) / busy, 1)
        for part in ("physics", "lidar", "mapping", "topology", "navigation", "policy"):
            out[f"{mode}_share_{part}"] = round(sum(r[part] for r in rows) / busy, 3)
        out[f"{mode}_ms_per_decision"] = round(busy / n * 1e3, 1)
        if mode == "training":
            topo = sum(r["topology"] for r in rows) / n * 1e3
            ter = sum(r["ter"] for r in rows) / n * 1e3
            pol = sum(r["policy"] for r in rows) / n * 1e3
            fwd = sum(r["training_forward"] for r in rows) / n * 1e3
            out.update(topology_ms_per_decision=round(topo, 2), ter_build_ms=round(ter, 2),
                       policy_ms_per_decision=round(pol, 2),
                       topology_plus_policy_ms=round(topo + pol, 2),
                       target_ms=8.0,
                       training_forward_ms=round(fwd, 2),
                       ariadne_ms_per_decision=ARIADNE_MS_PER_DECISION,
                       speedup_vs_ariadne=round(ARIADNE_MS_PER_DECISION / (topo + pol), 1))
        out[f"{mode}_bench_wall_s"] = round(wall, 1)
    from mjexplore.episode.workers import reuse_freed_memory

    reuse_freed_memory()  # As mjexplore train sets it for its learner.
    t = time.perf_counter()
    kinematic = ppo_round("kinematic")
    ppo = ppo_round("grid")
    n, rollout, update = ppo["decisions"], ppo["rollout_s"], ppo["update_s"]
    rate, kin_rate = _rate(ppo), _rate(kinematic)
    out.update(rollout_ms_per_decision=round(rollout / n * 1e3, 2),
               update_ms_per_decision=round(update / n * 1e3, 2), update_target_ms=10.0,
               update_share_of_training=round(update / (rollout + update), 3),
               train_decisions_per_s=round(rate, 2),
               train_decisions_per_s_kinematic=round(kin_rate, 2),
               grid_over_kinematic=round(rate / kin_rate, 2),
               ppo_bench_wall_s=round(time.perf_counter() - t, 1))
    # Two envs per core: while one env of a core waits for the slower env of its step,
    # the other works (a decision takes from one to hundreds of control periods).
    rate4 = _rate(ppo_round("grid", n_envs=4))
    out.update(train_decisions_per_s_4envs=round(rate4, 2),
               four_envs_over_two=round(rate4 / rate, 2))
    v2 = v2_round()
    n = v2["decisions"]
    out.update(v2_rollout_ms_per_decision=round(v2["rollout_s"] / n * 1e3, 2),
               v2_update_ms_per_decision=round(v2["update_s"] / n * 1e3, 2),
               v2_train_decisions_per_s=round(_rate(v2), 2))
    out.update(recipe_figures(envs, args.device, args.n_steps))
    out["decisions"] = "GVN policy, seed 0, " + ",".join(scenes)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
