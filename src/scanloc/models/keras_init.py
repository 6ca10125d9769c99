"""Keras 1.2.2 layer conventions (the author's framework), so that training starts where his did.

- Dense: `lecun_uniform`, U(±sqrt(3 / fan_in)); biases zero.
- Convolutions: `glorot_uniform`, U(±sqrt(6 / (fan_in + fan_out))); biases zero.
  Keras 1.2.2's Convolution1D stores its kernel as (length, 1, in, out) and computes the fans
  as if that were a Theano 2D kernel: fan_in = in·out, fan_out = length·in·out (not in·length,
  out·length). `conv1d_fans="keras1"` reproduces that quirk (the author's effective init),
  `"standard"` uses the textbook fans. Conv2D fans were computed correctly by Keras 1.
- BatchNormalization: momentum 0.99 and epsilon 1e-3 in Keras terms, i.e. PyTorch
  momentum = 1 − 0.99 = 0.01 (the weight of the new batch), eps = 1e-3; gamma 1, beta 0.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
from torch import nn

BN_MOMENTUM = 0.01  # PyTorch convention for Keras momentum 0.99
BN_EPS = 1e-3

Conv1dFans = Literal["keras1", "standard"]


def batch_norm_1d(num_features: int) -> nn.BatchNorm1d:
    """BatchNorm over features (B, F) or channels (B, C, L) with Keras 1 defaults."""
    return nn.BatchNorm1d(num_features, eps=BN_EPS, momentum=BN_MOMENTUM)


def lecun_uniform_bound(fan_in: int) -> float:
    return math.sqrt(3.0 / fan_in)


def glorot_uniform_bound(fan_in: int, fan_out: int) -> float:
    return math.sqrt(6.0 / (fan_in + fan_out))


def conv_fans(weight_shape: torch.Size, conv1d_fans: Conv1dFans = "keras1") -> tuple[int, int]:
    """(fan_in, fan_out) of a PyTorch conv kernel (out, in, *kernel) under Keras 1's rules."""
    out_ch, in_ch, *kernel = weight_shape
    receptive = math.prod(kernel)
    if conv1d_fans not in ("keras1", "standard"):
        raise ValueError(f"conv1d_fans must be 'keras1' or 'standard', got {conv1d_fans!r}")
    if len(kernel) == 1 and conv1d_fans == "keras1":
        return in_ch * out_ch, receptive * in_ch * out_ch
    return in_ch * receptive, out_ch * receptive


@torch.no_grad()
def keras_init_(module: nn.Module, conv1d_fans: Conv1dFans = "keras1") -> nn.Module:
    """Initialise every Linear / Conv / BatchNorm inside `module` in place, Keras 1 style.

    Draws from torch's global generator in module order, so a seeded run is reproducible.
    """
    for layer in module.modules():
        if isinstance(layer, nn.Linear):
            bound = lecun_uniform_bound(layer.in_features)
            layer.weight.uniform_(-bound, bound)
        elif isinstance(layer, nn.Conv1d | nn.Conv2d):
            bound = glorot_uniform_bound(*conv_fans(layer.weight.shape, conv1d_fans))
            layer.weight.uniform_(-bound, bound)
        elif isinstance(layer, nn.modules.batchnorm._BatchNorm):
            layer.reset_parameters()
            continue
        else:
            continue
        if layer.bias is not None:
            layer.bias.zero_()
    return module
