"""The paper's 1D CNN on the raw ranges (paper-spec §5, the configuration behind its results).

input BatchNorm (one channel) → Conv1D 64 k3 same + ReLU ×2 → MaxPool(p) → [Dropout] →
Conv1D 128 k3 same + ReLU ×2 → MaxPool(p) → [Dropout] → Flatten →
[Dense 512 → BN → sigmoid] ×2 → [Dense 64 → BN → sigmoid] → Dense 3.

Pool size 8 (the author's code; 667 → 83 → 10, 1280 features, 1,040,325 trainable parameters)
or 2 (the paper's text). Dropout 0.1 after each pool is Table 1's 20k variant.

Speed (same function, same parameters): each convolution runs as a (1 × 3) Conv2D on a
channels-last (B, C, 1, L) tensor, which oneDNN trains ~1.5x faster than a plain Conv1D at
batch 400 on CPU (benchmarks/train_throughput.py). The one-channel input is marked
channels-last by its strides: for C = 1 both layouts look alike, and oneDNN would answer the
first convolution in NCHW, costing two layout copies per step. The second ReLU of each pair
runs after its max-pool (ReLU and max commute, also in their gradients), on 1/p of the values.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from scanloc.models.keras_init import Conv1dFans, batch_norm_1d, keras_init_
from scanloc.models.pose_output import PoseOutput

HEAD_WIDTHS = (512, 512, 64)


class Conv1dAs2d(nn.Conv1d):
    """A 'same'-padded Conv1D (weights (out, in, k) as nn.Conv1d) applied to (B, C, 1, L)."""

    channels_last: bool = True

    def forward(self, x: Tensor) -> Tensor:
        weight = self.weight.unsqueeze(2)
        if self.channels_last:
            weight = weight.contiguous(memory_format=torch.channels_last)
        return F.conv2d(x, weight, self.bias, padding=(0, self.kernel_size[0] // 2))


def sigmoid_head(in_features: int, dropout: float = 0.0) -> nn.Sequential:
    """[Dense → BN → sigmoid (→ Dropout)] for widths 512, 512, 64, then Dense 3 (x, y, θ)."""
    layers: list[nn.Module] = []
    for width in HEAD_WIDTHS:
        layers += [nn.Linear(in_features, width), batch_norm_1d(width), nn.Sigmoid()]
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        in_features = width
    layers.append(PoseOutput(in_features))
    return nn.Sequential(*layers)


class Cnn1d(nn.Module):
    """Ranges (B, num_beams) float32 → pose (B, 3) = (x [m], y [m], θ [rad])."""

    def __init__(
        self,
        num_beams: int = 667,
        pool_size: int = 8,
        dropout: float = 0.0,
        conv1d_fans: Conv1dFans = "keras1",
        channels_last: bool = True,
    ) -> None:
        super().__init__()
        features = (num_beams // pool_size) // pool_size
        if features < 1:
            raise ValueError(f"num_beams={num_beams} is too short for two pools of {pool_size}")
        self.num_beams, self.pool_size = num_beams, pool_size
        self.input_norm = batch_norm_1d(1)
        self.conv = nn.ModuleList(
            Conv1dAs2d(c_in, c_out, 3) for c_in, c_out in ((1, 64), (64, 64), (64, 128), (128, 128))
        )
        self.dropout = nn.Dropout(dropout) if dropout > 0 else nn.Identity()
        self.head = sigmoid_head(128 * features)
        self.channels_last = channels_last
        keras_init_(self, conv1d_fans)

    @property
    def channels_last(self) -> bool:
        return self._channels_last

    @channels_last.setter
    def channels_last(self, value: bool) -> None:
        """A pure memory-layout choice (same results); vmap needs it off."""
        self._channels_last = value
        for conv in self.conv:
            conv.channels_last = value

    def forward(self, ranges: Tensor) -> Tensor:
        x = self.input_norm(ranges.unsqueeze(1)).unsqueeze(2)  # (B, 1, 1, N)
        if self.channels_last:
            x = x.as_strided(x.shape, (x.shape[-1], 1, x.shape[-1], 1))
        pool = (1, self.pool_size)
        for first, second in ((0, 1), (2, 3)):
            x = F.relu(self.conv[first](x))
            x = self.dropout(F.relu(F.max_pool2d(self.conv[second](x), pool)))
        return self.head(x.flatten(1))
