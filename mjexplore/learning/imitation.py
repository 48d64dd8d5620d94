"""A warm start for PPO: the policy imitates the ground-truth oracle (behaviour cloning, then
optionally DAgger).

The oracle (:mod:`mjexplore.explorers.oracle`) knows the true map and plans a near-optimal
coverage tour; :meth:`~mjexplore.explorers.oracle.OracleExplorer.expert_choice` says which
of the valid TER nodes it would go to next, in any state. Episodes of the training env are
driven by those choices, every decision's observation, mask and expert action is kept, and the
policy's actor is fitted to the expert actions by cross-entropy over the valid actions
(the critic is left to PPO). Learned explorers that beat classic ones start so (ARiADNE's
successors and most imitation-then-RL recipes): PPO from a uniform policy spends most of a
small budget finding what a planner already knows.

Cloning on the expert's states alone drifts: the learner's first mistakes take it to states the
expert never visits, where it was never taught. DAgger (Ross, Gordon and Bagnell, AISTATS 2011)
fixes that with ``dagger_iterations`` more rounds (:func:`warm_start`): round ``i`` rolls out a
mixture that lets the expert act at a decision with probability ``beta_i = beta0 ** i`` and the
learner otherwise (round 0 is the expert alone: plain cloning), labels *every* visited decision
with the oracle's choice on that state, adds them to all the labelled decisions so far and
refits the actor on the aggregate (:func:`clone`, continuing from the current weights). The
learner acts by its most probable valid action (the way the explorers and the model selection
run it, so the states taught are those the deployed policy meets), or with ``dagger_sample`` by
a draw from its distribution (more varied states, some the deployed policy never reaches).

Seeds (all layouts generated, grid world or whatever ``env`` says): round ``i``'s episode ``k``
resets the training env with seed ``imitation.seed + i * episodes + k`` (round 0: ``seed + k``,
the plain cloning's episodes); the env draws the layout's family, size and generator seed (in
[0, 2**31 - 1)) from that seed's stream. PPO's envs reset from ``seed + steps done + env index``
(the run's seed; later resets continue each env's stream), so keep ``imitation.seed`` above the
run's seed plus its decision budget (the recipes use 10**8) and the two streams never start
alike. Model selection's validation layouts (``eval.scene_list()``: generator seeds
``2**31 + [0, eval.layouts)``) and the test layouts after them (``eval.unseen_scenes(n)``:
``2**31 + [eval.layouts, eval.layouts + n)``, see
:func:`~mjexplore.envs.exploration.heldout_scenes`) are never drawn by a training stream.

Memory: an observation of the v3 recipe (256 nodes, 10 remembered TERs) is 214 kB of float32
(209 KiB), so 1,000 decisions hold about 204 MiB; a refit briefly holds the aggregate twice.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

# The oracle's answers to "which valid node next?" (methods of OracleExplorer) by the name
# ImitationConfig.expert gives them.
EXPERTS = {"choice": "expert_choice", "lookahead": "expert_lookahead"}

# A learner in a DAgger round: the observation (one decision's, unbatched) and its (A,) bool
# mask to (A,) action probabilities (zero at invalid actions).
Learner = Callable[[dict[str, np.ndarray], np.ndarray], np.ndarray]


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImitationConfig:
    """Behaviour cloning before PPO, optionally continued by DAgger rounds.

    Attributes:
        episodes: Expert episodes to collect (0: no warm start), and the episodes of each
            DAgger round.
        epochs: Passes over the collected decisions (at each DAgger refit: over all the
            decisions aggregated so far).
        batch_size: Decisions per gradient step.
        learning_rate: Adam's step size for the cloning.
        seed: Seed of the expert episodes' layouts and starts (disjoint from PPO's when it
            differs from the run's seed; the module docstring gives every round's seeds).
        dagger_iterations: DAgger rounds after the plain cloning (0: plain cloning only).
        beta0: Round ``i`` lets the expert act at a decision with probability
            ``beta0 ** i`` (round 0: always); 0 is Ross et al.'s practical choice, the
            learner alone from round 1.
        dagger_sample: The learner samples its action from its distribution over the valid
            actions instead of taking the most probable one.
        expert: The oracle's answer imitated: ``choice``
            (:meth:`~mjexplore.explorers.oracle.OracleExplorer.expert_choice`, the node
            nearest the first viewpoint of its tour) or ``lookahead``
            (:meth:`~mjexplore.explorers.oracle.OracleExplorer.expert_lookahead`, the node
            that leaves the shortest path plus tour).
        keep_prior_m: With ``lookahead``: the label is the policy's prior's choice (its
            greedy node) unless the lookahead's best node leaves a path plus tour shorter by
            more than this many metres (0: the lookahead's best alone). On the first 16
            validation layouts the lookahead alone took 254.0 s against the prior's 276.5
            (per-layout ratio 1.015, 0.85-1.26: faster on 10, far slower on some); keeping
            the prior unless 5 m are saved, 246.1 s (0.898, 0.84-0.96, faster on 13 of 16,
            slower on 2); unless 15 m, 279.0 s (the prior, nearly).
        loss: ``cross_entropy`` (the label's log-probability) or ``margin`` (a hinge on the
            label's logit against the best other valid one, :func:`margin_loss`: zero where
            the policy's greedy choice is the label by ``margin`` nats, so a residual on a
            prior the label mostly agrees with is fitted only where they differ).
        margin: The hinge's margin, nats.
        workers: Processes the rounds' episodes run in (one thread each; the labelled
            decisions are the same for any number).
    """

    episodes: int = 0
    epochs: int = 8
    batch_size: int = 64
    learning_rate: float = 1e-3
    seed: int = 1_000_003
    dagger_iterations: int = 0
    beta0: float = 0.0
    dagger_sample: bool = False
    expert: str = "choice"
    keep_prior_m: float = 0.0
    loss: str = "cross_entropy"
    margin: float = 1.0
    workers: int = 1

    def __post_init__(self) -> None:
        if self.workers < 1 or self.keep_prior_m < 0:
            raise ValueError("imitation.workers must be >= 1 and keep_prior_m >= 0")
        if self.loss not in ("cross_entropy", "margin") or self.margin <= 0:
            raise ValueError("imitation.loss must be cross_entropy or margin, and margin > 0")
        if self.keep_prior_m and self.expert != "lookahead":
            raise ValueError("imitation.keep_prior_m needs expert: lookahead")
        if self.expert not in EXPERTS:
            raise ValueError(f"imitation.expert must be one of {sorted(EXPERTS)}, "
                             f"not {self.expert!r}")
        if self.episodes < 0 or self.epochs < 1 or self.batch_size < 1 or \
                self.learning_rate <= 0:
            raise ValueError("imitation: episodes must be >= 0, epochs and batch_size >= 1, "
                             "learning_rate > 0")
        if self.dagger_iterations < 0 or not 0.0 <= self.beta0 <= 1.0:
            raise ValueError("imitation: dagger_iterations must be >= 0 and beta0 in [0, 1]")
        if self.dagger_iterations and not self.episodes:
            raise ValueError("imitation: dagger_iterations needs episodes >= 1 (per round)")

    def beta(self, iteration: int) -> float:
        """The probability that the expert acts at a decision of round ``iteration``."""
        return float(self.beta0 ** iteration)  # 0 ** 0 == 1: round 0 is the expert's.


def collect_expert_decisions(env_config, episodes: int, seed: int, expert: str = "choice",
                             workers: int = 1, keep_prior: tuple[float, float] | None = None
                             ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict]:
    """Runs ``episodes`` training-env episodes with the oracle choosing every node (a
    :func:`collect_learner_decisions` round without a learner).

    Returns:
        (observations stacked per key, (n, A) bool action masks, (n,) expert actions,
        stats: decisions, episodes explored, mean exploration time in simulated seconds).
    """
    observations, masks, actions, _, stats = collect_learner_decisions(
        env_config, None, episodes, seed, beta=1.0, expert=expert, workers=workers,
        keep_prior=keep_prior)
    keep = ("decisions", "episodes", "explored", "mean_exploration_time_s")
    return observations, masks, actions, {k: stats[k] for k in keep}


def collect_learner_decisions(env_config, learner: Learner | None, episodes: int, seed: int,
                              beta: float = 0.0, sample: bool = False, expert: str = "choice",
                              workers: int = 1, keep_prior: tuple[float, float] | None = None
                              ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray,
                                         np.ndarray, dict]:
    """One DAgger round: ``episodes`` training-env episodes (reset seeds ``seed + k``) where
    at each decision the expert acts with probability ``beta`` and the learner otherwise,
    every decision labelled with the oracle's choice on its state.

    Args:
        env_config: The training env's settings.
        learner: The learner's action probabilities of a decision (see :data:`Learner`);
            None: the expert acts at every decision (``beta`` must be 1).
        episodes: Episodes of the round.
        seed: Reset seed of the first episode; episode ``k``'s ``seed + k`` also seeds who
            acts (and, with ``sample``, the learner's draw).
        beta: Probability that the expert, not the learner, acts at a decision.
        sample: The learner draws its action from its probabilities (else the most
            probable valid one).
        expert: The oracle's answer that labels the decisions (a key of :data:`EXPERTS`).
        workers: Processes the episodes run in (one thread each); the result is the same
            for any number, episode by episode in order.
        keep_prior: With ``lookahead``: (metres the lookahead must save, the prior's
            ``pocket_m``): the label is the prior's greedy node unless the lookahead's best
            saves more (see :attr:`ImitationConfig.keep_prior_m`).

    Returns:
        (observations stacked per key (float32), (n, A) bool masks, (n,) expert actions, (n,)
        actions taken, stats: decisions, episodes, explored, mean exploration time in
        simulated seconds, ``agreement`` (the share of decisions where the learner's most
        probable valid action is the expert's, whoever acted) and ``expert_share`` (the
        share of decisions the expert acted at)).
    """
    jobs = [(env_config, learner, seed + k, beta, sample, expert, keep_prior)
            for k in range(episodes)]
    if workers > 1 and episodes > 1:
        import multiprocessing as mp

        from mjexplore.episode.workers import init_episode_worker, single_thread_children

        with single_thread_children(), mp.get_context("spawn").Pool(
                min(workers, episodes), initializer=init_episode_worker) as pool:
            runs = pool.map(_labelled_episode, jobs, chunksize=1)
    else:
        runs = [_labelled_episode(job) for job in jobs]
    # Keys from every episode: one that ends before its first decision has none.
    keys = dict.fromkeys(k for run in runs for k in run["observations"])
    observations = {k: [o for run in runs for o in run["observations"].get(k, [])]
                    for k in keys}
    labels = [a for run in runs for a in run["labels"]]
    n = len(labels)
    times = [run["time"] for run in runs if run["time"] is not None]
    agree = sum(run["agree"] for run in runs)
    stats = {"decisions": n, "episodes": episodes,
             "explored": sum(run["explored"] for run in runs),
             "mean_exploration_time_s": float(np.mean(times)) if times else None,
             "agreement": agree / n if n else None,
             "expert_share": sum(run["by_expert"] for run in runs) / n if n else None}
    return ({k: np.stack(v) for k, v in observations.items()},
            np.array([m for run in runs for m in run["masks"]], bool),
            np.array(labels, np.int64),
            np.array([a for run in runs for a in run["taken"]], np.int64), stats)


def _prior_choice(obs: dict[str, np.ndarray], mask: np.ndarray, pocket_m: float) -> int:
    """The greedy valid node of a v2/v3 observation's path prior
    (:func:`~mjexplore.policies.gvn.path_prior`, ``pocket_m`` metres per unit of pocket
    probability)."""
    import torch

    from mjexplore.policies.gvn import path_prior

    features = torch.as_tensor(obs["node_features"]).reshape(len(mask), -1)
    logits = path_prior(features, 1.0, pocket_m).numpy()
    return int(np.argmax(np.where(mask, logits, -np.inf)))


def _labelled_episode(job) -> dict[str, Any]:
    """One episode of a DAgger round (see :func:`collect_learner_decisions`): its
    decisions' observations, masks, expert labels and actions taken, and its outcome."""
    from mjexplore.envs import ExplorationEnv
    from mjexplore.explorers import make_explorer
    from mjexplore.explorers.oracle import lookahead_expert

    env_config, learner, seed, beta, sample, expert, keep_prior = job
    env = ExplorationEnv(env_config)
    oracle = lookahead_expert() if expert == "lookahead" else make_explorer("oracle")
    choose = getattr(oracle, EXPERTS[expert])
    out: dict[str, Any] = {"observations": {}, "masks": [], "labels": [], "taken": [],
                           "time": None, "explored": False, "agree": 0, "by_expert": 0}
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    episode = env.episode
    assert episode is not None  # Set by reset().
    oracle.reset(np.random.default_rng(seed))
    while True:
        mask = env.action_masks()
        extra = {}
        if keep_prior:
            extra = {"baseline": _prior_choice(obs, mask, keep_prior[1]), "gain_m": keep_prior[0]}
        label = choose(episode.decision_state(), env.decisions.action_positions(), mask,
                       **extra)
        if label < 0:
            break
        if learner is None:
            probs, best = np.zeros(len(mask)), label
        else:
            probs = np.where(mask, np.asarray(learner(obs, mask), np.float64), 0.0)
            best = int(np.argmax(probs)) if probs.any() else label
        out["agree"] += best == label
        if rng.random() < beta:
            action = label
            out["by_expert"] += 1
        elif sample and probs.sum() > 0:
            action = int(rng.choice(len(probs), p=probs / probs.sum()))
        else:
            action = best
        for key, value in obs.items():
            out["observations"].setdefault(key, []).append(np.array(value, np.float32))
        out["masks"].append(mask)
        out["labels"].append(label)
        out["taken"].append(action)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            out["explored"] = info["end_reason"] == "explored"
            out["time"] = info["sim_time"]
            break
    env.close()
    return out


class PolicyLearner:
    """A policy's action probabilities over the valid actions (no gradients), as a
    :data:`Learner`; picklable, so that DAgger's rollouts can run in worker processes."""

    def __init__(self, policy) -> None:
        self.policy = policy

    def __getstate__(self) -> dict[str, Any]:
        # The policy as SB3 saves one (constructor arguments and weights): a fitted policy
        # can hold tensors of its last forward pass, which autograd keeps from crossing
        # process boundaries.
        return {"cls": type(self.policy), "data": self.policy._get_constructor_parameters(),
                "state_dict": {k: v.detach().cpu() for k, v in
                               self.policy.state_dict().items()}}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.policy = state["cls"](**state["data"])
        self.policy.load_state_dict(state["state_dict"])
        self.policy.set_training_mode(False)

    def __call__(self, obs: dict[str, np.ndarray], mask: np.ndarray) -> np.ndarray:
        return _probabilities(self.policy, {k: np.asarray(v)[None] for k, v in obs.items()},
                              np.asarray(mask, bool)[None])[0]


def policy_learner(policy) -> Learner:
    """A policy's action probabilities over the valid actions, as a :data:`Learner`."""
    return PolicyLearner(policy)


def _probabilities(policy, observations: dict[str, np.ndarray], masks: np.ndarray,
                   batch: int = 64) -> np.ndarray:
    """(n, A) action probabilities of batched observations under ``masks``, in batches."""
    import torch

    policy.set_training_mode(False)
    out = []
    with torch.no_grad():
        for start in range(0, len(masks), batch):
            obs = {k: torch.as_tensor(v[start:start + batch], device=policy.device)
                   for k, v in observations.items()}
            dist = policy.get_distribution(obs, action_masks=masks[start:start + batch])
            out.append(dist.distribution.probs.cpu().numpy())
    return np.concatenate(out) if out else np.zeros((0, masks.shape[-1]))


def agreement(policy, observations: dict[str, np.ndarray], masks: np.ndarray,
              actions: np.ndarray) -> float | None:
    """The share of decisions whose most probable valid action under ``policy`` is
    ``actions``' (None without decisions)."""
    if not len(actions):
        return None
    probs = _probabilities(policy, observations, masks)
    return float((probs.argmax(-1) == actions).mean())


def departures(policy, observations: dict[str, np.ndarray], masks: np.ndarray,
               labels: np.ndarray) -> dict[str, float | None]:
    """Where the labels and the policy's most probable valid action depart from the
    policy's prior (its greedy node; a residual policy's base): what a learner must get
    right to beat its prior, which agreement alone hides when most labels are the prior's.

    Returns:
        ``label_departs`` (share of labels that are not the prior's node),
        ``learner_departs`` (share of decisions where the policy's choice is not),
        ``departure_precision`` (of the policy's departures, the share that take the label;
        None without any) and ``departure_recall`` (of the labels' departures, the share
        the policy takes; None without any); nothing for a policy without a prior.
    """
    import torch

    extractor = _actor_extractor(policy)
    if getattr(extractor, "prior_temperature", None) is None or not len(labels):
        return {}
    with torch.no_grad():
        prior = extractor.prior_logits(
            {"node_features": torch.as_tensor(observations["node_features"])}).numpy()
    prior = np.where(masks, prior, -np.inf).argmax(1)
    return departure_figures(_probabilities(policy, observations, masks).argmax(1), prior,
                             labels)


def departure_figures(choices: np.ndarray, prior: np.ndarray,
                      labels: np.ndarray) -> dict[str, float | None]:
    """:func:`departures`' figures from (n,) chosen, prior and label nodes (n > 0)."""
    label_departs, learner_departs = labels != prior, choices != prior
    hit = choices == labels
    return {"label_departs": float(label_departs.mean()),
            "learner_departs": float(learner_departs.mean()),
            "departure_precision": (float(hit[learner_departs].mean())
                                    if learner_departs.any() else None),
            "departure_recall": (float(hit[label_departs].mean())
                                 if label_departs.any() else None)}


def _actor_extractor(policy):
    """The features extractor the policy's actor reads (its own, or the shared one)."""
    return getattr(policy, "pi_features_extractor", None) or policy.features_extractor


def clone(policy, observations: dict[str, np.ndarray], masks: np.ndarray,
          actions: np.ndarray, config: ImitationConfig, seed: int = 0, *,
          dagger: bool = False) -> dict[str, Any]:
    """Fits the policy's actor to the expert actions (masked cross-entropy, Adam).

    Args:
        policy: The policy whose actor (not its critic) is fitted, from its current weights.
        observations, masks, actions: The labelled decisions.
        config: Epochs, batch size and learning rate.
        seed: Seed of the minibatches' order.
        dagger: Set by :func:`warm_start` for its refits. A config with
            ``dagger_iterations`` is refused otherwise: those rounds need the env, so a
            caller of :func:`collect_expert_decisions` and this function alone would
            silently clone only; call :func:`warm_start`.

    Returns:
        The final epoch's mean loss and the share of decisions whose most likely valid
        action is the expert's.

    Raises:
        ValueError: ``config.dagger_iterations`` without ``dagger``.
    """
    import torch

    if config.dagger_iterations and not dagger:
        raise ValueError("imitation.dagger_iterations needs the DAgger rounds: call "
                         "mjexplore.learning.imitation.warm_start(policy, env_config, "
                         "imitation, seed), not collect_expert_decisions and clone")

    rng = np.random.default_rng(seed)
    params = [p for name, p in policy.named_parameters() if "value_net" not in name and
              "vf_features_extractor" not in name and "critic" not in name]
    optimizer = torch.optim.Adam(params, lr=config.learning_rate)
    n = len(actions)
    policy.set_training_mode(True)
    loss_sum = agree = 0.0
    for _ in range(config.epochs):
        loss_sum = agree = 0.0
        order = rng.permutation(n)
        for start in range(0, n, config.batch_size):
            idx = order[start:start + config.batch_size]
            obs = {k: torch.as_tensor(v[idx], device=policy.device)
                   for k, v in observations.items()}
            dist = policy.get_distribution(obs, action_masks=masks[idx])
            target = torch.as_tensor(actions[idx], device=policy.device)
            loss = (-dist.log_prob(target).mean() if config.loss == "cross_entropy" else
                    margin_loss(dist.distribution.logits, masks[idx], target, config.margin))
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, 0.5)
            optimizer.step()
            loss_sum += float(loss.detach()) * len(idx)
            agree += float((dist.distribution.probs.argmax(-1) == target).sum())
    policy.set_training_mode(False)
    return {"loss": loss_sum / max(n, 1), "agreement": agree / max(n, 1)}


