"""The report's section on the map predictor: the quality of each training seed's predictor
and of the three non-learned predictors on one held-out set, measured at one revision by
``tools/predictor_quality.py`` into ``DATA/predictor/quality.json``."""

from __future__ import annotations

import json
from pathlib import Path

from mjexplore.errors import UserInputError
from mjexplore.eval.sweep import markdown_table

QUALITY_FILE = Path("predictor") / "quality.json"
MEASURES = ("bce", "accuracy", "iou_free", "ece")
BASELINE_NAMES = {"unknown_as_free": "unknown as free",
                  "unknown_as_occupied": "unknown as occupied",
                  "inpainting": "inpainting (cv2.inpaint)"}


def _row(name: str, q: dict) -> list[str]:
    return [name] + [f"{q[m]:.3f}" for m in MEASURES]


def _confident(q: dict) -> str:
    """The accuracy on the confident cells and their share, or a dash when there are
    none."""
    if q["confident_accuracy"] is None:
        return "- (0%)"
    return f"{q['confident_accuracy']:.3f} ({q['confident_share']:.0%})"


def predictor_section(data_dir: Path) -> list[str]:
    """The section's lines ([] when ``DATA/predictor/quality.json`` is not there).

    Raises:
        UserInputError: the file is damaged.
    """
    path = data_dir / QUALITY_FILE
    if not path.is_file():
        return []
    try:
        data = json.loads(path.read_text())
        models, baselines = data["models"], data["baselines"]
        rows = [_row(f"learned, {label} (weights `{q['weights_sha256'][:8]}`, fitted at "
                     f"`{(q.get('fitted_at') or '?')[:7]}`)", q)
                for label, q in models.items()]
        rows += [_row(BASELINE_NAMES.get(name, name), q) for name, q in baselines.items()]
        beaten = all(q["bce"] < b["bce"] and q["accuracy"] > b["accuracy"]
                     for q in models.values() for b in baselines.values())
        low = {m: min(q[m] for q in models.values()) for m in MEASURES}
        high = {m: max(q[m] for q in models.values()) for m in MEASURES}
        cells, maps = next(iter(models.values()))["cells"], data["held_maps"]
        free, episodes = next(iter(models.values()))["free_share"], data["held_episodes"]
        near = data.get("within_m") or {}
        near_lines = [
            "Accuracy on the unknown cells within r of a known cell (the cells a planner on "
            "the prediction meets first), and the share of the unknown cells there:", "",
            markdown_table(["predictor"] + [f"within {r} m" for r in near], [
                [BASELINE_NAMES.get(n, f"learned, {n}")] +
                [f"{near[r][n]['accuracy']:.3f} ({near[r][n]['cells'] / cells:.0%})"
                 for r in near] for n in next(iter(near.values()))]), ""] if near else []
        scored = {"all unknown": {**models, **baselines},
                  **{f"within {r} m": near[r] for r in near}}
        sure_lines = [
            "Accuracy on the confident cells (free probability at least 0.7 or at most 0.3: "
            "those `predicted_drive` plans and drives on), and their share of the cells "
            "scored:", "",
            markdown_table(["predictor", *scored], [
                [BASELINE_NAMES.get(n, f"learned, {n}")] +
                [_confident(q[n]) for q in scored.values()] for n in models
                if all(n in q for q in scored.values())]), ""
        ] if all("confident_share" in q for band in scored.values()
                 for q in band.values()) else []
    except (KeyError, TypeError, ValueError, StopIteration) as exc:
        raise UserInputError(f"{path} is damaged ({exc!r}): measure again with "
                             "tools/predictor_quality.py.") from None
    spread = ", ".join(f"{m} {low[m]:.3f}-{high[m]:.3f}" for m in MEASURES)
    return [
        "## The map predictor: quality on held-out partial maps", "",
        "Each unknown cell's probability of being free, predicted from the partial map on "
        "0.2 m cells (docs/guide/prediction.md), against the ground truth's free share, on "
        f"the {maps:,} partial maps of {episodes} held-out episodes "
        f"({cells:,} unknown cells, {free:.0%} of them free). One row per training seed of "
        "the learned predictor, then the three non-learned predictors. BCE in nats (lower "
        "is better), accuracy and IoU of the free space at probability 0.5, calibration "
        "error (ECE, 10 bins).", "",
        "```bash",
        "python tools/predictor_quality.py --data runs/train/predictor/data --models "
        + ",".join(f"{label}=PATH" for label in models) + " --out "
        "docs/results/data/predictor/quality.json",
        "```", "",
        f"Measured at revision `{data['revision'][:7]}`.", "",
        markdown_table(["predictor", "BCE (nats)", "accuracy", "IoU of the free space",
                        "calibration error"], rows),
        "",
        f"Over the {len(models)} training seeds: {spread}. "
        + ("Every seed beats each non-learned predictor in cross-entropy and accuracy."
           if beaten else "Not every seed beats each non-learned predictor in "
                          "cross-entropy and accuracy."),
        "", *near_lines, *sure_lines]
