"""The networks' last layer, Dense 3 → (x [m], y [m], θ [rad]), always computed in float32.

Under bf16 autocast (trainer precision bf16-mixed) every Linear would round its output to 8
bits of mantissa: a coordinate near 10 m in steps of 6 cm, the size of the errors the paper
reports. This layer is three outputs wide, so keeping it in float32 costs nothing.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class PoseOutput(nn.Linear):
    """Linear(in_features, 3) in its weights' dtype, whatever autocast says (parameters and
    state_dict as nn.Linear)."""

    def __init__(self, in_features: int) -> None:
        super().__init__(in_features, 3)

    def forward(self, x: Tensor) -> Tensor:
        with torch.autocast(x.device.type, enabled=False):
            return super().forward(x.to(self.weight.dtype))
