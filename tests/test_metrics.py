"""Table 2 and the modern localization metrics on hand-made cases."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from scanloc.evaluate.metrics import localization_metrics, mahalanobis_sq
from scanloc.evaluate.table2 import evaluate_all, evaluate_dir, metrics_json, round_sig


def _table(est: np.ndarray, cov: np.ndarray | None = None) -> pd.DataFrame:
    table = pd.DataFrame({"step": np.arange(len(est)), "x": est[:, 0], "y": est[:, 1]})
    table["theta"] = est[:, 2]
    if cov is not None:
        table["cov_xx"], table["cov_xy"], table["cov_yy"] = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    return table


def test_table2_uses_absolute_errors_and_population_std() -> None:
    truth = np.zeros((4, 3))
    est = np.array([[0.1, -0.2, 0.0], [-0.3, 0.2, 0.0], [0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]])
    m = localization_metrics(truth, _table(est))
    assert m["x_err_mean"] == pytest.approx(0.15)
    assert m["x_err_std"] == pytest.approx(np.std([0.1, 0.3, 0.1, 0.1]))
    assert m["y_err_mean"] == pytest.approx(0.1)
    assert m["y_err_std"] == pytest.approx(0.1)
    assert m["n_steps"] == 4 and m["frac_missing"] == 0.0


def test_theta_error_is_the_difference_of_sines() -> None:
    truth = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, np.pi / 2]])
    # π − θ has the same sine as θ: the paper's measure calls it perfect, the heading error not.
    est = np.array([[0.0, 0.0, -0.2], [0.0, 0.0, np.pi / 2 - 0.5]])
    m = localization_metrics(truth, _table(est))
    diffs = np.abs([np.sin(0.3) - np.sin(-0.2), 1.0 - np.sin(np.pi / 2 - 0.5)])
    assert m["theta_sin_err_mean"] == pytest.approx(diffs.mean())
    assert m["theta_sin_err_std"] == pytest.approx(diffs.std())
    mirrored = localization_metrics(truth[:1], _table(np.array([[0.0, 0.0, np.pi - 0.3]])))
    assert mirrored["theta_sin_err_mean"] == pytest.approx(0.0, abs=1e-12)
    assert mirrored["heading_err_mean_deg"] == pytest.approx(np.degrees(np.pi - 0.6))


def test_heading_error_wraps_around_pi() -> None:
    truth = np.array([[0.0, 0.0, np.pi - 0.01], [0.0, 0.0, -np.pi + 0.02]])
    est = np.array([[0.0, 0.0, -np.pi + 0.01], [0.0, 0.0, np.pi - 0.02]])
    m = localization_metrics(truth, _table(est))
    assert m["heading_err_mean_deg"] == pytest.approx(np.degrees(0.03))
    assert m["heading_err_median_deg"] == pytest.approx(np.degrees(0.03))


def test_position_statistics_and_shares() -> None:
    errors = np.array([0.05, 0.2, 0.3, 0.6, 2.0])
    truth = np.zeros((5, 3))
    est = np.stack([errors * 0.6, errors * 0.8, np.zeros(5)], axis=1)  # |(dx, dy)| = error
    m = localization_metrics(truth, _table(est), time_per_scan_s=0.002)
    assert m["pos_err_mean_m"] == pytest.approx(errors.mean())
    assert m["pos_err_median_m"] == pytest.approx(0.3)
    assert m["pos_err_rmse_m"] == pytest.approx(np.sqrt(np.mean(errors**2)))
    assert m["pos_err_p95_m"] == pytest.approx(0.6 + 0.8 * (2.0 - 0.6))  # linear, rank 3.8
    assert (m["frac_within_0_1m"], m["frac_within_0_25m"], m["frac_within_0_5m"]) == (
        pytest.approx(0.2),
        pytest.approx(0.4),
        pytest.approx(0.6),
    )
    assert m["frac_gross_over_1m"] == pytest.approx(0.2)
    assert m["time_per_scan_s"] == 0.002
    assert "calib_within_1sigma" not in m  # no covariance columns: no calibration


def test_missing_estimates_are_dropped_and_counted() -> None:
    truth = np.zeros((4, 3))
    est = np.array([[0.1, 0.0, 0.0], [np.nan, np.nan, np.nan], [0.3, 0.0, 0.0], [0.2, 0, 0]])
    m = localization_metrics(truth, _table(est))
    assert m["frac_missing"] == 0.25
    assert m["x_err_mean"] == pytest.approx(0.2)
    none = localization_metrics(truth[:1], _table(est[1:2]))
    assert np.isnan(none["pos_err_mean_m"]) and np.isnan(none["x_err_mean"])


def test_length_mismatch_names_the_file(tmp_path) -> None:
    truth = np.zeros((5, 3))
    with pytest.raises(ValueError, match=r"amcl\.csv.*4 rows.*5 steps"):
        localization_metrics(truth, _table(np.zeros((4, 3))), source="reports/localize/amcl.csv")
    (tmp_path / "loc").mkdir()
    _table(np.zeros((3, 3))).to_csv(tmp_path / "loc" / "cnn_single.csv", index=False)
    np.save(tmp_path / "truth.npy", truth)
    with pytest.raises(ValueError, match=r"cnn_single\.csv"):
        evaluate_dir(
            tmp_path / "truth.npy", tmp_path / "loc", tmp_path / "m.json", tmp_path / "t.md"
        )


def test_calibration_of_a_true_gaussian_matches_chi2() -> None:
    rng = np.random.default_rng(3)
    n = 40_000
    cov = np.array([[0.04, 0.015], [0.015, 0.01]])
    truth = np.zeros((n, 3))
    est = np.zeros((n, 3))
    est[:, :2] = rng.multivariate_normal([0.0, 0.0], cov, size=n)
    m = localization_metrics(truth, _table(est, np.broadcast_to(cov, (n, 2, 2))))
    assert m["calib_within_1sigma"] == pytest.approx(1 - np.exp(-0.5), abs=0.01)  # 39.3 %
    assert m["calib_within_2sigma"] == pytest.approx(1 - np.exp(-2.0), abs=0.01)  # 86.5 %
    over = localization_metrics(truth, _table(est, np.broadcast_to(cov / 9, (n, 2, 2))))
    assert over["calib_within_2sigma"] < 0.3  # overconfident covariances are caught


def test_mahalanobis_handles_degenerate_covariances() -> None:
    err = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 2.0]])
    cov = np.array([np.eye(2), np.zeros((2, 2)), np.diag([1.0, 4.0])])
    np.testing.assert_allclose(mahalanobis_sq(err, cov), [1.0, 0.0, 1.0])
    assert np.isinf(mahalanobis_sq(np.array([[0.1, 0.0]]), np.zeros((1, 2, 2))))[0]


def test_metrics_json_is_stable_and_ordered(tmp_path) -> None:
    truth = np.zeros((3, 3))
    est = np.array([[0.1, 0.0, 0.0], [0.2, 0.1, 0.1], [0.0, 0.3, -0.1]])
    tables = {"cnn_single": _table(est), "amcl": _table(est * 0.5), "zz_new": _table(est)}
    metrics = evaluate_all(truth, tables, {"amcl": 0.0123456789})
    assert list(metrics) == ["amcl", "cnn_single", "zz_new"]
    text = metrics_json(metrics)
    # the bytes do not depend on the order the tables come in
    reordered = dict(reversed(tables.items()))
    assert text == metrics_json(evaluate_all(truth, reordered, {"amcl": 0.0123456789}))
    doc = json.loads(text)
    assert list(doc["amcl"]) == sorted(metrics["amcl"])
    assert doc["amcl"]["time_per_scan_s"] == 0.0123457
    assert "time_per_scan_s" not in doc["cnn_single"]
    assert round_sig(float("nan")) is None and round_sig(7) == 7


def test_evaluate_dir_writes_json_and_table2(tmp_path) -> None:
    truth = np.zeros((3, 3))
    loc = tmp_path / "localize"
    loc.mkdir()
    _table(np.full((3, 3), 0.1)).to_csv(loc / "amcl.csv", index=False)
    (loc / "amcl_timing.json").write_text('{"time_per_scan_s": 0.5}')
    out_json, out_md = tmp_path / "metrics" / "localization.json", tmp_path / "table2.md"
    np.save(tmp_path / "truth.npy", truth)
    evaluate_dir(tmp_path / "truth.npy", loc, out_json, out_md)
    doc = json.loads(out_json.read_text())
    assert doc["amcl"]["x_err_mean"] == 0.1 and doc["amcl"]["time_per_scan_s"] == 0.5
    md = out_md.read_text()
    assert "| amcl | 0.1000 | 0.0000 |" in md
    assert md.rstrip().splitlines()[-1].endswith("| 500 |")  # the modern table's time in ms
