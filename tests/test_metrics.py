"""Table 2 and the modern localization metrics on hand-made cases."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from scanloc.evaluate.metrics import (
    convergence_metrics,
    localization_metrics,
    mahalanobis_sq,
    staying_right_metrics,
)
from scanloc.evaluate.table2 import evaluate_all, evaluate_runs, metrics_json, round_sig
from scanloc.pose import recall_within


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
    m = localization_metrics(truth, _table(est))
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
    (tmp_path / "loc" / "run").mkdir(parents=True)
    _table(np.zeros((3, 3))).to_csv(tmp_path / "loc" / "run" / "cnn_single.csv", index=False)
    (tmp_path / "traj" / "run").mkdir(parents=True)
    np.save(tmp_path / "traj" / "run" / "truth.npy", truth)
    with pytest.raises(ValueError, match=r"cnn_single\.csv"):
        evaluate_runs(["run"], tmp_path / "traj", [tmp_path / "loc"], tmp_path / "m.json", tmp_path)


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
    metrics = evaluate_all(truth, tables)
    assert list(metrics) == ["amcl", "cnn_single", "zz_new"]
    text = metrics_json(metrics)
    # the bytes do not depend on the order the tables come in
    reordered = dict(reversed(tables.items()))
    assert text == metrics_json(evaluate_all(truth, reordered))
    doc = json.loads(text)
    assert list(doc["amcl"]) == sorted(metrics["amcl"])
    assert doc["amcl"]["pos_err_mean_m"] == round_sig(metrics["amcl"]["pos_err_mean_m"])
    assert round_sig(float("nan")) is None and round_sig(7) == 7
    assert round_sig(0.0123456789) == 0.0123457


def test_evaluate_runs_writes_json_and_table2(tmp_path) -> None:
    run = "room_drive"
    (tmp_path / "traj" / run).mkdir(parents=True)
    np.save(tmp_path / "traj" / run / "truth.npy", np.zeros((3, 3)))
    for folder, method in (("localize", "amcl"), ("localize_cnn", "cnn_single")):
        (tmp_path / folder / run).mkdir(parents=True)
        _table(np.full((3, 3), 0.1)).to_csv(tmp_path / folder / run / f"{method}.csv", index=False)
    out_json = tmp_path / "metrics" / "localization.json"
    evaluate_runs(
        [run],
        tmp_path / "traj",
        [tmp_path / "localize", tmp_path / "localize_cnn"],
        out_json,
        tmp_path / "table2",
    )
    text = out_json.read_text()
    doc = json.loads(text)
    assert set(doc[run]) == {"amcl", "cnn_single"}  # both folders, one trajectory
    assert doc[run]["amcl"]["x_err_mean"] == 0.1
    # no wall clock in the hashed output: the same estimates give the same bytes anywhere
    assert "time_per_scan" not in text and "setup_s" not in text
    md = (tmp_path / "table2" / f"{run}.md").read_text()
    assert "| amcl | 0.1000 | 0.0000 |" in md
    assert "## Global localization and kidnapping" in md


def _errors_table(pos: list[float], heading_deg: float = 0.0) -> tuple[np.ndarray, pd.DataFrame]:
    """A truth at the origin and estimates `pos` metres off along x (NaN: no estimate)."""
    est = np.zeros((len(pos), 3))
    est[:, 0] = pos
    est[:, 2] = np.radians(heading_deg)
    return np.zeros((len(pos), 3)), _table(est)


def test_steps_to_converge_is_the_first_of_20_good_steps() -> None:
    # lost for 5 steps, good for 10, lost again at step 15, then good from step 17 on
    pos = [2.0] * 5 + [0.1] * 10 + [0.7, 0.9] + [0.2] * 30
    truth, table = _errors_table(pos)
    m = convergence_metrics(truth, table)
    assert m["steps_to_converge"] == 17
    assert m["tracking_pos_err_mean_m"] == pytest.approx(0.2)  # only the converged stretch
    assert m["tracking_share"] == pytest.approx(30 / len(pos))
    assert m["frac_lost"] == pytest.approx(5 / len(pos))
    assert "recovery_steps_max" not in m  # no kidnaps
    assert m["converged"] == 1
    # a heading 10° off is not converged, whatever the position: censored at the run's length
    never = convergence_metrics(*_errors_table([0.0] * 40, heading_deg=10.5))
    assert never["steps_to_converge"] == 40 and never["converged"] == 0


def test_recovery_steps_count_from_each_kidnap() -> None:
    # converged from 0; kidnap at 30: lost 4 steps; kidnap at 60: never recovers before 90
    pos = [0.1] * 30 + [3.0] * 4 + [0.1] * 26 + [3.0] * 30
    truth, table = _errors_table(pos)
    m = convergence_metrics(truth, table, kidnap_steps=(30, 60))
    assert m["steps_to_converge"] == 0
    assert m["recovery_steps_1"] == 4
    # the second never recovers: censored at its stretch's 30 steps, and not counted
    assert m["recovery_steps_2"] == 30 and m["recovered"] == 1 and m["kidnaps"] == 2
    assert m["recovery_steps_max"] == 30 and m["recovery_steps_mean"] == 17
    m2 = convergence_metrics(truth, table, kidnap_steps=(30,))
    assert m2["recovery_steps_max"] == 4 and m2["recovery_steps_mean"] == 4
    # a recovery must hold 20 steps before the next kidnap: 26 - 20 steps of slack here
    assert convergence_metrics(truth, table, kidnap_steps=(30, 50))["recovered"] == 0
    # a missing estimate counts as lost
    gap = [0.1] * 10 + [np.nan] + [0.1] * 25
    assert convergence_metrics(*_errors_table(gap))["steps_to_converge"] == 11


def test_recall_counts_the_truth_near_any_hypothesis() -> None:
    truth = np.zeros((3, 3))
    hyp = np.zeros((3, 2, 3))
    hyp[0] = [[2.0, 0.0, 0.0], [0.4, 0.0, 0.0]]  # the second is within 0.5 m
    hyp[1] = [[0.0, 0.0, 0.2], [0.6, 0.0, 0.0]]  # 11.5° and 0.6 m: neither
    hyp[2] = [[0.3, 0.3, np.radians(-9.0)], [5.0, 5.0, 0.0]]
    np.testing.assert_array_equal(recall_within(hyp, truth), [True, False, True])
    np.testing.assert_array_equal(recall_within(hyp[:, :1], truth), [False, False, True])


def _confident_table(
    pos: list[float], std_m: float | list[float]
) -> tuple[np.ndarray, pd.DataFrame]:
    """`_errors_table` with an isotropic position covariance of standard deviation `std_m`."""
    truth, table = _errors_table(pos)
    var = np.broadcast_to(np.square(std_m), len(pos))
    table["cov_xx"], table["cov_xy"], table["cov_yy"] = var, 0.0, var
    return truth, table


def test_relosses_count_each_loss_of_a_converged_filter_once() -> None:
    # converged (20 good), off for 4 steps (not a re-loss), good 25, off 6 (re-loss 1),
    # off again at once for 7 before re-converging (the same loss), good 20, off 5 (re-loss 2)
    pos = [0.1] * 20 + [0.8] * 4 + [0.1] * 25 + [0.8] * 6 + [0.1] * 3 + [0.8] * 7
    pos += [0.1] * 20 + [0.8] * 5
    truth, table = _errors_table(pos)
    assert staying_right_metrics(truth, table)["relosses"] == 2
    # lost before ever converging: no re-loss; a missing estimate is a bad step
    assert (
        staying_right_metrics(*_errors_table([0.8] * 10 + [0.1] * 19 + [0.8] * 9))["relosses"] == 0
    )
    gaps = [0.1] * 20 + [np.nan] * 5 + [0.1] * 5
    assert staying_right_metrics(*_errors_table(gaps))["relosses"] == 1
    # a kidnap is not a re-loss, and resets convergence: the stretch after it starts unconverged
    kidnapped = [0.1] * 30 + [3.0] * 10 + [0.1] * 30
    assert staying_right_metrics(*_errors_table(kidnapped), kidnap_steps=(30,))["relosses"] == 0
    assert staying_right_metrics(*_errors_table(kidnapped))["relosses"] == 1


def test_false_convergence_is_confidence_on_a_wrong_pose() -> None:
    # uncertain and wrong 10 steps, then confident on a twin 2 m off for 25 steps, then right
    pos = [2.0] * 35 + [0.1] * 30
    std = [3.0] * 10 + [0.2] * 55
    m = staying_right_metrics(*_confident_table(pos, std))
    assert m["false_convergences"] == 1
    # 19 confident wrong steps are not enough; uncertain wrong steps are merely lost
    assert (
        staying_right_metrics(*_confident_table([2.0] * 19 + [0.1] * 30, 0.2))["false_convergences"]
        == 0
    )
    assert staying_right_metrics(*_confident_table([2.0] * 40, 0.8))["false_convergences"] == 0
    # a heading 15° off on the right spot is a wrong mode too
    truth, table = _confident_table([0.0] * 30, 0.1)
    table["theta"] = np.radians(15.0)
    assert staying_right_metrics(truth, table)["false_convergences"] == 1
    # two separate wrong locks count twice
    twice = [2.0] * 20 + [0.1] * 5 + [2.0] * 20
    assert staying_right_metrics(*_confident_table(twice, 0.2))["false_convergences"] == 2


def test_false_convergence_skips_the_belief_a_kidnap_carries_over() -> None:
    # tracking right, kidnapped at 30: the old belief stays confident and wrong for 25 steps
    pos = [0.1] * 30 + [3.0] * 25 + [0.1] * 20
    truth, table = _confident_table(pos, 0.2)
    assert staying_right_metrics(truth, table, kidnap_steps=(30,))["false_convergences"] == 0
    assert staying_right_metrics(truth, table)["false_convergences"] == 1  # no kidnap: a lock
    # after the kidnap the filter spreads out, then locks onto a wrong pose: counted
    std = [0.2] * 30 + [2.0] * 5 + [0.2] * 40
    truth, table = _confident_table(pos, std)
    assert staying_right_metrics(truth, table, kidnap_steps=(30,))["false_convergences"] == 1
    # without a covariance the filter has no measure of its own: no figure
    assert "false_convergences" not in staying_right_metrics(*_errors_table(pos))


def test_kidnaps_recovered_frac_counts_recoveries_within_20_steps() -> None:
    # kidnap at 50: back after 20 steps (counted); at 100: after 21 (recovered, not counted)
    pos = [0.1] * 50 + [3.0] * 20 + [0.1] * 30 + [3.0] * 21 + [0.1] * 29
    m = convergence_metrics(*_errors_table(pos), kidnap_steps=(50, 100))
    assert (m["recovery_steps_1"], m["recovery_steps_2"]) == (20, 21)
    assert m["recovered"] == 2 and m["kidnaps_recovered_frac"] == 0.5
    # a stretch shorter than 20 steps that never recovers is not a quick recovery
    short = [0.1] * 30 + [3.0] * 10
    assert (
        convergence_metrics(*_errors_table(short), kidnap_steps=(30,))["kidnaps_recovered_frac"]
        == 0
    )
