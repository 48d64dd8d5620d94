"""Paired statistics against a baseline, and the report's table against the best classic."""

import numpy as np
import pytest

from mjexplore.eval.report_sections import paired_table
from mjexplore.eval.stats import compare_paired


def test_paired_ratios_interval_and_sign_test():
    c = compare_paired([90.0, 80.0, 100.0, 70.0], [100.0, 100.0, 100.0, 100.0])
    assert np.allclose(c.ratios, [0.9, 0.8, 1.0, 0.7]) and c.mean == pytest.approx(0.85)
    assert c.low <= c.mean <= c.high and 0.7 <= c.low and c.high <= 1.0
    assert (c.faster, c.slower) == (3, 0) and c.p_value == pytest.approx(0.25)  # Tie left out.
    assert compare_paired([90.0, 80.0], [100.0, 100.0]).low == \
        compare_paired([90.0, 80.0], [100.0, 100.0]).low  # Seeded: the same every run.
    with pytest.raises(ValueError):
        compare_paired([1.0], [1.0, 2.0])


def _runs(times):
    return [{"seed": s, "metrics": {"exploration_time_s": t}} for s, t in enumerate(times)]


def test_the_learned_explorer_is_paired_with_each_scenes_best_classic():
    groups = {"a": {"nearest": _runs([100, 110]), "potential": _runs([90, 95]),
                    "oracle": _runs([10, 10]), "gvn_v3": _runs([81, 95])},
              "b": {"nearest": _runs([50, 50]), "gvn_v3": _runs([60, 40])}}
    table = paired_table(groups, "gvn_v3")
    lines = table.splitlines()
    assert "| a | potential (of 2) | 2 | 0.950 |" in lines[2]  # Not the oracle's bound.
    assert "| b | nearest (of 1) | 2 | 1.000 |" in lines[3] and "1/1" in lines[3]
    assert lines[4].startswith("| all | each scene's best | 4 |")
    assert paired_table({"a": {"gvn_v3": _runs([1])}}, "gvn_v3") is None
