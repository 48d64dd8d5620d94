"""The CNN actor-critic of the "Naive Exp" baseline (paper ref. [27]) for MaskablePPO.

A small convolutional encoder reads the five-channel map image of
:class:`~mjexplore.envs.decisions.GridDecisions`; SB3's standard heads give one logit per
coarse goal cell (actor) and the state value (critic). Invalid cells are masked as for GVN.
"""

from __future__ import annotations

from typing import Any, cast

import torch
from gymnasium import spaces
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from mjexplore.envs.decisions import GRID_CHANNELS


class GridCnn(BaseFeaturesExtractor):
    """(B, C S S) flat image -> (B, features) through three strided convolutions."""

    def __init__(self, observation_space: spaces.Dict, features: int = 256) -> None:
        super().__init__(observation_space, features_dim=features)
        c = len(GRID_CHANNELS)
        image = cast(spaces.Box, observation_space["image"])  # See GridDecisions.
        self.side = int(round((image.shape[0] / c) ** 0.5))
        self.conv = nn.Sequential(
            nn.Conv2d(c, 32, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(32, 64, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(64, 64, 3, stride=2, padding=1), nn.ReLU(), nn.Flatten())
        with torch.no_grad():
            n = self.conv(torch.zeros(1, c, self.side, self.side)).shape[1]
        self.linear = nn.Sequential(nn.Linear(n, features), nn.ReLU())

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        x = observations["image"].view(-1, len(GRID_CHANNELS), self.side, self.side)
        return self.linear(self.conv(x))


class CnnPolicy(MaskableActorCriticPolicy):
    """MaskablePPO policy with :class:`GridCnn` and linear actor/critic heads.

    Args:
        masking: 'iam' or 'naive' (see :mod:`mjexplore.policies.sb3`).
        features: Width of the encoder's output.
    """

    def __init__(self, observation_space: spaces.Dict, action_space: spaces.Discrete,
                 lr_schedule, masking: str = "iam", features: int = 256,
                 **kwargs: Any) -> None:
        if masking != "iam":
            raise ValueError("the CNN baseline supports masking 'iam' only")
        self._cnn_kwargs = dict(masking=masking, features=features)
        kwargs.setdefault("features_extractor_class", GridCnn)
        kwargs.setdefault("features_extractor_kwargs", dict(features=features))
        kwargs.setdefault("net_arch", [])
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(self._cnn_kwargs)
        return data
