"""tools/research/iou_sensitivity.py: a map built at the true poses and moved as a whole loses IoU,
and more the farther it is moved."""

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_a_rigidly_moved_map_loses_iou():
    out = subprocess.run([sys.executable, "-m", "tools.research.iou_sensitivity", "--scene",
                          "train_loop", "--max-time", "100"], cwd=REPO, capture_output=True,
                         text=True, check=True, timeout=300)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    # Mapped again unmoved, the scans give the episode's own map.
    assert abs(result["iou"] - result["episode_iou"]) < 1e-3 and result["scans"] > 400
    assert result["iou_drop_shift_5cm"] > max(result["iou_drop_shift_1cm"], 0.05)
    assert result["iou_drop_turn_0.5deg"] > max(result["iou_drop_turn_0.05deg"], 0.05)
