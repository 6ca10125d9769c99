"""Error metrics of a localizer's per-step estimates against the true trajectory.

Table 2 of the paper: "the mean as well as the standard deviation of the pose estimation error
(x, y, θ)", the θ error being "the difference between the sinus values of the true orientation
and the predicted one". The means here are of ABSOLUTE errors (|x_est − x_true|,
|sin θ_true − sin θ_est|), i.e. error magnitudes, and the standard deviations are those of the
same absolute errors (population, divisor n). The sine difference is the paper's; note that it
cannot tell θ from π − θ, so the wrapped heading error in degrees is reported beside it.

Modern metrics: position error statistics, wrapped heading error, shares of steps within 0.1 /
0.25 / 0.5 m, gross failures over 1 m and, for localizers with a covariance, the calibration of
the 2×2 position covariance: the share of steps whose truth lies inside the 1σ / 2σ ellipse
(squared Mahalanobis distance ≤ 1 / ≤ 4; a calibrated Gaussian gives 39.3 % / 86.5 %).

Steps whose estimate is not finite count as missing: every statistic is taken over the valid
steps and `frac_missing` says how many were dropped.

Global localization and kidnapping (`convergence_metrics`): a localizer has converged at step s
when its error stays below 0.5 m and 10° for the 20 steps from s on (a missing estimate counts
as lost). `steps_to_converge` is the first such step of the run (before its first kidnap);
`recovery_steps_<k>` counts from the k-th kidnap to the first converged step after it (before
the next kidnap), summarised by their max and mean and the number `recovered`. A localizer
that never converges in a stretch gets the stretch's length, a censored count ("not within
these N steps"), so that every metric stays a number that DVC can show and compare; the flags
`converged` (0/1) and `recovered` (of `kidnaps`) say which counts are censored. The tracking
errors are taken over the converged stretches only (from convergence or recovery to the next
kidnap); `frac_lost` is the share of all steps more than 1 m off. `kidnaps_recovered_frac` is
the share of kidnaps recovered within `RECOVERED_WITHIN_STEPS` (20) steps (recovery_steps ≤ 20).

Staying right (`staying_right_metrics`): a converged filter can lose the pose again, or
converge on the wrong pose. `relosses` counts re-losses: within each stretch between kidnaps,
once converged (as above), a run of `RELOSS_STEPS` (5) or more consecutive steps that are not
good (error ≥ 0.5 m or ≥ 10°, or no estimate) is one re-loss; the filter counts as converged
again only after another 20 good steps in a row, so a long loss is one re-loss, not many.
`false_convergences` counts convergences on a wrong mode: maximal stretches of at least 20
consecutive steps in which the filter is confident by its own measure (the larger standard
deviation of its 2×2 position covariance ≤ `CONFIDENT_STD_M`, 0.5 m: its belief fits inside
the convergence radius) while its estimate is not good. A stretch that begins at a kidnap
step is a belief carried over by the kidnap, scored by the recovery metrics, and not counted.
A localizer without a position covariance has no measure of its own: no false_convergences.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pandas as pd

from scanloc.estimates import table_poses
from scanloc.pose import wrap_angle

POSE_COLUMNS = ("x", "y", "theta")
POSITION_COV_COLUMNS = ("cov_xx", "cov_xy", "cov_yy")
WITHIN_THRESHOLDS_M = {"frac_within_0_1m": 0.1, "frac_within_0_25m": 0.25, "frac_within_0_5m": 0.5}
GROSS_FAILURE_M = 1.0


CONVERGED_DISTANCE_M = 0.5
CONVERGED_ANGLE_DEG = 10.0
CONVERGED_STEPS = 20
RECOVERED_WITHIN_STEPS = 20
RELOSS_STEPS = 5
CONFIDENT_STD_M = 0.5


def read_estimates(path: Path) -> pd.DataFrame:
    """Read a per-step estimate table (CSV) and check it has the pose columns."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: estimate table not found")
    try:
        table = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable CSV estimate table: {exc}") from exc
    check_table(table, source=str(path))
    return table


