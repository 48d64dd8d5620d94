"""Policy kinds: the policy class, the decision space and the spaces of each.

``kind`` is stored in every weights file and checkpoint; ``layout`` is the JSON form of the
decision space's config (:class:`ObservationConfig` for 'gvn', :class:`GridConfig` for
'cnn').
"""

from __future__ import annotations

import dataclasses
from typing import Any

from mjexplore.errors import UserInputError

KINDS = ("gvn", "cnn")


def decisions_for(kind: str, layout: dict[str, Any]):
    """The decision space of a policy kind with a stored layout."""
    from mjexplore.envs.decisions import GridConfig, GridDecisions, TerDecisions
    from mjexplore.envs.observation import ObservationConfig

    try:
        if kind == "gvn":
            return TerDecisions(ObservationConfig(**layout))
        if kind == "cnn":
            return GridDecisions(GridConfig(**layout))
    except (TypeError, ValueError) as exc:
        raise UserInputError(f"the stored {kind!r} layout {layout!r} is invalid ({exc}).") \
            from None
    raise UserInputError(f"unknown policy kind {kind!r}: this version knows "
                         f"{', '.join(KINDS)}.")


def layout_of(kind: str, env_config) -> dict[str, Any]:
    """The layout a policy of ``kind`` trained on ``env_config`` is stored with."""
    cfg = env_config.observation if kind == "gvn" else env_config.grid
    return dataclasses.asdict(cfg)


def policy_class(kind: str):
    """The SB3 policy class of a kind."""
    if kind == "gvn":
        from mjexplore.policies.sb3 import GvnPolicy

        return GvnPolicy
    if kind == "cnn":
        from mjexplore.policies.cnn import CnnPolicy

        return CnnPolicy
    raise UserInputError(f"unknown policy kind {kind!r}: this version knows "
                         f"{', '.join(KINDS)}.")
