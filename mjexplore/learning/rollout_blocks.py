"""PPO minibatches of consecutive decisions: a rollout buffer for sb3-contrib's MaskablePPO.

A GVN observation holds the current TER and the last E TERs of its episode, so decision t's
TER comes back in the memory of decisions t+1 .. t+E. The GVN encodes each distinct TER of a
minibatch once (:func:`mjexplore.policies.gvn.distinct_graphs`): a minibatch of B decisions
drawn one by one from the rollout holds about B (E + 1) distinct TERs, and one made of runs
of L consecutive decisions of one env about B (1 + E / L). With E = 10 and L = 32 that is
about a third of the graphs to encode, for the same loss on the same number of decisions
(recurrent PPO samples sequences the same way). Each update draws the runs afresh.
"""

from __future__ import annotations

from collections.abc import Generator

import numpy as np
from sb3_contrib.common.maskable.buffers import (
    MaskableDictRolloutBuffer,
    MaskableDictRolloutBufferSamples,
)


def _check_block(block: int, num_steps: int) -> None:
    if block < 1 or num_steps % block:
        raise ValueError(f"a block of {block} decisions must divide the {num_steps} steps "
                         "per env of a rollout")


def block_permutation(num_envs: int, num_steps: int, block: int,
                      rng: np.random.Generator) -> np.ndarray:
    """Every flat rollout index (env * num_steps + step) once, in runs of ``block``
    consecutive steps of one env, the runs in random order.

    Raises:
        ValueError: ``block`` does not divide ``num_steps``.
    """
    _check_block(block, num_steps)
    starts = rng.permutation(num_envs * num_steps // block) * block
    return (starts[:, None] + np.arange(block)).reshape(-1)


class BlockDictRolloutBuffer(MaskableDictRolloutBuffer):
    """:class:`MaskableDictRolloutBuffer` whose minibatches are runs of ``block``
    consecutive decisions of one env (see the module docstring).

    Args:
        block: Decisions per run; divides the rollout's steps per env and the minibatch size.
        seed: Seed of the run order.
        *args, **kwargs: As for :class:`MaskableDictRolloutBuffer`.
    """

    def __init__(self, *args, block: int, seed: int, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        _check_block(block, self.buffer_size)
        self.block = block
        self.rng = np.random.default_rng(seed)

    # As sb3-contrib's own get() (ignored there too): its samples are not SB3's type.
    def get(self, batch_size: int | None = None  # type: ignore[override]
            ) -> Generator[MaskableDictRolloutBufferSamples, None, None]:
        """Minibatches of ``batch_size`` decisions (all of them when None), runs of
        ``block`` consecutive ones.

        Raises:
            ValueError: ``block`` does not divide ``batch_size``.
        """
        total = self.buffer_size * self.n_envs
        batch_size = batch_size or total
        if batch_size % self.block:
            raise ValueError(f"a block of {self.block} decisions must divide the minibatch "
                             f"size {batch_size}")
        assert self.full, "the rollout is not complete"
        if not self.generator_ready:
            # swap_and_flatten gives the flat index env * buffer_size + step.
            for key, obs in self.observations.items():
                self.observations[key] = self.swap_and_flatten(obs)
            for name in ("actions", "values", "log_probs", "advantages", "returns",
                         "action_masks"):
                self.__dict__[name] = self.swap_and_flatten(self.__dict__[name])
            self.generator_ready = True
        indices = block_permutation(self.n_envs, self.buffer_size, self.block, self.rng)
        for start in range(0, total, batch_size):
            yield self._get_samples(indices[start:start + batch_size])