def check_table(table: pd.DataFrame, source: str, steps: int | None = None) -> None:
    """Raise a ValueError naming `source` on missing pose columns or a length unlike the truth's."""
    missing = [c for c in POSE_COLUMNS if c not in table.columns]
    if missing:
        raise ValueError(f"{source}: missing column(s) {missing}; expected at least {POSE_COLUMNS}")
    if steps is not None and len(table) != steps:
        raise ValueError(f"{source}: {len(table)} rows, but the true trajectory has {steps} steps")
    if steps is not None and "step" in table.columns:
        if not np.array_equal(table["step"].to_numpy(), np.arange(steps)):
            raise ValueError(f"{source}: column 'step' must be 0, 1, ..., {steps - 1}")


def _stats(values: np.ndarray, prefix: str) -> dict[str, float]:
    if values.size == 0:
        return {f"{prefix}_mean": np.nan, f"{prefix}_std": np.nan}
    return {f"{prefix}_mean": float(values.mean()), f"{prefix}_std": float(values.std())}


def _share(mask: np.ndarray) -> float:
    return float(mask.mean()) if mask.size else np.nan


def mahalanobis_sq(error: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance of 2D errors (n, 2) under 2×2 covariances (n, 2, 2).

    A covariance that is not positive definite gives +inf (the truth lies outside any ellipse
    of a degenerate estimate), unless the error is exactly zero.
    """
    sxx, sxy, syy = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = sxx * syy - sxy * sxy
    dx, dy = error[:, 0], error[:, 1]
    quad = syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = np.where((det > 0) & (sxx > 0), quad / det, np.inf)
    return np.where((dx == 0) & (dy == 0), 0.0, d2)


def localization_metrics(
    truth: np.ndarray,
    table: pd.DataFrame,
    time_per_scan_s: float | None = None,
    source: str = "estimate table",
) -> dict[str, float]:
    """Table 2 and the modern metrics of one localizer (see the module docstring).

    Args:
        truth: (T, 3) true x, y, θ per step.
        table: per-step estimates with at least x, y, theta; cov_xx, cov_xy, cov_yy if any.
        time_per_scan_s: measured cost per scan, copied into the result when given.
        source: file or method name used in error messages.
    """
    truth = np.asarray(truth, dtype=np.float64)
    if truth.ndim != 2 or truth.shape[1] != 3:
        raise ValueError(f"truth must have shape (T, 3), got {truth.shape}")
    check_table(table, source, steps=truth.shape[0])
    est = table_poses(table)
    valid = np.isfinite(est).all(axis=1) & np.isfinite(truth).all(axis=1)
    est, true = est[valid], truth[valid]

    dx, dy = est[:, 0] - true[:, 0], est[:, 1] - true[:, 1]
    pos_err = np.hypot(dx, dy)
    heading_deg = np.degrees(np.abs(wrap_angle(est[:, 2] - true[:, 2])))
    out: dict[str, float] = {"n_steps": truth.shape[0], "frac_missing": _share(~valid)}
    out |= _stats(np.abs(dx), "x_err")
    out |= _stats(np.abs(dy), "y_err")
    out |= _stats(np.abs(np.sin(true[:, 2]) - np.sin(est[:, 2])), "theta_sin_err")
    empty = pos_err.size == 0
    out["pos_err_mean_m"] = np.nan if empty else float(pos_err.mean())
    out["pos_err_median_m"] = np.nan if empty else float(np.median(pos_err))
    out["pos_err_rmse_m"] = np.nan if empty else float(np.sqrt(np.mean(pos_err**2)))
    out["pos_err_p95_m"] = np.nan if empty else float(np.percentile(pos_err, 95))
    out["heading_err_mean_deg"] = np.nan if empty else float(heading_deg.mean())
    out["heading_err_median_deg"] = np.nan if empty else float(np.median(heading_deg))
    out["heading_err_rmse_deg"] = np.nan if empty else float(np.sqrt(np.mean(heading_deg**2)))
    for key, limit in WITHIN_THRESHOLDS_M.items():
        out[key] = _share(pos_err < limit)
    out["frac_gross_over_1m"] = _share(pos_err > GROSS_FAILURE_M)
    out |= _calibration(table, valid, np.stack([dx, dy], axis=1))
    if time_per_scan_s is not None:
        out["time_per_scan_s"] = float(time_per_scan_s)
    return out


def _calibration(table: pd.DataFrame, valid: np.ndarray, error: np.ndarray) -> dict[str, float]:
    """Shares of steps inside the 1σ / 2σ position ellipses; empty if the table has no
    covariance (a single network) or none of its valid steps has a finite one."""
    if not all(c in table.columns for c in POSITION_COV_COLUMNS):
        return {}
    sxx, sxy, syy = (table[c].to_numpy(dtype=np.float64)[valid] for c in POSITION_COV_COLUMNS)
    has_cov = np.isfinite(sxx) & np.isfinite(sxy) & np.isfinite(syy)
    if not has_cov.any():
        return {}
    cov = np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)[has_cov]
    d2 = mahalanobis_sq(error[has_cov], cov)
    return {"calib_within_1sigma": _share(d2 <= 1.0), "calib_within_2sigma": _share(d2 <= 4.0)}


CALIBRATION_BINS = 10


def reliability_bins(
    scores: np.ndarray, hits: np.ndarray, bins: int = CALIBRATION_BINS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per equal-width score bin over [0, 1]: (count, mean score, share of hits); NaN where
    a bin is empty. The reliability diagram plots the last against the second."""
    scores = np.clip(np.asarray(scores, dtype=np.float64), 0.0, 1.0)
    hits = np.asarray(hits, dtype=np.float64)
    index = np.minimum((scores * bins).astype(int), bins - 1)
    count = np.bincount(index, minlength=bins).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        confidence = np.bincount(index, scores, minlength=bins) / count
        accuracy = np.bincount(index, hits, minlength=bins) / count
    return count, confidence, accuracy


def expected_calibration_error(
    scores: np.ndarray, hits: np.ndarray, bins: int = CALIBRATION_BINS
) -> float:
    """Σ_bins (n_b / N)·|hit rate_b - mean score_b| over equal-width bins (Guo et al. 2017):
    0 when a score of p is right a share p of the time."""
    count, confidence, accuracy = reliability_bins(scores, hits, bins)
    if count.sum() == 0:
        return float("nan")
    filled = count > 0
    gap = np.abs(accuracy[filled] - confidence[filled])
    return float((count[filled] * gap).sum() / count.sum())


def first_converged(good: np.ndarray, start: int, stop: int, window: int = CONVERGED_STEPS) -> int:
    """The first step s in [start, stop - window] with good[s : s + window] all True, or -1."""
    run = 0
    for step in range(start, stop):
        run = run + 1 if good[step] else 0
        if run == window:
            return step - window + 1
    return -1


def convergence_metrics(
    truth: np.ndarray, table: pd.DataFrame, kidnap_steps: tuple[int, ...] = ()
) -> dict[str, float]:
    """steps_to_converge, recovery_steps per kidnap, tracking errors after convergence and
    frac_lost (see the module docstring)."""
    truth = np.asarray(truth, dtype=np.float64)
    est = table_poses(table)
    pos = np.hypot(est[:, 0] - truth[:, 0], est[:, 1] - truth[:, 1])
    heading = np.degrees(np.abs(wrap_angle(est[:, 2] - truth[:, 2])))
    with np.errstate(invalid="ignore"):
        good = (pos < CONVERGED_DISTANCE_M) & (heading < CONVERGED_ANGLE_DEG)
        lost = ~(pos <= GROSS_FAILURE_M)  # NaN (no estimate) counts as lost
    bounds = [0, *kidnap_steps, len(truth)]
    tracking = np.zeros(len(truth), dtype=bool)
    out: dict[str, float] = {}
    recoveries = []
    recovered = quick = 0
    for k, (start, stop) in enumerate(itertools.pairwise(bounds)):
        s = first_converged(good, start, stop)
        if s >= 0:
            tracking[s:stop] = True
        steps = float(s - start) if s >= 0 else float(stop - start)  # censored: the stretch
        if k == 0:
            out["steps_to_converge"] = steps
            out["converged"] = int(s >= 0)
        else:
            recoveries.append(steps)
            recovered += int(s >= 0)
            quick += int(0 <= s - start <= RECOVERED_WITHIN_STEPS)
            out[f"recovery_steps_{k}"] = steps
    if recoveries:
        out["recovery_steps_max"] = max(recoveries)
        out["recovery_steps_mean"] = float(np.mean(recoveries))
        out["recovered"] = recovered
        out["kidnaps"] = len(recoveries)
        out["kidnaps_recovered_frac"] = quick / len(recoveries)
    track = tracking & np.isfinite(pos)
    out["tracking_pos_err_mean_m"] = float(pos[track].mean()) if track.any() else np.nan
    out["tracking_pos_err_median_m"] = float(np.median(pos[track])) if track.any() else np.nan
    out["tracking_heading_err_mean_deg"] = float(heading[track].mean()) if track.any() else np.nan
    out["tracking_share"] = float(track.mean())
    out["frac_lost"] = float(lost.mean())
    return out


def _good_steps(truth: np.ndarray, table: pd.DataFrame) -> np.ndarray:
    """Per step: the estimate is within 0.5 m and 10° of the truth (no estimate: not good)."""
    truth = np.asarray(truth, dtype=np.float64)
    est = table_poses(table)
    pos = np.hypot(est[:, 0] - truth[:, 0], est[:, 1] - truth[:, 1])
    heading = np.degrees(np.abs(wrap_angle(est[:, 2] - truth[:, 2])))
    with np.errstate(invalid="ignore"):
        return (pos < CONVERGED_DISTANCE_M) & (heading < CONVERGED_ANGLE_DEG)


def confident_steps(table: pd.DataFrame) -> np.ndarray | None:
    """Per step: the filter's own position covariance has its larger standard deviation
    ≤ CONFIDENT_STD_M; None for a table without covariance columns or any finite covariance."""
    if not all(c in table.columns for c in POSITION_COV_COLUMNS):
        return None
    sxx, sxy, syy = (table[c].to_numpy(dtype=np.float64) for c in POSITION_COV_COLUMNS)
    if not np.isfinite(sxx + sxy + syy).any():
        return None
    # Larger eigenvalue of [[sxx, sxy], [sxy, syy]].
    largest = 0.5 * (sxx + syy) + np.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)
    with np.errstate(invalid="ignore"):
        return largest <= CONFIDENT_STD_M**2  # NaN: not confident


