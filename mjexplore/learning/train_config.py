"""The config of a training run: :class:`TrainConfig` and its sections (PPO, policy network,
held-out evaluation), read from a training YAML by :func:`load_train_config`, and the
settings a resumed run may change (:data:`RESUMABLE_CHANGES`)."""

from __future__ import annotations

import copy
import dataclasses
import logging
from pathlib import Path
from typing import Any

from mjexplore.config import load_yaml_config
from mjexplore.envs.exploration import (
    TEST_SEED_BASE,
    EnvConfig,
    ProceduralScenes,
    heldout_scenes,
)
from mjexplore.envs.observation import POSED
from mjexplore.episode import EpisodeConfig
from mjexplore.learning.imitation import ImitationConfig

log = logging.getLogger(__name__)

# Settings a resumed run may change (dotted: inside a section): how long it trains, on how
# many envs and threads, the checkpoints it keeps, and whether updates overlap collection.
RESUMABLE_CHANGES = ("total_steps", "n_envs", "torch_threads", "update_threads",
                     "keep_checkpoints", "ppo.overlap")

@dataclasses.dataclass(frozen=True, kw_only=True)
class PpoConfig:
    """MaskablePPO hyperparameters (SB3 names; steps are decisions per env).

    ``overlap`` runs each update in a thread while the next rollout is collected with the
    policy as it was before that update (:mod:`mjexplore.learning.overlap_ppo`): the env
    workers no longer wait for the update, at the cost of a one-update policy lag (PPO's
    ratio and clipping use the stored log-probabilities of the policy that collected, as
    APPO does; the loss is MaskablePPO's own). The update thread runs ``update_threads``
    torch threads (None: ``torch_threads``); checkpoints and evaluations still see the
    weights after a completed update, with every decision they count trained on. Checkpoints
    are therefore the same in both modes, and a resumed run may switch ``overlap``.

    ``prior_kl`` (GVN with a prior) puts ``prior_kl * KL(policy || prior)`` in the loss in
    place of the entropy bonus (:class:`~mjexplore.policies.sb3.GvnPolicy`'s
    ``entropy_reference: prior``; ``train/entropy_loss`` then logs the mean KL, nats):
    a residual policy departs from its prior only where the advantages keep asking for it,
    not by the drift of noisy updates. ``target_kl`` stops an update's epochs once the
    approximate KL from the collecting policy passes 1.5 times it (SB3's ``target_kl``).
    """

    n_steps: int = 256
    batch_size: int = 128
    n_epochs: int = 4
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    # Minibatches of runs of this many consecutive decisions of one env, not single ones
    # (mjexplore/learning/rollout_blocks.py: the GVN then encodes about a third of the TERs).
    minibatch_block: int = 1
    overlap: bool = False
    prior_kl: float = 0.0
    target_kl: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.overlap, bool):
            raise ValueError("ppo.overlap must be true or false")
        if self.prior_kl < 0 or (self.prior_kl and self.ent_coef):
            raise ValueError("ppo.prior_kl must be >= 0, and with it ppo.ent_coef 0 (the KL "
                             "to the prior takes the entropy bonus's place)")
        if self.target_kl is not None and not self.target_kl > 0:
            raise ValueError("ppo.target_kl must be > 0 (or absent: no early stop)")
        for name in ("n_steps", "batch_size", "n_epochs", "minibatch_block"):
            if getattr(self, name) < 1:
                raise ValueError(f"ppo.{name} must be >= 1")
        if self.n_steps % self.minibatch_block or self.batch_size % self.minibatch_block:
            raise ValueError(f"ppo.minibatch_block ({self.minibatch_block}) must divide "
                             f"ppo.n_steps ({self.n_steps}) and ppo.batch_size "
                             f"({self.batch_size})")
        if not 0 < self.gamma <= 1 or not 0 <= self.gae_lambda <= 1:
            raise ValueError("ppo.gamma must be in (0, 1] and ppo.gae_lambda in [0, 1]")
        if self.learning_rate <= 0:
            raise ValueError("ppo.learning_rate must be positive")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PolicyConfig:
    """Policy network and masking (see :mod:`mjexplore.policies.sb3`; ``features`` is the
    CNN baseline's encoder width, the others are GVN sizes). ``share_features_extractor``
    False gives the critic an encoder of its own: with one shared encoder the value loss's
    gradient, about 500 times the policy gradient's at the start, trains it for the critic.
    ``prior_temperature`` (metres per nat, GVN with v2 or v3 observations) adds the
    nearest-node rule's logits to the actor's: the network learns a residual on
    nearest-frontier. ``prior_pocket_m`` (v3) makes that rule count each node this many
    metres farther per unit of its pocket probability (the predictor's). ``residual_scale``
    multiplies the network's logits before the prior's are added (nats per unit of its
    output)."""

    masking: str = "iam"
    share_features_extractor: bool = True
    features: int = 256
    hidden: int = 64
    gcn_layers: int = 3
    tcn_kernel: int = 3
    tcn_dilations: tuple[int, ...] = (1, 2, 4)
    prior_temperature: float | None = None
    prior_pocket_m: float = 0.0
    residual_scale: float = 1.0

    def __post_init__(self) -> None:
        from mjexplore.policies.sb3 import MASKING_MODES

        if self.masking not in MASKING_MODES:
            raise ValueError(f"policy.masking must be one of {', '.join(MASKING_MODES)}")
        if self.hidden < 1 or self.gcn_layers < 1 or self.tcn_kernel < 1:
            raise ValueError("policy sizes must be >= 1")
        if self.prior_temperature is not None and not self.prior_temperature > 0:
            raise ValueError("policy.prior_temperature must be > 0 (metres per nat) or null")
        if self.prior_pocket_m < 0 or (self.prior_pocket_m and self.prior_temperature is None):
            raise ValueError("policy.prior_pocket_m must be >= 0 and needs prior_temperature")
        if not self.residual_scale > 0:
            raise ValueError("policy.residual_scale must be > 0 (nats per unit of the "
                             "network's output)")


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvalConfig:
    """Periodic evaluation on held-out scenes (deterministic policy, in as many processes as
    the run has envs); the best evaluated weights are kept (model selection).

    Select on held-out generated layouts (``procedural``), never on a scene results are
    reported on (the paper's evaluation scenes, the lobby, Explore-Bench, ARiADNE): a
    warning says so when ``scenes`` names one.

    Attributes:
        scenes: Held-out scenes (never trained on), used when ``procedural`` is None.
        procedural: If set, ``layouts`` generated layouts of these families and sizes whose
            generator seeds training never draws (see :func:`heldout_scenes`), the same
            at every evaluation.
        layouts: How many held-out layouts.
        every: Evaluate every this many decision steps (0: never).
        episode: Episode settings of the evaluation (full physics by default).
        seed: Seed of the evaluation episodes and of the held-out layouts' draw.
    """

    scenes: tuple[str, ...] = ("loop_with_corridor",)
    procedural: ProceduralScenes | None = None
    layouts: int = 8
    every: int = 4096
    episode: EpisodeConfig = dataclasses.field(default_factory=EpisodeConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        if self.layouts < 1:
            raise ValueError("eval.layouts must be >= 1")
        if self.procedural is None and self.every:
            from mjexplore.scenes.canonical import canonical_names

            reported = set(canonical_names("eval")) | set(canonical_names("real"))
            named = [s for s in self.scenes if s in reported or any(
                t in str(s).lower() for t in ("explore_bench", "ariadne"))]
            if named:
                log.warning("model selection on %s, where results are reported, biases them: "
                            "set eval.procedural to select on held-out generated layouts",
                            ", ".join(named))

    def scene_list(self) -> tuple[str, ...]:
        """The scenes evaluated: ``scenes``, or the held-out layouts' folders."""
        if self.procedural is None:
            return self.scenes
        return heldout_scenes(self.procedural, self.layouts, self.seed)

    def unseen_scenes(self, count: int) -> tuple[str, ...]:
        """``count`` generated layouts after the model-selection ones (the same draw, seen
        by neither training nor model selection): where a selected policy is tested.

        Raises:
            ValueError: No ``procedural`` layouts to draw them from.
        """
        if self.procedural is None:
            raise ValueError("unseen layouts need eval.procedural")
        return heldout_scenes(self.procedural, self.layouts + count, self.seed)[self.layouts:]

    def test_scenes(self, count: int) -> tuple[str, ...]:
        """``count`` generated layouts for final figures, with generator seeds from
        :data:`~mjexplore.envs.exploration.TEST_SEED_BASE`: neither training, model selection
        nor any tuning on :meth:`scene_list` or :meth:`unseen_scenes` draws them.

        Raises:
            ValueError: No ``procedural`` layouts to draw them from.
        """
        if self.procedural is None:
            raise ValueError("test layouts need eval.procedural")
        return heldout_scenes(self.procedural, count, self.seed, base=TEST_SEED_BASE)


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """A training run.

    Attributes:
        kind: Policy kind: 'gvn' (needs ``env.decisions: ter``) or 'cnn' (``grid``).
        env: Training env settings.
        policy: Network and masking.
        ppo: PPO hyperparameters.
        eval: Held-out evaluation.
        imitation: Behaviour cloning of the ground-truth oracle before PPO (a fresh run's
            warm start; see :mod:`mjexplore.learning.imitation`).
        total_steps: Decision steps to train for (all envs together).
        n_envs: Environments, each in its own worker process when more than one.
        checkpoint_every: Checkpoint after at least this many steps since the last one.
        keep_checkpoints: Keep only this many newest checkpoints (each 3.5 MB for the v3
            GVN, one per update by default: 7 GB over 10^6 decisions); 0 keeps all.
        seed: Seed of torch, numpy and the envs.
        torch_threads: torch intra-op threads in the learner (1 is fastest on 2 cores).
        update_threads: torch intra-op threads during PPO updates, while the env workers
            wait (None: ``torch_threads``).
    """

    kind: str = "gvn"
    env: EnvConfig = dataclasses.field(
        default_factory=lambda: EnvConfig(scenes=("train_loop",)))
    policy: PolicyConfig = dataclasses.field(default_factory=PolicyConfig)
    ppo: PpoConfig = dataclasses.field(default_factory=PpoConfig)
    eval: EvalConfig = dataclasses.field(default_factory=EvalConfig)
    imitation: ImitationConfig = dataclasses.field(default_factory=ImitationConfig)
    total_steps: int = 20000
    n_envs: int = 2
    checkpoint_every: int = 512
    keep_checkpoints: int = 0
    seed: int = 0
    torch_threads: int = 1
    update_threads: int | None = None

    def __post_init__(self) -> None:
        from mjexplore.policies.registry import KINDS

        if self.kind not in KINDS:
            raise ValueError(f"kind {self.kind!r} is unknown: use one of {', '.join(KINDS)}")
        wanted = "ter" if self.kind == "gvn" else "grid"
        if self.env.decisions != wanted:
            raise ValueError(f"kind {self.kind!r} needs env.decisions: {wanted}")
        if self.kind == "cnn" and self.policy.masking != "iam":
            raise ValueError("the cnn kind supports policy.masking: iam only")
        if self.policy.prior_temperature is not None and (
                self.kind != "gvn" or self.env.observation.features not in POSED):
            raise ValueError("policy.prior_temperature needs kind gvn with "
                             "env.observation.features: v2 or v3 (the path feature)")
        if self.policy.prior_pocket_m and self.env.observation.features != "v3":
            raise ValueError("policy.prior_pocket_m needs env.observation.features: v3 (the "
                             "pocket feature)")
        if (self.policy.masking == "none") != (self.env.valid_actions == "all_nodes"):
            raise ValueError("policy.masking: none (training without a mask) goes with "
                             "env.valid_actions: all_nodes, and all_nodes only with none")
        if self.total_steps < 1 or self.n_envs < 1 or self.checkpoint_every < 1:
            raise ValueError("total_steps, n_envs and checkpoint_every must be >= 1")
        if self.keep_checkpoints < 0:
            raise ValueError("keep_checkpoints must be >= 0 (0 keeps all)")
        if self.torch_threads < 1 or (self.update_threads or 1) < 1:
            raise ValueError("torch_threads and update_threads must be >= 1")
        if self.ppo.minibatch_block > 1 and self.kind != "gvn":
            raise ValueError("ppo.minibatch_block > 1 is for kind gvn (its TER memory)")
        if self.ppo.prior_kl and self.policy.prior_temperature is None:
            raise ValueError("ppo.prior_kl needs policy.prior_temperature (the prior it pulls "
                             "toward)")


def load_train_config(path: str | Path, total_steps: int | None = None,
                      n_envs: int | None = None, seed: int | None = None) -> TrainConfig:
    """Reads a training YAML (see training/gvn.yaml); ``total_steps``, ``n_envs`` and
    ``seed``, when given, replace the file's values."""
    config = load_yaml_config(TrainConfig, path)
    overrides: dict[str, Any] = {
        k: v for k, v in (("total_steps", total_steps), ("n_envs", n_envs), ("seed", seed))
        if v is not None}
    return dataclasses.replace(config, **overrides) if overrides else config


def fixed_settings(config: dict[str, Any]) -> dict[str, Any]:
    """A config dict without the settings a resumed run may change (``RESUMABLE_CHANGES``)."""
    out = copy.deepcopy(config)
    for name in RESUMABLE_CHANGES:
        *sections, key = name.split(".")
        part = out
        for section in sections:
            part = part.get(section) or {}
        part.pop(key, None)
    return out
