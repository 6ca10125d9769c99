"""The paper's 2D CNN on a rasterised image of the scan (paper-spec §4 eq. 1–4 and §5).

ranges → binary image (B, 1, 384, 384), drawn on the fly on the model's device →
six blocks [Conv2D 3×3 same → ReLU → MaxPool 2 → Dropout 0.1] with 4, 8, 8, 16, 16, 16
filters (384 → 6; 576 features) → [Dense 512/512/64 → BN → sigmoid → Dropout 0.05] → Dense 3.

Rasterising inside the model keeps the datasets small (ranges only) and lets the same
predict/load code serve all three networks. As in the 1D CNN, the convolutions run
channels-last and each ReLU after its max-pool (they commute), on a quarter of the values.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from scanloc.data.rasterize import rasterize_scans
from scanloc.models.cnn1d import sigmoid_head
from scanloc.models.keras_init import keras_init_
from scanloc.sensor.laser import LaserSpec

FILTERS = (4, 8, 8, 16, 16, 16)


class Cnn2d(nn.Module):
    """Ranges (B, num_beams) float32 → pose (B, 3) = (x [m], y [m], θ [rad])."""

    def __init__(
        self,
        num_beams: int = 667,
        angle_min: float = -2.09439510239,
        angle_max: float = 2.09439510239,
        image_size: int = 384,
        max_range: float = 7.1,
        draw_no_return: bool = True,
        no_return_value: float = 7.0,
        dropout: float = 0.1,
        head_dropout: float = 0.05,
        channels_last: bool = True,
    ) -> None:
        super().__init__()
        side = image_size
        for _ in FILTERS:
            side //= 2
        if side < 1:
            raise ValueError(f"image_size={image_size} is too small for {len(FILTERS)} pools of 2")
        self.num_beams, self.image_size, self.max_range = num_beams, image_size, max_range
        self.skip_range = None if draw_no_return else no_return_value
        laser = LaserSpec(num_beams=num_beams, angle_min=angle_min, angle_max=angle_max)
        angles = torch.from_numpy(laser.beam_angles()).to(torch.float32)
        # Derived from the constructor arguments, so not part of the state dict.
        self.register_buffer("angles", angles, persistent=False)
        channels = (1, *FILTERS)
        self.conv = nn.ModuleList(
            nn.Conv2d(c_in, c_out, 3, padding=1)
            for c_in, c_out in zip(channels[:-1], FILTERS, strict=True)
        )
        self.dropout = nn.Dropout(dropout) if dropout > 0 else nn.Identity()
        self.head = sigmoid_head(FILTERS[-1] * side * side, head_dropout)
        self.channels_last = channels_last
        keras_init_(self)

    def image(self, ranges: Tensor) -> Tensor:
        """The network's input picture of each scan (B, 1, size, size), see data.rasterize."""
        return rasterize_scans(
            ranges, self.angles, self.image_size, self.max_range, skip_range=self.skip_range
        )

    def forward(self, ranges: Tensor) -> Tensor:
        x = self.image(ranges)
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        for conv in self.conv:
            x = self.dropout(F.relu(F.max_pool2d(conv(x), 2)))
        return self.head(x.flatten(1))