def count_relosses(good: np.ndarray, start: int, stop: int) -> int:
    """Re-losses in good[start:stop] (see the module docstring): after CONVERGED_STEPS good
    steps in a row, RELOSS_STEPS bad ones in a row are one re-loss and end the convergence."""
    relosses, converged, good_run, bad_run = 0, False, 0, 0
    for step in range(start, stop):
        if good[step]:
            good_run, bad_run = good_run + 1, 0
            converged = converged or good_run >= CONVERGED_STEPS
        else:
            good_run, bad_run = 0, bad_run + 1
            if converged and bad_run >= RELOSS_STEPS:
                relosses, converged = relosses + 1, False
    return relosses


def count_false_convergences(
    good: np.ndarray, confident: np.ndarray, kidnap_steps: tuple[int, ...] = ()
) -> int:
    """Maximal stretches of ≥ CONVERGED_STEPS steps confident but not good, not beginning at a
    kidnap step (see the module docstring)."""
    wrong = confident & ~good
    count, run_start = 0, -1
    for step in range(len(wrong) + 1):
        if step < len(wrong) and wrong[step]:
            run_start = step if run_start < 0 else run_start
            continue
        if run_start >= 0 and step - run_start >= CONVERGED_STEPS and run_start not in kidnap_steps:
            count += 1
        run_start = -1
    return count


def staying_right_metrics(
    truth: np.ndarray, table: pd.DataFrame, kidnap_steps: tuple[int, ...] = ()
) -> dict[str, float]:
    """`relosses` and (for a table with a position covariance) `false_convergences`."""
    good = _good_steps(truth, table)
    bounds = [0, *kidnap_steps, len(good)]
    out: dict[str, float] = {
        "relosses": sum(count_relosses(good, a, b) for a, b in itertools.pairwise(bounds))
    }
    confident = confident_steps(table)
    if confident is not None:
        out["false_convergences"] = count_false_convergences(good, confident, kidnap_steps)
    return out
