"""The three networks: shapes, exact parameter counts, Keras 1 initialisation and BatchNorm
settings, and that the speed-ups (channels-last layout, ReLU after pooling) change nothing."""

from __future__ import annotations

import itertools
import math

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from scanloc.models.cnn1d import Cnn1d
from scanloc.models.cnn2d import Cnn2d
from scanloc.models.keras_init import conv_fans, keras_init_
from scanloc.models.mlp import Mlp
from scanloc.models.pose_output import PoseOutput


def trainable(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def dense(n_in: int, n_out: int) -> int:
    return n_in * n_out + n_out


HEAD = (
    dense(576, 512) + 2 * 512 + dense(512, 512) + 2 * 512 + dense(512, 64) + 2 * 64 + dense(64, 3)
)


@pytest.mark.parametrize(
    "model",
    [
        Mlp(64),
        Cnn1d(64, pool_size=8),
        Cnn1d(64, pool_size=2, dropout=0.1),
        Cnn2d(64, image_size=64),
    ],
    ids=["mlp", "cnn1d_p8", "cnn1d_p2", "cnn2d"],
)
def test_output_shape_train_and_eval(model: nn.Module) -> None:
    x = torch.rand(5, 64) * 7
    assert model(x).shape == (5, 3)
    model.eval()
    out = model(x)
    assert out.shape == (5, 3) and out.dtype == torch.float32


def test_paper_sized_networks_and_exact_parameter_counts() -> None:
    cnn1d = Cnn1d()
    conv = (1 * 64 * 3 + 64) + (64 * 64 * 3 + 64) + (64 * 128 * 3 + 128) + (128 * 128 * 3 + 128)
    head_1d = HEAD - dense(576, 512) + dense(1280, 512)
    assert trainable(cnn1d) == 2 + conv + head_1d == 1_040_325  # "about 1.04 M"
    assert cnn1d(torch.rand(2, 667) * 7).shape == (2, 3)
    # Pool 2 (the paper's text): 667 -> 333 -> 166 positions, 21,248 features.
    assert trainable(Cnn1d(pool_size=2)) == 2 + conv + head_1d - dense(1280, 512) + dense(
        128 * 166, 512
    )
    mlp = Mlp()
    blocks = dense(667, 512) + 2 * (dense(512, 512)) + 3 * 2 * 512
    assert trainable(mlp) == blocks + dense(512, 64) + 2 * 64 + dense(64, 3) == 903_555
    assert trainable(Mlp(hidden=128)) == blocks + dense(512, 128) + 2 * 128 + dense(128, 3)
    cnn2d = Cnn2d()
    filters = (1, 4, 8, 8, 16, 16, 16)
    convs = sum(dense(9 * a, b) for a, b in itertools.pairwise(filters))
    assert trainable(cnn2d) == convs + HEAD == 600_011  # 576 features after six pools
    assert cnn2d(torch.rand(2, 667) * 7).shape == (2, 3)


def test_too_short_inputs_are_rejected() -> None:
    with pytest.raises(ValueError, match="too short"):
        Cnn1d(num_beams=50, pool_size=8)
    with pytest.raises(ValueError, match="too small"):
        Cnn2d(image_size=32)


def _bounds_hold(weight: torch.Tensor, bound: float) -> None:
    assert weight.abs().max() <= bound
    # Uniform on ±bound: the largest of many draws is close to the bound, std = bound/√3.
    if weight.numel() >= 1000:
        assert weight.abs().max() > 0.95 * bound
        assert weight.std().item() == pytest.approx(bound / math.sqrt(3), rel=0.05)


def test_keras1_initialisation() -> None:
    torch.manual_seed(0)
    for model in (Mlp(), Cnn1d(), Cnn2d(image_size=64)):
        for layer in model.modules():
            if isinstance(layer, nn.Linear):
                _bounds_hold(layer.weight, math.sqrt(3 / layer.in_features))  # lecun_uniform
            elif isinstance(layer, nn.Conv1d):
                out_ch, in_ch, k = layer.weight.shape
                # Keras 1.2.2 Conv1D fans: in*out and k*in*out.
                _bounds_hold(layer.weight, math.sqrt(6 / (in_ch * out_ch * (1 + k))))
            elif isinstance(layer, nn.Conv2d):
                out_ch, in_ch, kh, kw = layer.weight.shape
                _bounds_hold(layer.weight, math.sqrt(6 / ((in_ch + out_ch) * kh * kw)))
            if isinstance(layer, nn.Linear | nn.Conv1d | nn.Conv2d):
                assert torch.count_nonzero(layer.bias) == 0


def test_standard_conv1d_fans_and_bad_choice() -> None:
    assert conv_fans(torch.Size([64, 32, 3]), "standard") == (96, 192)
    assert conv_fans(torch.Size([64, 32, 3]), "keras1") == (2048, 6144)
    assert conv_fans(torch.Size([8, 4, 3, 3]), "keras1") == (36, 72)
    torch.manual_seed(0)
    conv = keras_init_(nn.Conv1d(64, 64, 3), "standard")
    _bounds_hold(conv.weight, math.sqrt(6 / (192 + 192)))
    with pytest.raises(ValueError, match="conv1d_fans"):
        conv_fans(torch.Size([64, 32, 3]), "keras2")  # type: ignore[arg-type]


def test_batchnorm_uses_keras_momentum_and_epsilon() -> None:
    for model in (Mlp(64), Cnn1d(64), Cnn2d(64, image_size=64)):
        norms = [m for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
        assert norms
        for norm in norms:
            assert norm.momentum == pytest.approx(0.01) and norm.eps == pytest.approx(1e-3)
    # Keras momentum 0.99: the running mean moves 1 % towards a batch mean.
    model = Cnn1d(64)
    model(torch.full((4, 64), 5.0))
    assert model.input_norm.running_mean.item() == pytest.approx(0.05)


def keras_order_cnn1d(model: Cnn1d, ranges: torch.Tensor) -> torch.Tensor:
    """The textbook layer order with plain Conv1D: conv, ReLU, conv, ReLU, pool per pair."""
    x = model.input_norm(ranges.unsqueeze(1))
    for first, second in ((0, 1), (2, 3)):
        for conv in (model.conv[first], model.conv[second]):
            x = F.relu(F.conv1d(x, conv.weight, conv.bias, padding=1))
        x = F.max_pool1d(x, model.pool_size)
    return model.head(x.flatten(1))


@pytest.mark.parametrize("channels_last", [True, False])
def test_cnn1d_equals_the_textbook_layer_order(channels_last: bool) -> None:
    torch.manual_seed(1)
    # float64: the head's BatchNorm after tiny early activations amplifies float32 rounding.
    model = Cnn1d(64, pool_size=2, channels_last=channels_last).double()
    x = torch.rand(6, 64, dtype=torch.float64) * 7
    ours = model(x)
    ours.sum().backward()
    grads = [p.grad.clone() for p in model.parameters()]
    model.zero_grad()
    reference = keras_order_cnn1d(model, x)
    reference.sum().backward()
    torch.testing.assert_close(ours, reference, rtol=1e-10, atol=1e-10)
    for got, want in zip(grads, (p.grad for p in model.parameters()), strict=True):
        torch.testing.assert_close(got, want, rtol=1e-7, atol=1e-10)


def test_cnn1d_activations_stay_channels_last() -> None:
    """A one-channel input is ambiguous between layouts; unless it is marked channels-last the
    first convolution answers in NCHW and every step pays two 400 x 64 x 667 layout copies and
    a mixed-layout ReLU backward (~25 % of a CPU step)."""
    model = Cnn1d(64, pool_size=2)
    layouts = []
    for conv in model.conv:
        conv.register_forward_hook(lambda _m, inputs, out: layouts.append((inputs[0], out)))
    model(torch.rand(5, 64))
    for inp, out in layouts[1:]:
        assert inp.stride(1) == 1 and out.stride(1) == 1  # channels innermost
    assert layouts[0][1].stride(1) == 1


@pytest.mark.parametrize("model", [Mlp(64), Cnn1d(64, pool_size=2), Cnn2d(64, image_size=64)])
def test_pose_output_stays_float32_under_bf16_autocast(model: nn.Module) -> None:
    torch.manual_seed(3)
    last = [m for m in model.modules() if isinstance(m, nn.Linear)][-1]
    assert isinstance(last, PoseOutput) and last.out_features == 3
    x = torch.rand(4, 64) * 7
    with torch.autocast("cpu", dtype=torch.bfloat16):
        pose = model.eval()(x)
        hidden = torch.rand(4, last.in_features, dtype=torch.bfloat16)
        out = last(hidden)
    assert pose.dtype == torch.float32 and out.dtype == torch.float32
    torch.testing.assert_close(out, F.linear(hidden.float(), last.weight, last.bias))


def test_cnn2d_image_and_layouts_agree() -> None:
    torch.manual_seed(2)
    model = Cnn2d(64, image_size=64, dropout=0.0, head_dropout=0.0).eval()
    x = torch.rand(3, 64) * 7
    image = model.image(x)
    assert image.shape == (3, 1, 64, 64) and set(image.unique().tolist()) <= {0.0, 1.0}
    out = model(x)
    model.channels_last = False
    torch.testing.assert_close(model(x), out, rtol=1e-5, atol=1e-6)
    # The beam angles follow the constructor, not the state dict.
    assert "angles" not in model.state_dict()
    assert model.angles[0].item() == pytest.approx(-2.09439510239)


def test_mlp_hidden_dropout_defaults_to_dropout() -> None:
    rates = [m.p for m in Mlp(dropout=0.25).modules() if isinstance(m, nn.Dropout)]
    assert rates == [0.25] * 4
    rates = [
        m.p for m in Mlp(hidden=128, hidden_dropout=0.5).modules() if isinstance(m, nn.Dropout)
    ]
    assert rates == [0.25, 0.25, 0.25, 0.5]


def test_a_flat_model_config_builds_what_hydra_instantiate_builds() -> None:
    from hydra.utils import instantiate

    from scanloc.models.model_files import build_model

    grid = {"origin": [0.0, 0.0], "cell_size": 1.0, "shape": [3, 4], "cells": [[0, 1], [2, 3]]}
    grid["heading_bins"] = 8
    configs = [
        {"_target_": "scanloc.models.cnn1d.Cnn1d", "num_beams": 64, "pool_size": 8},
        {"_target_": "scanloc.models.mlp.Mlp", "num_beams": 64, "hidden": 32},
        {
            "_target_": "scanloc.scanlocnet.model.ScanLocNet",
            "num_beams": 64,
            "range_max": 5.6,
            "grid": grid,
            "channels": [8, 8],
            "kernels": [5, 3],
            "features": 32,
            "hidden": 16,
        },
    ]
    for cfg in configs:
        torch.manual_seed(0)
        expected = instantiate(cfg, _convert_="all")
        torch.manual_seed(0)
        built = build_model(cfg)
        assert type(built) is type(expected)
        assert built.state_dict().keys() == expected.state_dict().keys()
        assert all(
            torch.equal(a, b)
            for a, b in zip(
                built.state_dict().values(), expected.state_dict().values(), strict=True
            )
        )


def test_a_model_config_with_hydra_keys_still_goes_through_instantiate() -> None:
    from scanloc.models.model_files import _needs_instantiate

    assert not _needs_instantiate({"_target_": "a.B", "grid": {"cells": [[0, 1]]}})
    assert _needs_instantiate({"_target_": "a.B", "_partial_": True})
    assert _needs_instantiate({"_target_": "a.B", "act": {"_target_": "torch.nn.ReLU"}})
    assert _needs_instantiate({"_target_": "a.B", "layers": [{"_target_": "torch.nn.ReLU"}]})
