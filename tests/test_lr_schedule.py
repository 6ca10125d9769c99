"""Keras' per-update learning-rate decay."""

from __future__ import annotations

import pytest
import torch

from scanloc.models.lr_schedule import keras_decay, keras_decay_factor


def test_rate_after_t_updates() -> None:
    param = torch.nn.Parameter(torch.zeros(1))
    optimizer = torch.optim.SGD([param], lr=0.01)
    schedule = keras_decay(optimizer, 0.005)
    used = []
    for _ in range(1001):
        used.append(optimizer.param_groups[0]["lr"])
        param.grad = torch.ones(1)
        optimizer.step()
        schedule.step()
    # The first update uses lr_0; update t (0-based) uses lr_0 / (1 + decay * t).
    assert used[0] == pytest.approx(0.01)
    assert used[1] == pytest.approx(0.01 / 1.005)
    assert used[1000] == pytest.approx(0.01 / 6.0)
    assert param.item() == pytest.approx(-sum(used))


def test_zero_decay_is_constant_and_negative_is_rejected() -> None:
    assert keras_decay_factor(10**6, 0.0) == 1.0
    assert keras_decay_factor(200, 0.005) == pytest.approx(0.5)
    optimizer = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    with pytest.raises(ValueError, match="lr_decay"):
        keras_decay(optimizer, -0.1)