def margin_loss(logits, masks: np.ndarray, target, margin: float):
    """Mean hinge ``max(0, margin - (logit of the label - best other valid logit))``.

    Args:
        logits: (n, A) action logits (torch).
        masks: (n, A) bool, the valid actions.
        target: (n,) the labels (torch, int64).
        margin: Nats by which the label should lead.

    Returns:
        The scalar loss (torch); zero where every label leads by ``margin``.
    """
    import torch

    valid = torch.as_tensor(masks, device=logits.device)
    label = logits.gather(1, target[:, None])[:, 0]
    others = valid.clone()
    others[torch.arange(len(target)), target] = False
    rival = torch.where(others, logits, torch.finfo(logits.dtype).min).max(1).values
    gap = torch.where(others.any(1), label - rival, torch.full_like(label, margin))
    return torch.relu(margin - gap).mean()


@dataclasses.dataclass
class Aggregate:
    """Labelled decisions of DAgger's rounds so far: observations stacked per key (float32),
    (n, A) bool masks, (n,) expert labels."""

    observations: dict[str, np.ndarray]
    masks: np.ndarray
    actions: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)

    def extended(self, observations: dict[str, np.ndarray], masks: np.ndarray,
                 actions: np.ndarray) -> Aggregate:
        """These decisions and the new ones (the new ones' keys must be this one's, or
        this one empty)."""
        if not len(actions):
            return self
        if not len(self):
            return Aggregate(observations, masks, actions)
        return Aggregate({k: np.concatenate([v, observations[k]])
                          for k, v in self.observations.items()},
                         np.concatenate([self.masks, masks]),
                         np.concatenate([self.actions, actions]))


