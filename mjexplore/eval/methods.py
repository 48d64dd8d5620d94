"""Every exploration method by name, and the run labels of learned ones.

A method is one explorer: a classic planner (:mod:`mjexplore.explorers`) or a learned one
(``gvn``, ``cnn``: :mod:`mjexplore.policies`), which runs a policy (``--policy NAME|PATH``),
with or without the mask at evaluation. A *spec* names one run setting as text, as
``bench --explorers`` and sweep folders take it: a method (``gvn`` runs its recommended
model), ``METHOD:POLICY`` with an optional ``:unmasked``, or a run label (``gvn_v3``,
``gvn_v3_unmasked``, the paper's recipe as ``gvn``... see
:func:`~mjexplore.policies.models.run_label`).
"""

from __future__ import annotations

import dataclasses
import json

from mjexplore.episode.explorer import Explorer
from mjexplore.errors import UserInputError
from mjexplore.explorers import make_explorer as make_classic
from mjexplore.explorers.team import TEAM_METHODS, make_team_explorers
from mjexplore.policies.models import (
    DEFAULT_MODEL,
    resolve_policy,
    run_label,
    shipped_models,
    trained_masking,
    weights_metadata,
)

LEARNED = ("gvn", "cnn")
METHODS: dict[str, str] = {
    "nearest": "nearest frontier by path (Yamauchi 1997)",
    "pocket_nearest": "gvn_v3's prior alone: the TER frontier of least path + 50 m P(small pocket)",
    "explore_lite": "ROS m-explore's explore_lite (frontier cost with size and orientation)",
    "frontier_tsp": "a global tour over the frontiers (TARE/FUEL style)",
    "rrt": "rrt_exploration (RRT frontier detection, information-gain utility)",
    "potential": "MMPF potential field",
    "oracle": "the ground-truth bound: coverage viewpoints and an OR-Tools tour",
    "distance_advantage": "the TER frontier nearest the robot and farthest from the others "
                          "(Ericson et al. 2025)",
    "pocket_advantage": "distance_advantage on pocket_nearest's prior (+ 50 m P(small pocket))",
    "pocket_truth": "pocket_nearest's rule with the true pockets (privileged bound)",
    "oracle_2m": "the oracle's planner given the truth within 2 m of the mapped cells",
    "oracle_5m": "the oracle's planner given the truth within 5 m of the mapped cells",
    "oracle_10m": "the oracle's planner given the truth within 10 m of the mapped cells",
    "predicted_tour": "pocket_nearest, departing when the oracle's tour on the learned map "
                      "prediction saves > 5 m",
    "predicted_tour_inpainting": "predicted_tour with inpainting as the prediction (ablation)",
    "predicted_tour_truth": "predicted_tour with the true map as the prediction (privileged)",
    "predicted_plan": "the oracle's planner on the map plus the learned prediction within 5 m, "
                      "followed on the robot's map",
    "predicted_plan_inpainting": "predicted_plan with inpainting as the prediction (ablation)",
    "predicted_plan_truth": "predicted_plan with the true map as the prediction (privileged)",
    "predicted_drive": "predicted_plan driving on the map plus the learned prediction within "
                       "5 m, as oracle_5m drives on the truth",
    "predicted_drive_inpainting": "predicted_drive with inpainting as the prediction "
                                  "(ablation)",
    "predicted_drive_truth": "predicted_drive with the true map as the prediction "
                             "(privileged)",
    "pocket_predicted": "pocket_nearest's rule with the pockets read from the learned map "
                        "prediction (no pocket classifier)",
    "pocket_predicted_inpainting": "pocket_predicted with inpainting as the prediction "
                                   "(ablation)",
    "gvn": "the learned GVN policy on the TER (--policy picks the model; default gvn_v3)",
    "cnn": "the 'Naive Exp' CNN on the map image (--policy picks the model; default cnn_paper)",
}


