"""Shipped policies as models: one folder each under ``models/`` (RL Zoo style).

A model folder holds ``policy.safetensors`` (the weights, with the resolved training config
in their metadata), ``config.yaml`` (that config as YAML; the recipe it came from is
``training/NAME.yaml``, named in the card) and ``README.md`` (the model card: what it is,
data and budget, figures, and the weights file's sha256, which loading checks). A learned
explorer takes ``--policy NAME`` (a model here) or ``--policy PATH`` (a weights file, or a
folder holding ``policy.safetensors``, such as a training run's output).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import re
from pathlib import Path

from mjexplore.errors import UserInputError
from mjexplore.io.provenance import REPO, file_sha256

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
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(path), "pt") as f:
            return f.metadata() or {}
    except (OSError, ValueError, RuntimeError, SafetensorError) as exc:
        raise UserInputError(f"{str(path)!r} is not a readable safetensors file ({exc}).") \
            from None


def trained_masking(provenance: dict) -> str:
    """The masking a policy was trained with, from its weights' decoded provenance ('iam'
    when it does not say)."""
    return provenance.get("config", {}).get("policy", {}).get("masking", "iam")


def describe(kind: str, layout: dict, provenance: dict) -> str:
    """A policy's kind, feature set (GVN) and training masking, e.g. 'gvn v3, masking iam':
    what its explorer and decision space depend on."""
    what = kind + (f" {layout.get('features', 'v1')}" if kind == "gvn" else "")
    return f"{what}, masking {trained_masking(provenance)}"


def describe_file(path: str | os.PathLike) -> str:
    """:func:`describe` of a weights file, from its header alone."""
    meta = weights_metadata(path)
    try:
        return describe(meta.get("kind", "?"), json.loads(meta.get("layout", "{}")),
                        json.loads(meta.get("provenance", "{}")))
    except ValueError:
        raise UserInputError(f"{str(path)!r} has damaged metadata: give a weights file "
                             "written by 'mjexplore train'.") from None


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


_COPIES: dict[str, tuple[str, Path]] = {}


def register_copy(policy: str, name: str, path: str | os.PathLike) -> None:
    """Makes :func:`resolve_policy` resolve ``policy``, as another machine gave it, to
    ``(name, path)``: the name it has there and this machine's copy of its weights (a Ray
    worker's), so that run records name the weights as the machine that sent them."""
    _COPIES[policy] = (name, Path(path))


def resolve_policy(policy: str | os.PathLike | None, kind: str) -> tuple[str, Path]:
    """(name, weights file) of ``policy``: a model name, a weights file, a folder holding
    ``policy.safetensors``, or None for ``kind``'s default model. A file's name is its path
    (on the machine that gave it: see :func:`register_copy`).

    Raises:
        UserInputError: neither a model nor a file; the message lists the models.
    """
    if policy is None:
        policy = DEFAULT_MODEL[kind]
    text = str(policy)
    if text in _COPIES:
        return _COPIES[text]
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


@dataclasses.dataclass(frozen=True)
class Card:
    """What a shipped model's card (``models/NAME/README.md``) says of its weights.

    Attributes:
        name: The model's name.
        sha256: The weights file's full sha256 (None if the card names none).
        recipe: The training config it came from, e.g. ``gvn_v3.yaml`` (None if unnamed).
    """

    name: str
    sha256: str | None
    recipe: str | None


def read_card(name: str) -> Card:
    """The card of the shipped model ``name`` (fields None where it says nothing)."""
    path = MODELS_DIR / name / "README.md"
    text = path.read_text() if path.is_file() else ""
    sha = re.search(r"sha256 `([0-9a-f]{64})`", text)
    recipe = re.search(r"\| recipe \| `(?:training/)?([^`]+)`", text)
    return Card(name, sha and sha.group(1), recipe and recipe.group(1))


def _header(path: str | os.PathLike) -> bytes | None:
    """A safetensors file's header (its length and JSON: tensor names, dtypes, shapes,
    offsets and metadata), None if it has none."""
    try:
        with open(path, "rb") as f:
            length = int.from_bytes(f.read(8), "little")
            return f.read(length) if 0 < length < 1 << 26 else None
    except OSError:
        return None


@functools.lru_cache(maxsize=1)
def _shipped_headers() -> dict[bytes, str]:
    """The header of each shipped model's weights, to its name."""
    headers: dict[bytes, str] = {}
    for weights in sorted(MODELS_DIR.glob(f"*/{WEIGHTS_NAME}")):
        header = _header(weights)
        if header is not None:
            headers.setdefault(header, weights.parent.name)
    return headers


def shipped_model_of(path: str | os.PathLike) -> str | None:
    """The shipped model whose weights ``path`` is, or is a copy of (the same header:
    tensor layout and metadata), None for any other file."""
    path = Path(path)
    with_name = path.resolve()
    if with_name.name == WEIGHTS_NAME and with_name.parent.parent == MODELS_DIR.resolve():
        return with_name.parent.name
    header = _header(path)
    return None if header is None else _shipped_headers().get(header)


def run_label(kind: str, name: str, masked: bool, trained: str) -> str:
    """The label of runs of ``kind``'s explorer with the policy ``name`` (a model or a
    path), run with the mask or without it, that was trained with masking ``trained``.

    Shipped models are labelled by their name (the paper's recipe by its earlier labels,
    ``gvn`` and ``cnn``), with ``_unmasked`` when a policy trained with a mask runs
    without; a user's file by ``KIND_NAME_SHA``: the name of the run folder that holds its
    ``policy.safetensors`` (else the file's stem) and the first 8 hex digits of its sha256,
    which make a safe folder name of one level that tells apart two files of one name.
    """
    unmasked = not masked and trained != "none"
    if name not in shipped_models():
        _, path = resolve_policy(name, kind)  # This machine's copy where it has one.
        given = Path(name)
        stem = given.parent.name if given.name == WEIGHTS_NAME else given.stem
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "-", stem).strip("._-")[:40] or "policy"
        return f"{kind}_{slug}_{file_sha256(path)[:8]}" + ("_unmasked" if unmasked else "")
    label = LEGACY_LABELS.get(name, name)
    return label + ("_unmasked" if unmasked else "")