@dataclasses.dataclass(frozen=True)
class DaggerRound:
    """One finished round of :func:`dagger_rounds`.

    Attributes:
        iteration: The round (0: the expert's episodes).
        observations, masks, labels, taken: Its new decisions (see
            :func:`collect_learner_decisions`).
        stats: Its figures (as :func:`warm_start`'s ``rounds`` entries).
    """

    iteration: int
    observations: dict[str, np.ndarray]
    masks: np.ndarray
    labels: np.ndarray
    taken: np.ndarray
    stats: dict[str, Any]


def prior_keep(policy, config: ImitationConfig) -> tuple[float, float] | None:
    """The ``keep_prior`` argument of the rounds: (``keep_prior_m``, the policy's prior's
    ``pocket_m``), or None without ``keep_prior_m``."""
    if not config.keep_prior_m:
        return None
    return config.keep_prior_m, float(getattr(_actor_extractor(policy), "prior_pocket_m", 0.0))


def dagger_rounds(policy, env_config, config: ImitationConfig, seed: int = 0,
                  rounds: int | None = None, start: int = 0,
                  aggregate: Aggregate | None = None) -> Iterator[DaggerRound]:
    """DAgger's rounds ``start`` .. ``rounds - 1`` (see the module docstring), each yielded
    once its refit is done, ``policy`` fitted in place.

    A run resumed from round ``start`` (``aggregate``: the decisions of rounds 0 ..
    ``start - 1``, ``policy``: the weights after round ``start - 1``'s refit) goes on as the
    run that never stopped: every round's episodes, learner and refit depend only on those
    (the refit itself repeats only to rounding: see :mod:`mjexplore.learning.dagger_run`).

    Args:
        policy: The policy, fitted in place.
        env_config: The training env's settings.
        config: The imitation settings.
        seed: Seed of the refits' minibatch order (round ``i``'s: ``seed + i``).
        rounds: Rounds in all (default ``1 + config.dagger_iterations``).
        start: The first round to run.
        aggregate: The earlier rounds' decisions (needed when ``start`` > 0).
    """
    rounds = 1 + config.dagger_iterations if rounds is None else rounds
    if start and (aggregate is None or not len(aggregate)):
        raise ValueError("a DAgger run resumed after round 0 needs the earlier rounds' "
                         "decisions")
    aggregate = aggregate or Aggregate({}, np.zeros((0, 0), bool), np.zeros(0, np.int64))
    keep = prior_keep(policy, config)
    for i in range(start, rounds):
        tick = time.perf_counter()
        learner = policy_learner(policy) if i else None
        observations, masks, labels, taken, stats = collect_learner_decisions(
            env_config, learner, config.episodes, config.seed + i * config.episodes,
            config.beta(i), config.dagger_sample, config.expert, config.workers, keep)
        before = stats.pop("agreement")
        if not i:  # The untrained policy on the expert's states.
            before = agreement(policy, observations, masks, labels)
        stats.update(departures(policy, observations, masks, labels))
        rollout_s = time.perf_counter() - tick
        aggregate = aggregate.extended(observations, masks, labels)
        tick = time.perf_counter()
        fit = clone(policy, aggregate.observations, aggregate.masks, aggregate.actions,
                    config, seed=seed + i, dagger=True)
        stats = {"iteration": i, "beta": config.beta(i), **stats, "agreement_before": before,
                 "aggregate": len(aggregate), "fit_loss": fit["loss"],
                 "fit_agreement": fit["agreement"], "rollout_s": round(rollout_s, 1),
                 "fit_s": round(time.perf_counter() - tick, 1)}
        log.info("imitation round %d (beta %.3g): %d new decisions, learner agreed on %s "
                 "before the refit, %d aggregated, fit agreement %.3f", i, config.beta(i),
                 stats["decisions"], before, len(aggregate), fit["agreement"])
        yield DaggerRound(i, observations, masks, labels, taken, stats)


