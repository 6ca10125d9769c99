"""The claim-by-claim verdict rules of the report."""

from __future__ import annotations

import numpy as np
import pandas as pd

from scanloc.report.claims import (
    NOT_REPRODUCED,
    NOT_TESTABLE,
    PARTLY,
    REPRODUCED,
    Run,
    check_claims,
    claim_1,
    claim_2,
    claim_3,
    claim_4,
    claim_5,
    claim_6,
    claim_7,
)


def _run(
    val: float,
    train: float | None = None,
    epoch_s: float = 1.0,
    samples: int = 20000,
    curve: np.ndarray | None = None,
) -> Run:
    curve = np.array([val]) if curve is None else curve
    history = pd.DataFrame({"epoch": np.arange(1, len(curve) + 1), "val_mae": curve})
    history["train_mae"] = curve if train is None else train
    return Run(history, {"val_mae": val, "epoch_s": epoch_s}, {"samples": samples, "epochs": 4})


def test_claim_1_compares_both_1d_cnns_with_the_mlp() -> None:
    runs = {"mlp": _run(2.5), "cnn1d_20k": _run(0.4), "cnn1d_200k": _run(0.15)}
    assert claim_1(runs).verdict == REPRODUCED
    assert claim_1(runs | {"cnn1d_20k": _run(3.0)}).verdict == PARTLY
    assert claim_1(runs | {"mlp": _run(0.1)}).verdict == NOT_REPRODUCED
    missing = claim_1({"mlp": _run(2.5)})
    assert missing.verdict == NOT_TESTABLE and "cnn1d_20k" in missing.ours


def test_claim_2_thresholds() -> None:
    runs = {"cnn1d_20k": _run(0.4), "cnn1d_200k": _run(0.2)}
    assert claim_2(runs | {"cnn2d": _run(0.75, train=0.95)}).verdict == REPRODUCED
    assert claim_2(runs | {"cnn2d": _run(0.69, train=0.9)}).verdict == PARTLY
    assert claim_2(runs | {"cnn2d": _run(0.1)}).verdict == NOT_REPRODUCED
    assert claim_2({"cnn2d": _run(1.0)}).verdict == NOT_TESTABLE


def test_claims_3_and_4_use_time_per_sample() -> None:
    small = _run(0.4, epoch_s=5.0)
    slow_2d = _run(1.0, epoch_s=60.0)
    assert claim_3({"cnn1d_20k": small, "cnn2d": slow_2d}, "cpu").verdict == REPRODUCED
    fast_2d = _run(1.0, epoch_s=10.0)
    assert claim_3({"cnn1d_20k": small, "cnn2d": fast_2d}, "cpu").verdict == PARTLY
    large = _run(0.15, epoch_s=55.0, samples=200000)
    assert claim_4({"cnn1d_20k": small, "cnn1d_200k": large}, "cpu").verdict == REPRODUCED
    too_slow = _run(0.15, epoch_s=500.0, samples=200000)
    assert claim_4({"cnn1d_20k": small, "cnn1d_200k": too_slow}, "cpu").verdict == NOT_REPRODUCED


def test_claim_5_needs_more_data_to_help() -> None:
    small = _run(0.4)
    assert claim_5({"cnn1d_20k": small, "cnn1d_200k": _run(0.14, 0.13)}).verdict == REPRODUCED
    assert claim_5({"cnn1d_20k": small, "cnn1d_200k": _run(0.3, 0.1)}).verdict == PARTLY
    assert claim_5({"cnn1d_20k": small, "cnn1d_200k": _run(0.5)}).verdict == NOT_REPRODUCED


def test_claim_6_compares_the_early_epochs() -> None:
    slow = np.array([3.0, 2.0, 1.0, 0.9, 0.8, 0.7, 0.6, 0.5])
    fast = np.array([1.5, 1.0, 0.8, 0.7, 0.6, 0.6, 0.5, 0.5])
    runs = {"cnn1d_20k": _run(0.3), "transfer/scratch": _run(0.5, curve=slow)}
    assert claim_6(runs | {"transfer/pretrained": _run(0.5, curve=fast)}).verdict == REPRODUCED
    assert claim_6(runs | {"transfer/pretrained": _run(0.5, curve=slow + 1)}).verdict == PARTLY
    assert claim_6({"cnn1d_20k": _run(0.3)}).verdict == NOT_TESTABLE


def test_claim_7_localization() -> None:
    metrics = {
        "amcl": {"pos_err_mean_m": 0.05},
        "cnn_single": {"pos_err_mean_m": 0.3, "frac_gross_over_1m": 0.05, "pos_err_p95_m": 0.9},
        "cnn_ensemble": {
            "pos_err_mean_m": 0.2,
            "frac_gross_over_1m": 0.01,
            "pos_err_p95_m": 0.5,
            "calib_within_2sigma": 0.6,
        },
    }
    claim = claim_7(metrics)
    assert claim.verdict == REPRODUCED and "0.250 m" in claim.ours
    worse = metrics | {"cnn_ensemble": metrics["cnn_ensemble"] | {"frac_gross_over_1m": 0.2}}
    assert claim_7(worse).verdict == PARTLY
    assert claim_7({"amcl": {}}).verdict == NOT_TESTABLE
    assert [c.number for c in check_claims({}, metrics, "cpu")] == list(range(1, 8))
