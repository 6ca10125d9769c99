"""Timestamped planar poses from a CSV file `t,x,y,theta` (header row; t in seconds, θ in
radians), optionally with scanloc's covariance columns (cov_xx, cov_xy, cov_xt, cov_yy, cov_yt,
cov_tt): ground truth for a bag, or any localizer's estimates to score."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from scanloc.estimates import COV_INDEX

CSV_COLUMNS = ("t", "x", "y", "theta")


def read_pose_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t (N,) seconds, poses (N, 3), covariances (N, 6) or NaN) of a pose CSV, rows in time
    order (a row going back in time is an error)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: pose CSV not found")
    try:
        table = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable CSV: {exc}") from exc
    missing = [c for c in CSV_COLUMNS if c not in table.columns]
    if missing:
        raise ValueError(
            f"{path}: missing column(s) {missing}; expected a header row with {list(CSV_COLUMNS)}"
        )
    for column in CSV_COLUMNS:
        if not pd.api.types.is_numeric_dtype(table[column]):
            raise ValueError(f"{path}: column '{column}': expected numbers")
    times = table["t"].to_numpy(dtype=np.float64)
    if not np.isfinite(times).all():
        raise ValueError(f"{path}: column 't': expected finite times in seconds")
    back = np.flatnonzero(np.diff(times) < 0)
    if back.size:
        row = int(back[0]) + 1
        raise ValueError(
            f"{path}: column 't': row {row + 1} goes back in time ({times[row]} after "
            f"{times[row - 1]}): expected non-decreasing times"
        )
    poses = table[["x", "y", "theta"]].to_numpy(dtype=np.float64)
    covs = np.full((len(table), len(COV_INDEX)), np.nan)
    for k, name in enumerate(COV_INDEX):
        if name in table.columns:
            covs[:, k] = table[name].to_numpy(dtype=np.float64)
    return times, poses, covs
