"""The report's map predictor section: one row per training seed and per non-learned
predictor, from DATA/predictor/quality.json; what it says follows the figures."""

from __future__ import annotations

import json

import pytest

from mjexplore.errors import UserInputError
from mjexplore.eval.predictor_report import predictor_section


def _quality(bce, accuracy):
    return {"cells": 1000, "bce": bce, "accuracy": accuracy, "iou_free": 0.5, "ece": 0.05,
            "free_share": 0.47}


def _write(tmp_path, seed1_bce):
    data = {"revision": "abcdef0123", "held_maps": 975, "held_episodes": 60,
            "models": {"seed0": {"weights_sha256": "268e003c" * 8, "fitted_at": "e545d49xx",
                                 **_quality(0.53, 0.71)},
                       "seed1": {"weights_sha256": "5942f135" * 8, "fitted_at": "9e74436xx",
                                 **_quality(seed1_bce, 0.70)}},
            "baselines": {"inpainting": _quality(1.9, 0.47),
                          "unknown_as_free": _quality(4.9, 0.47)},
            "within_m": {"1": {"seed0": {**_quality(0.3, 0.91), "cells": 100},
                               "inpainting": {**_quality(0.9, 0.62), "cells": 100}}}}
    (tmp_path / "predictor").mkdir(exist_ok=True)
    (tmp_path / "predictor" / "quality.json").write_text(json.dumps(data))


def test_the_section_lists_each_seed_and_baseline_and_says_whether_all_beat_them(tmp_path):
    assert predictor_section(tmp_path) == []  # Nothing measured: no section.
    _write(tmp_path, 0.52)
    text = "\n".join(predictor_section(tmp_path))
    assert "learned, seed0 (weights `268e003c`, fitted at `e545d49`) | 0.530 | 0.710" in text
    assert "| inpainting (cv2.inpaint) | 1.900 | 0.470" in text
    assert "revision `abcdef0`" in text and "975 partial maps of 60 held-out" in text
    assert "bce 0.520-0.530" in text
    assert "Every seed beats each non-learned predictor" in text
    assert "| learned, seed0 | 0.910 (10%) |" in text  # 100 of the 1000 unknown cells.
    assert "| inpainting (cv2.inpaint) | 0.620 (10%) |" in text
    assert "confident cells" not in text  # Measured before their scores existed.
    _write(tmp_path, 2.5)  # Seed 1 worse than inpainting in cross-entropy.
    assert "Not every seed beats" in "\n".join(predictor_section(tmp_path))


def test_a_damaged_file_is_refused_with_how_to_fix_it(tmp_path):
    (tmp_path / "predictor").mkdir()
    (tmp_path / "predictor" / "quality.json").write_text('{"models": {}}')
    with pytest.raises(UserInputError, match="predictor_quality.py"):
        predictor_section(tmp_path)


def test_the_confident_cells_table_gives_each_seed_in_every_band(tmp_path):
    _write(tmp_path, 0.52)
    path = tmp_path / "predictor" / "quality.json"
    data = json.loads(path.read_text())
    for band in [data["models"], data["baselines"], *data["within_m"].values()]:
        for q in band.values():
            q.update(confident_share=0.25, confident_accuracy=0.9)
    data["within_m"]["1"]["seed0"].update(confident_share=0.0, confident_accuracy=None)
    path.write_text(json.dumps(data))
    text = "\n".join(predictor_section(tmp_path))
    assert "| predictor | all unknown | within 1 m |" in text
    assert "| learned, seed0 | 0.900 (25%) | - (0%) |" in text
    assert "learned, seed1 | 0.900" not in text  # Not scored within 1 m.
