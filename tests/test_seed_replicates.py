"""A training row repeated over seeds: its figures over the seeds (mean, Student-t 95 %
interval, per-seed values) and its further seeds trained together, from a pre-trained model
where the row is a transfer run."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from scipy import stats

from scanloc.models.model_files import load_model, read_model_file
from scanloc.models.seed_replicates import (
    SEED_FIGURES,
    further_seed_dirs,
    over_seeds,
    train_further_seeds,
)
from scanloc.models.stacked_ensemble import fit_stacked
from scanloc.models.training import fit

CNN1D = {"_target_": "scanloc.models.cnn1d.Cnn1d", "pool_size": 8, "dropout": 0.2}
TINY = {"epochs": 1, "batch_size": 32, "lr_decay": 0.0, "max_samples": 128}

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _figures(value: float) -> dict[str, float]:
    """A seed's metrics: every figure over seeds `value` + its index, and a machine figure."""
    return {name: value + k for k, name in enumerate(SEED_FIGURES)} | {"epoch_s": 9.0}


def test_over_seeds_gives_the_mean_and_a_student_t_interval() -> None:
    per_seed = {7: _figures(1.0), 8: _figures(2.0), 9: _figures(4.0)}
    row = dict(per_seed[7])
    out = over_seeds(row, per_seed)
    assert row == per_seed[7]  # the row's own metrics are left as they were
    # By hand: mean 7/3, s.d. √(7/3), t(0.975, 2 d.o.f.) = 4.302653 (a t table).
    mean, sd, t = 7 / 3, math.sqrt(7 / 3), 4.302652729911275
    half = t * sd / math.sqrt(3)
    assert out["val_mae"] == pytest.approx(mean)
    assert out["val_mae_ci95_low"] == pytest.approx(mean - half)
    assert out["val_mae_ci95_high"] == pytest.approx(mean + half)
    # ... and as scipy gives it.
    low, high = stats.t.interval(0.95, 2, loc=mean, scale=stats.sem([1.0, 2.0, 4.0]))
    assert (out["val_mae_ci95_low"], out["val_mae_ci95_high"]) == pytest.approx((low, high))
    for k, name in enumerate(SEED_FIGURES):  # every figure, each over its own values
        assert out[name] == pytest.approx(mean + k)
        assert out[f"{name}_ci95_high"] - out[f"{name}_ci95_low"] == pytest.approx(2 * half)
    assert out["n_seeds"] == 3
    assert out["seeds"] == {str(s): {n: m[n] for n in SEED_FIGURES} for s, m in per_seed.items()}
    assert out["seeds"]["9"]["val_mae"] == 4.0
    assert out["epoch_s"] == 9.0  # not a figure over seeds: the row's own


def test_one_seed_gives_an_interval_of_zero_width() -> None:
    out = over_seeds(_figures(1.5), {3: _figures(1.5)})
    assert out["val_mae"] == out["val_mae_ci95_low"] == out["val_mae_ci95_high"] == 1.5
    assert out["n_seeds"] == 1 and list(out["seeds"]) == ["3"]


def test_further_seeds_go_beside_the_row(tmp_path: Path) -> None:
    assert further_seed_dirs(tmp_path, 5, 3) == {6: tmp_path / "seeds/6", 7: tmp_path / "seeds/7"}
    assert further_seed_dirs(tmp_path, 5, 1) == {}
    # One seed: nothing to train, the row's metrics as they are.
    metrics = _figures(1.0)
    out = train_further_seeds(metrics=metrics, out_dir=tmp_path, seed=5, seeds=1, fit_kwargs={})
    assert out == metrics and out is not metrics and not (tmp_path / "seeds").exists()


def _parameters(path: Path) -> dict[str, torch.Tensor]:
    """The trainable weights of a model file (not the BatchNorm statistics, which an epoch
    updates whatever the learning rate)."""
    names = {name for name, _ in load_model(path).named_parameters()}
    state = read_model_file(path)["state_dict"]
    return {name: state[name] for name in names}


def _equal(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_further_seeds_start_from_the_pretrained_model(scans: Path, tmp_path: Path) -> None:
    pretrained = tmp_path / "pretrained"
    fit(model_cfg=CNN1D, dataset_dir=scans, out_dir=pretrained, seed=1, lr=0.006, **TINY)
    init = _parameters(pretrained / "model.pt")
    row = tmp_path / "row"
    # The row's own seed (fit refuses a learning rate of 0; fit_stacked takes it).
    metrics = fit(
        model_cfg=CNN1D,
        dataset_dir=scans,
        out_dir=row,
        seed=2,
        lr=0.006,
        init_from=pretrained / "model.pt",
        **TINY,
    )
    kwargs = {"model_cfg": CNN1D, "dataset_dir": scans, "lr": 0.0, **TINY}
    out = train_further_seeds(
        metrics=metrics,
        out_dir=row,
        seed=2,
        seeds=3,
        fit_kwargs=kwargs,
        init_from=pretrained / "model.pt",
    )
    # With a learning rate of 0 the members' weights stay where they started: the
    # pre-trained model's, for every further seed.
    for seed in (3, 4):
        assert _equal(_parameters(row / "seeds" / str(seed) / "last.pt"), init), seed
    assert out["n_seeds"] == 3 and set(out["seeds"]) == {"2", "3", "4"}
    per_seed = [out["seeds"][s]["val_mae"] for s in ("2", "3", "4")]
    assert per_seed[0] == metrics["val_mae"]
    assert out["val_mae"] == pytest.approx(sum(per_seed) / 3)
    # Not a tautology: without init_from the same seeds start from their own random weights.
    fresh = tmp_path / "fresh"
    fit_stacked(out_dirs=[fresh / "3", fresh / "4"], seeds=[3, 4], **kwargs)
    for seed in (3, 4):
        assert not _equal(_parameters(fresh / str(seed) / "last.pt"), init), seed
    assert not _equal(_parameters(fresh / "3" / "last.pt"), _parameters(fresh / "4" / "last.pt"))
