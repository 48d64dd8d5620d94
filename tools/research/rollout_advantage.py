"""Trial and error one decision at a time: the exact effect of departing from pocket_nearest at
a decision, measured by rollouts, and whether what the actor observes predicts it.

On each training layout (the recipe's training stream: generator seeds below 2**31, never a
validation or test layout) the prior (gvn_v3's path prior: pocket_nearest's rule) drives an
episode in the grid world, which is deterministic. At a share (``--share``) of its decisions,
drawn at random among those with more than one valid node, the process forks once per
alternative: the ``--alternatives`` valid nodes the prior ranks next. The fork takes that
node, then follows the prior to the end. Its exploration time against the prior's own
episode is the departure's whole effect on that layout, with nothing else changed:
``d = log(T_departure / T_prior)`` (> 0: slower; an episode that does not explore counts the
time limit plus 1000 s per unit of coverage missing).

With ``--nudge M`` each departed decision gets one more fork, a row of rank -1: the prior's
own node with the robot first moved M metres (1 mm, say) in a random direction. Its ``d`` is
the noise floor: how much of a departure's effect the episode's sensitivity to any change at
all would give.

A learner that beats its prior has to find departures of ``d < 0`` from what it observes.
``--fit`` reads the collected rows and asks whether the observable per-node terms of
``dagger_fit``'s linear model (:func:`v3_prior.node_terms`; the departure's terms minus the
prior node's) predict ``d`` on layouts held out (ridge regression, folds by layout): the
held-out correlation, and how the departures predicted to gain, and the tenth predicted best,
fared.
With ``--validate`` it then runs the rule that the fit on every layout implies (depart to the
node of least predicted ``d`` where that is below ``-margin``) on the recipe's validation
layouts beside the prior.

The actor's terms describe each node alone. Each row also carries the departure's map
context (``context``, :data:`CONTEXT` of the departed node minus the prior node's, then
:data:`PAIRWISE`): the unknown and occupied shares of the map within 1, 2 and 4 m of the
node, its path cost to the nearest other valid node and the mean to them all, the valid nodes
within 5 m of path, its bearing from the robot's heading; the path between the two nodes, the
detour of passing the departed node on the way to the prior's, how much longer a short tour
of every valid node is when it starts there, the valid nodes and the known share of the map.
``privileged`` holds what only the ground truth tells (:data:`PRIVILEGED`): the free area not
yet seen around each node. ``--fit --context`` fits the terms and the context together,
``--privileged`` the ground truth's terms too (never in a rule: an upper bound on what a
predictor of the unseen map could add); ``--observe`` measures both for rows collected
without them into ``OUT/context.jsonl`` by replaying the prior's episode.

One JSON line per departure goes to ``OUT/rows.jsonl`` (appended layout by layout, so a run
that stops keeps what it measured; ``--resume`` skips the layouts done), and one per start,
with the git revision and the arguments, to ``OUT/sessions.jsonl`` (``--observe`` too).

Usage: python -m tools.research.rollout_advantage --config training/gvn_batch.yaml
    --out runs/rollout/a [--layouts 40] [--share 0.08] [--alternatives 2] [--nudge 0.0]
    [--workers 2] [--resume]
       python -m tools.research.rollout_advantage --config ... --out runs/rollout/a --fit
    [--context] [--privileged] [--folds 5] [--ridge 1.0] [--validate] [--margin 0.0]
       python -m tools.research.rollout_advantage --config ... --out runs/rollout/a --observe
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
from pathlib import Path

import numpy as np

from tools.research.v3_prior import load_v3_recipe, node_terms, paired, penalised_time

_WORKER: dict = {}


def _init(config) -> None:
    from mjexplore.episode.workers import init_episode_worker

    init_episode_worker()
    _WORKER["config"] = config


def _terms(obs, mask):
    """(N, 10) node terms and (N,) prior logits of one observation."""
    features = np.asarray(obs["node_features"], np.float32).reshape(1, len(mask), -1)
    terms, prior = node_terms(features, np.asarray(mask, bool)[None])
    return terms[0].numpy(), prior[0].numpy()


def _follow_prior(env, obs, first_action: int) -> dict:
    """Steps ``env`` to the episode's end, ``first_action`` first, then pocket_nearest's
    choices (:class:`~mjexplore.learning.evaluation.NearestNodeRule`, 50 m a unit of pocket
    probability: the prior's greedy node); the episode's metrics."""
    from mjexplore.learning.evaluation import NearestNodeRule

    prior, action = NearestNodeRule(50.0), first_action
    while True:
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return info["episode_metrics"]
        action = prior.predict(obs, action_masks=env.action_masks())[0]


def _follow_prior_nudged(env, obs, action: int, offset: np.ndarray) -> dict:
    """:func:`_follow_prior` with the robot first moved by ``offset`` (x, y, metres, the
    ``map`` frame): how far the episode's time moves for a change that no explorer could
    mean, the noise floor under every departure's ``d``."""
    sim = env.episode.sim
    x, y, yaw = sim.pose
    sim._pose = (float(x + offset[0]), float(y + offset[1]), float(yaw))
    return _follow_prior(env, obs, action)


def _in_fork(run) -> dict:
    """``run()``'s result (a JSON-able dict) computed in a forked copy of this process: the
    whole episode state is copied exactly (copy on write), and this process's is untouched."""
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # The child: run, report, leave without running the parent's exit code.
        os.close(read)
        code = 1
        try:
            os.write(write, json.dumps(run()).encode())
            code = 0
        finally:
            os._exit(code)
    os.close(write)
    chunks = []
    while chunk := os.read(read, 65536):
        chunks.append(chunk)
    os.close(read)
    _, status = os.waitpid(pid, 0)
    if status != 0:
        raise RuntimeError(f"a departure's rollout failed (wait status {status})")
    return json.loads(b"".join(chunks))


def _layout(job) -> list[dict]:
    """Every departure row of one layout (see the module docstring)."""
    from mjexplore.learning.evaluation import heldout_env

    scene, share, alternatives, nudge, seed = job
    config = _WORKER["config"]
    env = heldout_env(config, scene)
    obs, _ = env.reset(seed=config.eval.seed)
    rng = np.random.default_rng(seed)
    nudges = np.random.default_rng([*seed, 1])  # Apart, so that --nudge moves no draw.
    rows, k = [], 0
    while True:  # This process drives the prior's own episode.
        mask = env.action_masks()
        terms, prior = _terms(obs, mask)
        logits = np.where(mask, prior, -np.inf)
        order = np.argsort(-logits)
        choice = int(order[0])
        if rng.random() < share and mask.sum() > 1:
            departures = [int(a) for a in order[1:1 + alternatives] if mask[a]]
            context = _in_fork(lambda c=choice, n=departures: _decision_context(
                env, c, n)) if departures else {}
            # Rank 0, once a layout, is the prior's own node: its fork must run the prior's
            # episode to the same time (the check that a fork copies the episode exactly).
            for rank in range(0 if not rows else 1, 1 + alternatives):
                a = int(order[rank])
                if not mask[a]:
                    break
                branch = _in_fork(lambda a=a, obs=obs: _follow_prior(env, obs, a))
                rows.append({"scene": scene, "decision": k, "rank": rank,
                             "valid": int(mask.sum()), "t": penalised_time(branch, config),
                             "logit_gap": float(logits[choice] - logits[a]),
                             "terms": (terms[a] - terms[choice]).tolist(),
                             **(context[str(a)] if rank else {})})
            if nudge > 0:
                heading = nudges.uniform(-np.pi, np.pi)
                offset = nudge * np.array([np.cos(heading), np.sin(heading)])
                branch = _in_fork(lambda o=offset, obs=obs, c=choice: _follow_prior_nudged(
                    env, obs, c, o))
                rows.append({"scene": scene, "decision": k, "rank": -1,
                             "valid": int(mask.sum()), "t": penalised_time(branch, config),
                             "nudge": offset.tolist()})
        obs, _, terminated, truncated, info = env.step(choice)
        k += 1
        if terminated or truncated:
            break
    t_prior = penalised_time(info["episode_metrics"], config)
    for row in rows:
        row.update(t_prior=t_prior, d=float(np.log(row["t"] / t_prior)))
    if rows and rows[0]["t"] != t_prior:
        raise RuntimeError(f"{scene}: the prior's own node, run in a fork, took {rows[0]['t']} "
                           f"s against the episode's {t_prior} s: forks do not copy the "
                           "episode exactly, and no row of this layout can be trusted")
    return rows


# The map around a node and its place among the other valid nodes: what the actor's terms
# leave out, measured for the prior's node and each departure (``--observe``).
RADII = (1.0, 2.0, 4.0)  # metres
CONTEXT = tuple(f"{kind}_{r:g}" for r in RADII for kind in ("unknown", "occupied")) + (
    "isolation", "mean_path", "nodes_5m", "bearing")
PAIRWISE = ("between", "detour", "tour", "valid", "known_share")
# What only the ground truth tells (never the actor's): the free area not yet seen within 2,
# 4 and 8 m of the node and in the unseen free regions that touch it, tens of m^2 (departed
# node minus the prior's), and all of it on the map, hundreds of m^2. An upper bound on what
# a predictor of the unseen map could add to the observation.
PRIVILEGED_RADII = (2.0, 4.0, 8.0)  # metres
PRIVILEGED = tuple(f"unseen_free_{r:g}" for r in PRIVILEGED_RADII) + ("behind", "unseen_total")


def _disc(grid, pos, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols) index arrays of the cells within ``radius`` (metres) of ``pos``, clipped
    to the grid, and the mask of those inside the disc and the grid."""
    half = int(np.ceil(radius / grid.resolution))
    row, col = grid.world_to_cell(pos)
    rows = np.arange(row - half, row + half + 1)[:, None]
    cols = np.arange(col - half, col + half + 1)[None, :]
    counted = (((rows - row) ** 2 + (cols - col) ** 2 <= half ** 2)
               & (rows >= 0) & (rows < grid.shape[0]) & (cols >= 0) & (cols < grid.shape[1]))
    return (np.clip(rows, 0, grid.shape[0] - 1), np.clip(cols, 0, grid.shape[1] - 1), counted)


def _path_costs(state, start, positions) -> np.ndarray:
    """Path costs (metres; inf where unreachable) from ``start`` (x, y) to within 0.5 m of
    each of ``positions`` (n, 2), as the v2 features read a node's path."""
    grid = state.grid
    cells = np.clip(grid.world_to_cell(positions), 0, np.array(grid.shape) - 1)
    return state.costmap.distances_near(start, cells, int(round(0.5 / grid.resolution)))


def _node_context(state, positions, valid, x) -> tuple[np.ndarray, np.ndarray]:
    """The :data:`CONTEXT` features of node ``x`` (a valid node index), and its path costs to
    every node (metres, inf where unreachable or not valid)."""
    grid, pos = state.grid, positions[x]
    out = []
    for r in RADII:
        rows, cols, counted = _disc(grid, pos, r)
        cells = grid.data[rows, cols]
        n = max(int(counted.sum()), 1)
        out += [float(((cells < 0) & counted).sum()) / n,
                float(((cells >= 50) & counted).sum()) / n]
    path = _path_costs(state, pos, positions)
    path[~valid] = np.inf
    others = path.copy()
    others[x] = np.inf
    finite = others[np.isfinite(others)]
    heading = np.arctan2(pos[1] - state.pose[1], pos[0] - state.pose[0])
    out += [float(finite.min()) if len(finite) else 100.0,
            float(np.minimum(finite, 100.0).mean()) if len(finite) else 100.0,
            float((finite < 5.0).sum()),
            float(np.cos(heading - state.pose[2]))]
    return np.array(out), path


def _tour(first: int, costs: np.ndarray, nodes: np.ndarray) -> float:
    """Length (metres) of a short open tour of ``nodes`` that starts at ``first``
    (:func:`~mjexplore.navigation.tour.open_tour`, the frontier-TSP explorer's solver).
    ``costs``: (N, N) path costs between nodes, capped (unreachable = the cap)."""
    from mjexplore.navigation.tour import open_tour, tour_length

    places = [first, *(n for n in nodes if n != first)]
    distance = costs[np.ix_(places, places)]
    return tour_length(distance, open_tour(distance))


def _node_privileged(state, unseen, regions, sizes, pos) -> np.ndarray:
    """The per-node :data:`PRIVILEGED` features (the first four) of a node at ``pos``."""
    cell_area = state.grid.resolution ** 2
    out = []
    for r in PRIVILEGED_RADII:
        rows, cols, counted = _disc(state.grid, pos, r)
        out.append(float((unseen[rows, cols] & counted).sum()) * cell_area / 10.0)
    rows, cols, counted = _disc(state.grid, pos, 0.5)
    touching = np.unique(regions[rows, cols][counted])
    out.append(float(sizes[touching[touching > 0]].sum()) * cell_area / 10.0)
    return np.array(out)


def _decision_context(env, choice: int, departures: list[int]) -> dict:
    """For each departure: ``context``, its :data:`CONTEXT` minus the prior node's, then
    :data:`PAIRWISE` (path between the two nodes, the detour of passing the departure on the
    way to the prior's node, how much longer a short tour of every valid node is from the
    robot through the departure first than through the prior's node first, metres; valid
    nodes; known share of the map); and
    ``privileged``, :data:`PRIVILEGED` the same way."""
    from scipy import ndimage

    state = env.episode.decision_state()
    positions = env.decisions.padded.node_positions
    valid = env.action_masks()
    nodes = np.flatnonzero(valid)
    costs = np.full((len(valid), len(valid)), 100.0)
    paths = {}
    for x in nodes:  # Every valid node's context and path costs, for the tours.
        paths[x] = _node_context(state, positions, valid, x)
        costs[x] = np.minimum(paths[x][1], 100.0)
    prior, path_p = paths[choice]
    robot = np.minimum(_path_costs(state, state.pose[:2], positions), 100.0)
    known = float((state.grid.data >= 0).mean())
    truth = state.ground_truth
    if truth is None or truth.shape != state.grid.shape:
        raise RuntimeError("the privileged context needs the ground truth on the map's grid")
    unseen = (state.grid.data < 0) & truth.free
    regions, _ = ndimage.label(unseen)
    sizes = np.bincount(regions.reshape(-1))
    total = float(unseen.sum()) * state.grid.resolution ** 2 / 100.0
    seen_prior = _node_privileged(state, unseen, regions, sizes, positions[choice])
    out = {}
    tour_prior = robot[choice] + _tour(choice, costs, nodes)
    for a in departures:
        mine = paths[a][0]
        between = min(float(path_p[a]), 100.0)
        privileged = _node_privileged(state, unseen, regions, sizes, positions[a]) - seen_prior
        out[str(a)] = {"context": (mine - prior).tolist() + [
            between, min(float(robot[a] + between - robot[choice]), 100.0),
            float(robot[a] + _tour(a, costs, nodes) - tour_prior),
            float(valid.sum()), known], "privileged": privileged.tolist() + [total]}
    return out


def _observe(job) -> list[dict]:
    """The context rows of one layout's departures: the prior's episode replayed (the
    grid world is deterministic) and, at each departed decision, :func:`_decision_context`
    measured in a fork (so that its searches cannot touch the episode)."""
    from mjexplore.learning.evaluation import heldout_env

    scene, wanted, t_prior = job  # wanted: {decision: [ranks]}
    config = _WORKER["config"]
    env = heldout_env(config, scene)
    obs, _ = env.reset(seed=config.eval.seed)
    rows, k = [], 0
    while True:
        mask = env.action_masks()
        _, prior = _terms(obs, mask)
        order = np.argsort(-np.where(mask, prior, -np.inf))
        choice = int(order[0])
        if k in wanted:
            nodes = [int(order[rank]) for rank in wanted[k]]
            context = _in_fork(lambda c=choice, n=nodes: _decision_context(env, c, n))
            rows += [{"scene": scene, "decision": k, "rank": rank, **context[str(a)]}
                     for rank, a in zip(wanted[k], nodes)]
        obs, _, terminated, truncated, info = env.step(choice)
        k += 1
        if terminated or truncated:
            break
    if penalised_time(info["episode_metrics"], config) != t_prior:
        raise RuntimeError(f"{scene}: the replayed prior took another time than the rows' "
                           f"{t_prior} s: its context rows would describe other states")
    return rows


def _observe_all(args, config) -> None:
    """``OUT/context.jsonl``: :func:`_observe` on every layout of ``OUT/rows.jsonl``."""
    rows = [json.loads(line) for line in (args.out / "rows.jsonl").read_text().splitlines()]
    path = args.out / "context.jsonl"
    done = set()  # Layouts measured whole (lines without "privileged" predate it).
    if path.is_file():
        done = {c["scene"] for c in map(json.loads, path.read_text().splitlines())
                if "privileged" in c}
    jobs = {}
    for r in rows:
        if r["rank"] > 0 and r["scene"] not in done and "privileged" not in r:
            wanted = jobs.setdefault(r["scene"], ({}, r["t_prior"]))[0]
            wanted.setdefault(r["decision"], []).append(r["rank"])
    ctx = mp.get_context("spawn")
    with ctx.Pool(args.workers, initializer=_init, initargs=(config,)) as pool:
        for out in pool.imap_unordered(_observe, [(s, *v) for s, v in jobs.items()]):
            with open(path, "a") as f:
                f.writelines(json.dumps(r) + "\n" for r in out)
            print(json.dumps({"scene": out[0]["scene"], "rows": len(out)}), flush=True)


def _collect(args, config) -> None:
    from mjexplore.envs.exploration import procedural_scene

    rows_path = args.out / "rows.jsonl"
    done = set()
    if args.resume and rows_path.is_file():
        done = {json.loads(line)["scene"] for line in rows_path.read_text().splitlines()}
    draw = np.random.default_rng([args.seed, 0])
    scenes = [str(procedural_scene(config.env.procedural, draw)) for _ in range(args.layouts)]
    jobs = [(s, args.share, args.alternatives, args.nudge, [args.seed, i])
            for i, s in enumerate(scenes) if s not in done]
    ctx = mp.get_context("spawn")
    with ctx.Pool(args.workers, initializer=_init, initargs=(config,)) as pool:
        for rows in pool.imap_unordered(_layout, jobs):
            with open(rows_path, "a") as f:
                f.writelines(json.dumps(r) + "\n" for r in rows)
            d = np.array([r["d"] for r in rows if r["rank"] > 0])
            if len(d):
                print(json.dumps({"scene": rows[0]["scene"], "departures": len(d),
                                  "t_prior": rows[0]["t_prior"], "mean_d": float(d.mean()),
                                  "gained": int((d < 0).sum()), "equal": int((d == 0).sum())}),
                      flush=True)


def _ridge(x: np.ndarray, y: np.ndarray, ridge: float) -> np.ndarray:
    """Weights (with an intercept last) of a ridge regression of y on standardised x."""
    mean, scale = x.mean(0), x.std(0) + 1e-9
    z = np.column_stack([(x - mean) / scale, np.ones(len(x))])
    penalty = ridge * np.eye(z.shape[1])
    penalty[-1, -1] = 0.0
    beta = np.linalg.solve(z.T @ z + penalty, z.T @ y)
    return np.r_[beta[:-1] / scale, beta[-1] - (beta[:-1] / scale) @ mean]


def _features(rows) -> np.ndarray:
    return np.array([r["terms"] + [r["logit_gap"]] for r in rows])


def _fit(args) -> dict:
    rows = [json.loads(line) for line in (args.out / "rows.jsonl").read_text().splitlines()]
    rows = [r for r in rows if r["rank"] > 0]
    x = _features(rows)
    keys = ("context",) * args.context + ("privileged",) * args.privileged
    if keys:  # Only the departures whose context was measured, the terms beside it.
        path = args.out / "context.jsonl"  # Rows collected before rows carried it.
        lines = path.read_text().splitlines() if path.is_file() else []
        context = {(c["scene"], c["decision"], c["rank"]): sum((c[k] for k in keys), [])
                   for c in (*map(json.loads, lines), *rows) if all(k in c for k in keys)}
        keep = [i for i, r in enumerate(rows)
                if (r["scene"], r["decision"], r["rank"]) in context]
        rows = [rows[i] for i in keep]
        x = np.column_stack([x[keep], [context[r["scene"], r["decision"], r["rank"]]
                                       for r in rows]])
    scenes = sorted({r["scene"] for r in rows})
    y = np.array([r["d"] for r in rows])
    rng = np.random.default_rng(args.seed)
    fold_of = dict(zip(scenes, rng.permutation(len(scenes)) % args.folds))
    fold = np.array([fold_of[r["scene"]] for r in rows])
    predicted = np.empty_like(y)
    for f in range(args.folds):
        w = _ridge(x[fold != f], y[fold != f], args.ridge)
        predicted[fold == f] = x[fold == f] @ w[:-1] + w[-1]
    gain = predicted < -args.margin
    # The tenth of the departures the held-out fits rank best: is any signal there at all?
    best = np.argsort(predicted)[:max(1, len(y) // 10)]
    w = _ridge(x, y, args.ridge)
    return {"departures": len(rows), "layouts": len(scenes), "mean_d": float(y.mean()),
            "share_gained": float((y < 0).mean()), "sd_d": float(y.std()),
            "heldout_corr": float(np.corrcoef(predicted, y)[0, 1]),
            "predicted_gain": int(gain.sum()),
            "their_mean_d": float(y[gain].mean()) if gain.any() else None,
            "their_share_gained": float((y[gain] < 0).mean()) if gain.any() else None,
            "best_tenth_mean_d": float(y[best].mean()),
            "best_tenth_share_gained": float((y[best] < 0).mean()),
            "weights": w.tolist()}


class PredictedDepartureRule:
    """The prior's node unless a valid node's predicted ``d`` (the fit's weights over its
    terms minus the prior node's, the logit gap and, with ``env``, its map context) is below
    ``-margin``: then the node of least predicted ``d``. SB3's ``predict``.

    Args:
        weights: The fit's weights, the intercept last.
        margin: Predicted log-ratio gain a departure needs.
        env: The episode's env, for a fit with ``--context`` (its context is measured in a
            fork at each decision); None for a fit of the terms alone.
    """

    def __init__(self, weights, margin: float, env=None) -> None:
        self.w = np.asarray(weights[:-1], np.float64)
        self.b = float(weights[-1])
        self.margin = margin
        self.env = env

    def predict(self, obs, deterministic=True, action_masks=None):
        mask = np.asarray(action_masks, bool)
        terms, prior = _terms(obs, mask)
        logits = np.where(mask, prior, -np.inf)
        choice = int(np.argmax(logits))
        valid = np.flatnonzero(mask & (np.arange(len(mask)) != choice))
        if not len(valid):
            return choice, None
        x = np.column_stack([terms[valid] - terms[choice], logits[choice] - logits[valid]])
        if self.env is not None:
            nodes = valid.tolist()
            context = _in_fork(lambda: _decision_context(self.env, choice, nodes))
            x = np.column_stack([x, [context[str(a)]["context"] for a in nodes]])
        d = x @ self.w + self.b
        best = int(np.argmin(d))
        return (int(valid[best]) if d[best] < -self.margin else choice), None


def _episode(job) -> float:
    from mjexplore.learning.evaluation import NearestNodeRule, heldout_env, heldout_episode

    weights, margin, context, scene = job
    config = _WORKER["config"]
    env = heldout_env(config, scene)
    policy = (NearestNodeRule(50.0) if weights is None
              else PredictedDepartureRule(weights, margin, env if context else None))
    return penalised_time(heldout_episode(policy, config, scene, env), config)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="training recipe (YAML)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--layouts", type=int, default=40, help="default: 40")
    parser.add_argument("--share", type=float, default=0.08,
                        help="chance that a decision is departed from (default: 0.08, some "
                             "6 a layout)")
    parser.add_argument("--alternatives", type=int, default=2,
                        help="departures per decision: the nodes the prior ranks next "
                             "(default: 2)")
    parser.add_argument("--nudge", type=float, default=0.0,
                        help="at each departed decision, one more fork: the prior's own node "
                             "with the robot first moved this far (metres; a row of rank -1), "
                             "the noise floor of d (default: 0, none)")
    parser.add_argument("--workers", type=int, default=2, help="default: 2")
    parser.add_argument("--seed", type=int, default=0, help="default: 0")
    parser.add_argument("--resume", action="store_true", help="skip the layouts done "
                        "(default: off)")
    parser.add_argument("--fit", action="store_true",
                        help="fit the collected rows instead of collecting (default: off)")
    parser.add_argument("--observe", action="store_true",
                        help="measure the map context of the collected departures into "
                             "OUT/context.jsonl (default: off)")
    parser.add_argument("--context", action="store_true",
                        help="with --fit: the measured map context beside the terms "
                             "(default: off)")
    parser.add_argument("--privileged", action="store_true",
                        help="with --fit: the ground truth's unseen free area around the "
                             "nodes beside the terms, an upper bound on what a predictor of "
                             "the unseen map could add (default: off)")
    parser.add_argument("--folds", type=int, default=5, help="default: 5")
    parser.add_argument("--ridge", type=float, default=1.0, help="default: 1.0")
    parser.add_argument("--margin", type=float, default=0.0,
                        help="predicted log-ratio gain a departure needs (default: 0.0)")
    parser.add_argument("--validate", action="store_true",
                        help="with --fit: run the fitted rule on the validation layouts "
                             "(default: off)")
    args = parser.parse_args()

    if args.validate and args.privileged:
        parser.error("--validate runs a rule of what the actor may see: leave out "
                     "--privileged")
    config = load_v3_recipe(parser, args.config)
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.fit:  # Which code measured which rows (and contexts).
        from mjexplore.io.provenance import git_revision

        with open(args.out / "sessions.jsonl", "a") as f:
            f.write(json.dumps({"revision": git_revision(), "args": {
                k: str(v) for k, v in vars(args).items()}}) + "\n")
    if args.observe:
        _observe_all(args, config)
        return
    if not args.fit:
        _collect(args, config)
        return
    result = _fit(args)
    print(json.dumps(result), flush=True)
    if args.validate:
        scenes = config.eval.scene_list()
        ctx = mp.get_context("spawn")
        with ctx.Pool(args.workers, initializer=_init, initargs=(config,)) as pool:
            jobs = [(w, args.margin, args.context, s)
                    for w in (result["weights"], None) for s in scenes]
            times = np.array(pool.map(_episode, jobs, chunksize=1)).reshape(2, len(scenes))
        print(json.dumps({"validate": len(scenes), **paired(times[0], times[1]),
                          "times": times.tolist()}), flush=True)


if __name__ == "__main__":
    main()
