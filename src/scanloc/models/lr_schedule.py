"""Keras' per-update learning-rate decay (Table 1's "LR-Decay"), as a PyTorch LambdaLR.

Keras 1 optimisers scale the rate before every update: lr_t = lr_0 / (1 + decay · t) with t the
number of updates made so far (0 for the first). Step the scheduler once per batch.
"""

from __future__ import annotations

import torch
from torch.optim.lr_scheduler import LambdaLR


def keras_decay_factor(step: int, decay: float) -> float:
    """lr_t / lr_0 after `step` optimiser updates."""
    return 1.0 / (1.0 + decay * step)


def keras_decay(optimizer: torch.optim.Optimizer, decay: float) -> LambdaLR:
    """A scheduler to `.step()` after every optimiser update."""
    if decay < 0:
        raise ValueError(f"lr_decay must be >= 0, got {decay}")
    return LambdaLR(optimizer, lambda step: keras_decay_factor(step, decay))
