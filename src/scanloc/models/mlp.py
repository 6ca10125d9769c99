"""The paper's multi-layer perceptron baseline (paper-spec §5).

ranges → [Dense 512 → BN → ReLU → Dropout d] ×3 → [Dense hidden → BN → ReLU → Dropout] →
Dense 3. The paper's text gives hidden = 64 and dropout 0.25 throughout; the author's code
used hidden = 128 with dropout 0.5 on that layer (`hidden=128, hidden_dropout=0.5`).
"""

from __future__ import annotations

from torch import Tensor, nn

from scanloc.models.keras_init import batch_norm_1d, keras_init_
from scanloc.models.pose_output import PoseOutput


class Mlp(nn.Module):
    """Ranges (B, num_beams) float32 → pose (B, 3) = (x [m], y [m], θ [rad])."""

    def __init__(
        self,
        num_beams: int = 667,
        dropout: float = 0.25,
        hidden: int = 64,
        hidden_dropout: float | None = None,
    ) -> None:
        super().__init__()
        self.num_beams = num_beams
        widths = (512, 512, 512, hidden)
        rates = (dropout, dropout, dropout, dropout if hidden_dropout is None else hidden_dropout)
        layers: list[nn.Module] = []
        in_features = num_beams
        for width, rate in zip(widths, rates, strict=True):
            layers += [nn.Linear(in_features, width), batch_norm_1d(width), nn.ReLU()]
            if rate > 0:
                layers.append(nn.Dropout(rate))
            in_features = width
        layers.append(PoseOutput(in_features))
        self.layers = nn.Sequential(*layers)
        keras_init_(self)

    def forward(self, ranges: Tensor) -> Tensor:
        return self.layers(ranges)
