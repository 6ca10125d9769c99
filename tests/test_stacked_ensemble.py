"""Members trained together must be the members `fit` trains alone."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from scanloc.models.cnn1d import Cnn1d
from scanloc.models.mlp import Mlp
from scanloc.models.stacked_ensemble import StackedMembers, fit_stacked
from scanloc.models.training import MACHINE_KEYS, fit, load_model, read_model_file

CNN1D = {"_target_": "scanloc.models.cnn1d.Cnn1d", "pool_size": 8, "dropout": 0.2}
COMMON = {"epochs": 2, "batch_size": 32, "lr": 0.006, "lr_decay": 0.01, "max_samples": 128}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.parametrize("precision", ["32-true", "bf16-mixed"])
def test_each_member_equals_fit_with_its_seed(scans: Path, tmp_path: Path, precision: str) -> None:
    seeds = [4, 9, 6]
    together = [tmp_path / f"member_{k}" for k in range(3)]
    trainer = {"precision": precision}
    results = fit_stacked(
        model_cfg=CNN1D,
        dataset_dir=scans,
        out_dirs=together,
        seeds=seeds,
        trainer_cfg=trainer,
        **COMMON,
    )
    assert [r["stacked_members"] for r in results] == [3, 3, 3]
    assert [r["precision"] for r in results] == [precision] * 3
    fit(
        model_cfg=CNN1D,
        dataset_dir=scans,
        out_dir=tmp_path / "alone",
        seed=9,
        trainer_cfg=trainer,
        **COMMON,
    )
    # Same initialisation, data order, dropout masks, Adam state and BatchNorm statistics:
    # the very same files (dropout included, in the default "loop" mode).
    for name in ("model.pt", "last.pt", "history.csv"):
        assert (together[1] / name).read_bytes() == (tmp_path / "alone" / name).read_bytes()
    alone = json.loads((tmp_path / "alone" / "metrics.json").read_text())
    # the model folder's metrics leave out what measures the machine (epoch_s, device)
    left_out = (*MACHINE_KEYS, "stacked_members")
    assert {k: v for k, v in results[1].items() if k not in left_out} == alone
    assert results[1]["device"]["type"] == "cpu" and results[1]["epoch_s"] > 0
    # The members are different models.
    weights = [read_model_file(d / "last.pt")["state_dict"]["head.0.weight"] for d in together]
    assert not torch.equal(weights[0], weights[1]) and not torch.equal(weights[0], weights[2])
    assert load_model(together[2] / "model.pt")(torch.rand(4, 64)).shape == (4, 3)


def test_vmap_mode_matches_loop_mode_in_one_step() -> None:
    torch.manual_seed(0)
    # float64, so that kernel-order rounding (amplified by BatchNorm) stays negligible.
    for make in (lambda: Mlp(64, dropout=0.0), lambda: Cnn1d(64, pool_size=8)):
        models = [make().double() for _ in range(3)]
        xs = [torch.rand(16, 64, dtype=torch.float64) * 7 for _ in range(3)]
        ys = [torch.randn(16, 3, dtype=torch.float64) for _ in range(3)]
        outs, grads, stats = {}, {}, {}
        for mode in ("loop", "vmap"):
            members = StackedMembers(models, torch.device("cpu"), mode)
            members.train(True)
            preds = members.backward_each(list(zip(xs, ys, strict=True)))
            outs[mode] = torch.stack(preds)
            grads[mode] = {k: v.grad.clone() for k, v in members.params.items()}
            stats[mode] = {k: v.clone() for k, v in members.buffers.items()}
        torch.testing.assert_close(outs["vmap"], outs["loop"], rtol=1e-9, atol=1e-9)
        for key, grad in grads["loop"].items():
            torch.testing.assert_close(grads["vmap"][key], grad, rtol=1e-7, atol=1e-9)
        for key, value in stats["loop"].items():  # BatchNorm running statistics per member
            torch.testing.assert_close(stats["vmap"][key], value, rtol=1e-9, atol=1e-12)
        assert all(value.shape[0] == 3 for value in stats["loop"].values())


def test_vmap_mode_trains_and_writes_member_files(scans: Path, tmp_path: Path) -> None:
    dirs = [tmp_path / "a", tmp_path / "b"]
    cfg = CNN1D | {"dropout": 0.0}
    results = fit_stacked(
        model_cfg=cfg, dataset_dir=scans, out_dirs=dirs, seeds=[1, 2], mode="vmap", **COMMON
    )
    assert all(r["epochs"] == 2 and r["val_mae"] > 0 for r in results)
    for d in dirs:
        assert {p.name for p in d.iterdir()} >= {
            "model.pt",
            "last.pt",
            "history.csv",
            "metrics.json",
        }


def test_bad_arguments(scans: Path, tmp_path: Path) -> None:
    args = {"model_cfg": CNN1D, "dataset_dir": scans, **COMMON}
    with pytest.raises(ValueError, match="one out_dir per seed"):
        fit_stacked(out_dirs=[tmp_path], seeds=[1, 2], **args)
    with pytest.raises(ValueError, match="seeds must differ"):
        fit_stacked(out_dirs=[tmp_path / "a", tmp_path / "b"], seeds=[1, 1], **args)
    with pytest.raises(ValueError, match="mode"):
        fit_stacked(out_dirs=[tmp_path], seeds=[1], mode="threads", **args)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="'16-mixed': fit_stacked trains in 32-true or bf16"):
        fit_stacked(out_dirs=[tmp_path], seeds=[1], trainer_cfg={"precision": "16-mixed"}, **args)
