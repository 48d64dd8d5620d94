"""Policy kinds: the policy class, the decision space and the spaces of each.

``kind`` is stored in every weights file and checkpoint; ``layout`` is the JSON form of the
decision space's config (:class:`ObservationConfig` for 'gvn', :class:`GridConfig` for
'cnn'). A 'gvn' layout also holds, under ``topology``, the topology settings of the episodes
the policy was trained in (information gain kind and window, D_gain, ...: what the TER's
node features mean), so that the explorer builds the TERs it was trained on; layouts
written before carry neither ``features`` (they are 'v1') nor ``topology`` (the
episode's settings are used, as then).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from mjexplore.errors import UserInputError

KINDS = ("gvn", "cnn")


def decisions_for(kind: str, layout: dict[str, Any]):
    """The decision space of a policy kind with a stored layout."""
    from mjexplore.envs.decisions import GridConfig, GridDecisions, TerDecisions

    try:
        if kind == "gvn":
            observation, topology = gvn_layout(layout)
            return TerDecisions(observation, topology=topology)
        if kind == "cnn":
            return GridDecisions(GridConfig(**layout))
    except (TypeError, ValueError, UserInputError) as exc:
        raise UserInputError(f"the stored {kind!r} layout {layout!r} is invalid ({exc}).") \
            from None
    raise UserInputError(f"unknown policy kind {kind!r}: this version knows "
                         f"{', '.join(KINDS)}.")


def gvn_layout(layout: dict[str, Any]):
    """(ObservationConfig, TopologyConfig or None) of a stored 'gvn' layout.

    Raises:
        TypeError, ValueError, UserInputError: an invalid layout.
    """
    from mjexplore.config import from_dict
    from mjexplore.envs.observation import ObservationConfig
    from mjexplore.topology.pipeline import TopologyConfig

    layout = dict(layout)
    topology = layout.pop("topology", None)
    return (ObservationConfig(**layout),
            None if topology is None else from_dict(TopologyConfig, topology, "topology"))


def layout_of(kind: str, env_config) -> dict[str, Any]:
    """The layout a policy of ``kind`` trained on ``env_config`` is stored with."""
    if kind != "gvn":
        return dataclasses.asdict(env_config.grid)
    from mjexplore.config import to_dict

    return {**dataclasses.asdict(env_config.observation),
            "topology": to_dict(env_config.episode.topology)}


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
