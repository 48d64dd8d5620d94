"""Which policy class and observation space belong to a weights file's ``kind``."""

from __future__ import annotations

from mjexplore.errors import UserInputError


def policy_class(kind: str):
    """(policy class, observation-space builder) for a policy kind."""
    if kind == "gvn":
        from mjexplore.envs.observation import observation_space
        from mjexplore.policies.sb3 import GvnPolicy

        return GvnPolicy, observation_space
    raise UserInputError(f"unknown policy kind {kind!r} in the weights file: this version knows "
                         "'gvn'.")
