"""Paired statistics of one method against another over the same episodes (scene, seed).

Exploration times of two methods on the same scene and seed are paired: the per-seed ratio
``mine / theirs`` (below 1: faster), their mean, a bootstrap 95 % interval of that mean
(the seeds resampled with replacement, a seeded generator: the same interval on every run)
and a two-sided sign test (how many seeds were faster, ties left out).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy.stats import binomtest

BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0


@dataclasses.dataclass(frozen=True)
class PairedComparison:
    """Per-seed ratios of one method's values to another's and what they support.

    Attributes:
        ratios: (n,) ``mine / theirs`` per paired episode.
        mean: Mean of the ratios.
        low, high: Bootstrap 95 % interval of the mean.
        faster, slower: Episodes with a ratio below and above 1.
        p_value: Two-sided sign test of ``faster`` against ``slower`` (1 with no untied
            pair).
    """

    ratios: np.ndarray
    mean: float
    low: float
    high: float
    faster: int
    slower: int
    p_value: float


def compare_paired(mine: Sequence[float], theirs: Sequence[float]) -> PairedComparison:
    """Paired statistics of ``mine`` against ``theirs`` (the same episodes, in order).

    Raises:
        ValueError: the two differ in length, are empty, or ``theirs`` holds a value <= 0.
    """
    a, b = np.asarray(mine, float), np.asarray(theirs, float)
    if a.shape != b.shape or a.size == 0 or (b <= 0).any():
        raise ValueError("paired values need two equally long, non-empty sequences with "
                         "positive values to divide by")
    ratios = a / b
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    means = ratios[rng.integers(0, len(ratios), (BOOTSTRAP_RESAMPLES, len(ratios)))].mean(1)
    low, high = np.percentile(means, [2.5, 97.5])
    faster, slower = int((ratios < 1).sum()), int((ratios > 1).sum())
    p = binomtest(faster, faster + slower).pvalue if faster + slower else 1.0
    return PairedComparison(ratios, float(ratios.mean()), float(low), float(high), faster,
                            slower, float(p))
