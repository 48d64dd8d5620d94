"""Shipped policies as models: one folder each under ``models/`` (RL Zoo style).

A model folder holds ``policy.safetensors`` (the weights, with the resolved training config
in their metadata), ``config.yaml`` (that config as YAML; the recipe it came from is
``training/NAME.yaml``, named in the card) and ``README.md`` (the model card: what it
is, data and budget, figures, sha256). A learned explorer takes ``--policy NAME`` (a model
here) or ``--policy PATH`` (a weights file, or a folder holding ``policy.safetensors``, such
as a training run's output).
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from mjexplore.errors import UserInputError
from mjexplore.io.provenance import REPO

MODELS_DIR = REPO / "models"
WEIGHTS_NAME = "policy.safetensors"
# The model each learned explorer runs unless told otherwise: the best of its kind.
DEFAULT_MODEL = {"gvn": "gvn_v3", "cnn": "cnn_paper"}
# Labels of the runs made before models had names of their own (the report's data): the
# paper's recipe ran as plain "gvn" and "cnn".
LEGACY_LABELS = {"gvn_paper": "gvn", "gvn_paper_naive": "gvn_naive",
                 "gvn_paper_none": "gvn_none", "cnn_paper": "cnn"}


@dataclasses.dataclass(frozen=True)
class Model:
    """A shipped model.

    Attributes:
        name: The folder's name, what ``--policy`` takes.
        kind: The policy kind ('gvn' or 'cnn').
        masking: The masking it was trained with ('iam', 'naive' or 'none'); a 'none' model
            runs without the mask, the others with it.
        summary: The model card's first sentence.
    """

    name: str
    kind: str
    masking: str
    summary: str

    @property
    def weights(self) -> Path:
        return MODELS_DIR / self.name / WEIGHTS_NAME


def weights_metadata(path: str | os.PathLike) -> dict[str, str]:
    """The safetensors metadata of a weights file, read from its header alone."""
    from safetensors import safe_open

    try:
        with safe_open(str(path), "pt") as f:
            return f.metadata() or {}
    except (OSError, ValueError, RuntimeError) as exc:
        raise UserInputError(f"{str(path)!r} is not a readable safetensors file ({exc}).") \
            from None


def trained_masking(provenance: dict) -> str:
    """The masking a policy was trained with, from its weights' decoded provenance ('iam'
    when it does not say)."""
    return provenance.get("config", {}).get("policy", {}).get("masking", "iam")


def _summary(card: Path) -> str:
    if not card.is_file():
        return ""
    text = " ".join(line.strip() for line in card.read_text().splitlines()
                    if line.strip() and not line.startswith("#"))
    return text.split(". ")[0].rstrip(".") + "." if text else ""


def shipped_models() -> dict[str, Model]:
    """The models under ``models/``, by name."""
    models = {}
    for folder in sorted(MODELS_DIR.glob(f"*/{WEIGHTS_NAME}")):
        meta = weights_metadata(folder)
        name = folder.parent.name
        models[name] = Model(name, meta.get("kind", "?"),
                             trained_masking(json.loads(meta.get("provenance", "{}"))),
                             _summary(folder.parent / "README.md"))
    return models


def resolve_policy(policy: str | os.PathLike | None, kind: str) -> tuple[str, Path]:
    """(name, weights file) of ``policy``: a model name, a weights file, a folder holding
    ``policy.safetensors``, or None for ``kind``'s default model. A file's name is its path.

    Raises:
        UserInputError: neither a model nor a file; the message lists the models.
    """
    if policy is None:
        policy = DEFAULT_MODEL[kind]
    text = str(policy)
    if (MODELS_DIR / text / WEIGHTS_NAME).is_file() and os.sep not in text:
        return text, MODELS_DIR / text / WEIGHTS_NAME
    path = Path(policy)
    if path.is_dir() and (path / WEIGHTS_NAME).is_file():
        path = path / WEIGHTS_NAME
    if path.is_file():
        return str(path), path
    names = ", ".join(n for n, m in shipped_models().items() if m.kind == kind)
    raise UserInputError(f"--policy {text!r} is neither a shipped {kind} model ({names}) nor "
                         "a weights file: give one of those names, or the path of a "
                         "policy.safetensors ('mjexplore policies' lists the models).")


def run_label(kind: str, name: str, masked: bool, trained: str) -> str:
    """The label of runs of ``kind``'s explorer with the policy ``name`` (a model or a
    path), run with the mask or without it, that was trained with masking ``trained``.

    Shipped models are labelled by their name (the paper's recipe by its earlier labels,
    ``gvn`` and ``cnn``), with ``_unmasked`` when a policy trained with a mask runs
    without; a user's file by ``kind:path``.
    """
    if name not in shipped_models():
        return f"{kind}:{name}" + ("" if masked or trained == "none" else ":unmasked")
    label = LEGACY_LABELS.get(name, name)
    return label + ("_unmasked" if not masked and trained != "none" else "")
