"""The per-step estimate table every localizer writes (reports/localize/<method>.csv).

One row per trajectory step: step index, time, pose (x, y, θ ∈ (−π, π]), the six distinct
entries of the pose covariance (NaN where a localizer has none) and `n_particles`, the number
of hypotheses behind the estimate (amcl: particles; an ensemble: members; one network or a
Kalman filter: 1). Evaluation and report read this format; localizers build it here.
A ground-floor module: it imports only scanloc.pose.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import pandas as pd

from scanloc.pose import wrap_angle

TABLE_COLUMNS: tuple[str, ...] = (
    "step",
    "t",
    "x",
    "y",
    "theta",
    "cov_xx",
    "cov_xy",
    "cov_xt",
    "cov_yy",
    "cov_yt",
    "cov_tt",
    "n_particles",
)
COV_INDEX: dict[str, tuple[int, int]] = {
    "cov_xx": (0, 0),
    "cov_xy": (0, 1),
    "cov_xt": (0, 2),
    "cov_yy": (1, 1),
    "cov_yt": (1, 2),
    "cov_tt": (2, 2),
}


class Localization(NamedTuple):
    """A localizer's output: the per-step table, and what it cost (kept out of the table, so
    that the table is byte-deterministic while the timing is not).

    Every localizer is timed alike: `scan_seconds` holds the wall time of each scan's own work
    (one filter update, or one network inference for that scan alone), and `setup_s` the
    one-off work before the first scan (map tables, model loading, compilation).
    `counts` carries event counts a localizer reports (e.g. gate rejections); `hypotheses`, for
    a localizer with ranked hypotheses, arrays "poses" (T, K, 3), "weights" (T, K) and "stds"
    (T, K, 3), best first.
    """

    table: pd.DataFrame
    setup_s: float
    scan_seconds: np.ndarray
    counts: Mapping[str, int] | None = None
    hypotheses: Mapping[str, np.ndarray] | None = None

    def timing(self) -> dict[str, float | int]:
        """What the localize stage writes to <method>_timing.json."""
        seconds = np.asarray(self.scan_seconds, dtype=np.float64)
        return {
            "time_per_scan_s": float(seconds.mean()) if seconds.size else float("nan"),
            "time_per_scan_median_s": float(np.median(seconds)) if seconds.size else float("nan"),
            "time_per_scan_max_s": float(seconds.max()) if seconds.size else float("nan"),
            "setup_s": float(self.setup_s),
            **(self.counts or {}),
        }


def estimate_table(
    steps: np.ndarray,
    times: np.ndarray,
    means: np.ndarray,
    covs: np.ndarray | None,
    n_particles: np.ndarray | int,
) -> pd.DataFrame:
    """The per-step table from step indices (T,), times (T,), poses (T, 3), covariances
    (T, 3, 3) or None (all NaN) and hypothesis counts (T,) or one count for every step.
    θ is wrapped to (−π, π]."""
    means = np.asarray(means, dtype=np.float64)
    if means.ndim != 2 or means.shape[1] != 3:
        raise ValueError(f"means must have shape (T, 3), got {means.shape}")
    count = means.shape[0]
    covs = np.full((count, 3, 3), np.nan) if covs is None else np.asarray(covs, np.float64)
    if covs.shape != (count, 3, 3):
        raise ValueError(f"covs must have shape ({count}, 3, 3), got {covs.shape}")
    columns: dict[str, np.ndarray] = {
        "step": np.asarray(steps, dtype=np.int64),
        "t": np.asarray(times, dtype=np.float64),
        "x": means[:, 0],
        "y": means[:, 1],
        "theta": wrap_angle(means[:, 2]),
    }
    for name, (i, j) in COV_INDEX.items():
        columns[name] = covs[:, i, j]
    hypotheses = np.asarray(n_particles, dtype=np.int64)
    columns["n_particles"] = np.full(count, hypotheses) if hypotheses.ndim == 0 else hypotheses
    for name in ("step", "t", "n_particles"):
        if columns[name].shape != (count,):
            raise ValueError(f"{name} must have shape ({count},), got {columns[name].shape}")
    return pd.DataFrame(columns, columns=list(TABLE_COLUMNS))


def table_poses(table: pd.DataFrame) -> np.ndarray:
    """The (T, 3) poses of a per-step table."""
    return table[["x", "y", "theta"]].to_numpy(dtype=np.float64)


def table_covariances(table: pd.DataFrame) -> np.ndarray:
    """The (T, 3, 3) symmetric pose covariances of a per-step table (NaN where it has none)."""
    covs = np.empty((len(table), 3, 3))
    for name, (i, j) in COV_INDEX.items():
        covs[:, i, j] = covs[:, j, i] = table[name].to_numpy(dtype=np.float64)
    return covs
