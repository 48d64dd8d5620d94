"""A small fixed subset of the stress sweep (tools/stress_explorers.py): no classic
explorer may end an episode before the target ratio on these layouts."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / "tools" / "stress_explorers.py"


@pytest.mark.slow
def test_classic_explorers_finish_small_layouts():
    out = subprocess.run([sys.executable, str(TOOL), "--layouts", "2", "--sizes", "small",
                          "--explorers", "nearest,explore_lite,frontier_tsp,potential,oracle",
                          "--workers", "1"], capture_output=True, text=True, check=True,
                         timeout=600)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["runs"] == 10
    assert result["premature"] == {}, result["failures"]
    assert result["reached_target"] == result["runs"]


def test_a_sweep_started_again_skips_the_runs_it_has(tmp_path):
    out = tmp_path / "stress.jsonl"
    args = [sys.executable, str(TOOL), "--layouts", "1", "--sizes", "small", "--explorers",
            "nearest", "--workers", "1", "--out", str(out)]
    first = json.loads(subprocess.run(args, capture_output=True, text=True, check=True,
                                      timeout=300).stdout.strip().splitlines()[-1])
    lines = out.read_text().splitlines()
    assert len(lines) == 1 and json.loads(lines[0])["revision"]
    second = json.loads(subprocess.run(args, capture_output=True, text=True, check=True,
                                       timeout=300).stdout.strip().splitlines()[-1])
    assert out.read_text().splitlines() == lines  # Nothing ran again...
    assert second == first  # ...and the summary still covers the run.


def test_the_time_cap_grows_with_the_layout():
    import importlib.util
    spec = importlib.util.spec_from_file_location("stress_explorers", TOOL)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    assert tool.time_cap(("maze", 12.0, 10.0, 1), 1800.0, 4.0) == 1800.0
    assert tool.time_cap(("maze", 39.4, 22.0, 1), 1800.0, 4.0) == 3470.0