def warm_start(policy, env_config, config: ImitationConfig, seed: int = 0) -> dict[str, Any]:
    """The warm start of ``config``: plain cloning of the expert's episodes, then
    ``config.dagger_iterations`` DAgger rounds (see the module docstring), in this process.

    Args:
        policy: The (fresh) policy, fitted in place.
        env_config: The training env's settings (layouts, dynamics, observation).
        config: The imitation settings.
        seed: Seed of the minibatches' order (round ``i``'s refit: ``seed + i``).

    Returns:
        Without DAgger rounds, plain cloning's figures (the expert's decisions, episodes,
        explored, mean exploration time; the fit's loss and agreement), bit for bit those of
        :func:`collect_expert_decisions` then :func:`clone`. With them: ``decisions`` and
        ``episodes`` over all rounds, the last refit's ``loss`` and ``agreement`` (on the
        aggregate), ``observation_mib`` (the aggregate's observations), ``wall_s``, and
        ``rounds``: per round its ``beta``, new ``decisions``, ``episodes``, ``explored``,
        ``mean_exploration_time_s`` (its rollouts, simulated seconds; the learner's own from
        round 1 when ``beta0`` is 0), ``agreement_before`` (the learner's most probable
        valid action against the expert's label on the round's new states, before the
        refit: DAgger's signal; round 0: the untrained policy on the expert's states),
        ``expert_share``, ``aggregate`` decisions, the refit's ``fit_loss`` and
        ``fit_agreement``, and the wall seconds of its ``rollout_s`` and ``fit_s``.
    """
    start = time.perf_counter()
    if not config.dagger_iterations:
        observations, masks, actions, stats = collect_expert_decisions(
            env_config, config.episodes, config.seed, config.expert, config.workers,
            prior_keep(policy, config))
        return {**stats, **clone(policy, observations, masks, actions, config, seed=seed)}
    rounds, mib = [], 0.0
    for done in dagger_rounds(policy, env_config, config, seed):
        rounds.append(done.stats)
        mib += sum(v.nbytes for v in done.observations.values()) / 2**20
    return {"decisions": rounds[-1]["aggregate"],
            "episodes": sum(r["episodes"] for r in rounds),
            "loss": rounds[-1]["fit_loss"], "agreement": rounds[-1]["fit_agreement"],
            "observation_mib": round(mib, 1), "wall_s": round(time.perf_counter() - start, 1),
            "rounds": rounds}