@dataclasses.dataclass(frozen=True)
class MethodSpec:
    """One method run setting.

    Attributes:
        method: A name of :data:`METHODS`.
        policy: A learned method's model name or weights path (None: its default model).
        masking: A learned GVN's masking at evaluation (None: as it was trained).
    """

    method: str
    policy: str | None = None
    masking: bool | None = None

    def build(self, deterministic: bool = True) -> Explorer:
        """The explorer this spec describes (loads and checks a learned one's weights)."""
        if self.method == "gvn":
            from mjexplore.policies.gvn_explorer import GvnExplorer

            return GvnExplorer(self.policy, self.masking, deterministic)
        if self.method == "cnn":
            from mjexplore.policies.cnn_explorer import CnnExplorer

            if self.masking is False:
                raise UserInputError("the cnn explorer always runs with its mask: drop "
                                     "--no-masking (or ':unmasked').")
            return CnnExplorer(self.policy, deterministic)
        return make_classic(self.method)

    @property
    def text(self) -> str:
        """This spec as unambiguous text (a learned method's model named), which
        :func:`parse_method` reads back to the same setting."""
        if self.method not in LEARNED:
            return self.method
        text = f"{self.method}:{self.policy or DEFAULT_MODEL[self.method]}"
        return text + (":unmasked" if self.masking is False else "")

    @property
    def label(self) -> str:
        """The label its runs are filed under (a learned method's names its model)."""
        if self.method not in LEARNED:
            return self.method
        name, path = resolve_policy(self.policy, self.method)
        trained = trained_masking(json.loads(weights_metadata(path).get("provenance", "{}")))
        masked = self.masking if self.masking is not None else trained != "none"
        return run_label(self.method, name, masked, trained)


def _legacy_labels() -> dict[str, MethodSpec]:
    """Run labels of every shipped model, masked and unmasked, as specs."""
    specs: dict[str, MethodSpec] = {}
    for name, model in shipped_models().items():
        for masked in (True, False):
            label = run_label(model.kind, name, masked, model.masking)
            specs.setdefault(label, MethodSpec(model.kind, name, masked))
    return specs


def spec_of_label(label: str) -> str:
    """The spec that runs what the run label ``label`` names, as ``bench --explorers``
    takes it: a shipped model's label names its model (the paper's ``gvn`` is
    ``gvn:gvn_paper``, while the method ``gvn`` runs today's default model); other
    labels are their own spec."""
    legacy = _legacy_labels()
    return legacy[label].text if label in legacy else label


def parse_method(spec: str) -> MethodSpec:
    """The :class:`MethodSpec` a spec names.

    Raises:
        UserInputError: an unknown method, or a policy given to a classic one.
    """
    text = spec.strip()
    method, _, rest = text.partition(":")
    if method in METHODS and not rest:
        return MethodSpec(method)
    if method in LEARNED and rest:
        policy, masking = rest, None
        if rest.endswith(":unmasked"):
            policy, masking = rest[:-len(":unmasked")], False
        return MethodSpec(method, policy or None, masking)
    if not rest and text in (legacy := _legacy_labels()):
        return legacy[text]
    if method in METHODS:
        raise UserInputError(f"{text!r}: only the learned methods ({', '.join(LEARNED)}) take a "
                             "policy (METHOD:POLICY).")
    if text in shipped_models():
        kind = shipped_models()[text].kind
        raise UserInputError(f"{text!r} is a model, not an explorer: run it with --explorer "
                             f"{kind} --policy {text} (in bench --explorers: {kind}:{text}).")
    from mjexplore.explorers.team import TEAM_METHODS

    if text in TEAM_METHODS:
        raise UserInputError(f"{text!r} is a team method: add --robots 2 (or more).")
    raise UserInputError(f"unknown explorer {text!r}: use one of {', '.join(METHODS)}, "
                         "METHOD:POLICY for a learned one, or a shipped model's run label "
                         "('mjexplore policies' lists them).")


def team_explorers(spec: str, n: int) -> tuple[list[Explorer], str]:
    """The ``n`` explorers of a team method spec and the run's label: a coordinated method
    by name (:data:`~mjexplore.explorers.team.TEAM_METHODS`), else the naive team of the
    single-robot method ``spec``, each robot running it on its own (labelled
    ``naive_LABEL``).

    Raises:
        UserInputError: an unknown method.
    """
    if spec in TEAM_METHODS:
        return make_team_explorers(spec, n), spec
    parsed = parse_method(spec)
    explorers = [parsed.build() for _ in range(n)]
    return explorers, f"naive_{getattr(explorers[0], 'label', parsed.label)}"


def make_explorer(spec: str, **kwargs) -> Explorer:
    """The explorer a spec names; ``kwargs`` go to a classic explorer's constructor, or are
    ``policy``/``masking``/``deterministic`` for a learned one (they override the spec's).

    Raises:
        UserInputError: an unknown spec, or unusable weights.
    """
    parsed = parse_method(spec)
    if parsed.method not in LEARNED:
        return make_classic(parsed.method, **kwargs)
    deterministic = kwargs.pop("deterministic", True)
    parsed = dataclasses.replace(parsed, **kwargs)
    return parsed.build(deterministic)

