"""Any localizer's estimates, from a bag topic or a CSV, scored on a scanloc run exactly as the
evaluate stage scores scanloc's own localizers.

Alignment: each step takes the latest estimate stamped at or before the step's scan (1 ms of
slack for stamps rounded in text), as a robot acting on the localizer's output would; steps
before the first estimate have none (NaN: missing, and lost for convergence). No
interpolation: an estimate is only known once it is published. Bag stamps are taken relative
to the run's step 0 (meta `time_origin_ns`; scanloc's exported bags start at EPOCH_NS), CSV
times `t` are the run's times (seconds, as in times.npy and every estimate table).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from scanloc.bags.errors import BagError
from scanloc.bags.pose_csv import read_pose_csv
from scanloc.bags.ros_messages import EPOCH_NS
from scanloc.bags.topics import read_topics
from scanloc.estimates import COV_INDEX, estimate_table
from scanloc.evaluate.metrics import read_estimates
from scanloc.evaluate.table2 import evaluate_all, metrics_json
from scanloc.io import atomic_path, read_json
from scanloc.trajectory.format import load_trajectory

STAMP_SLACK_NS = 1_000_000  # 1 ms: times printed as %.9g are within 50 µs up to 10^4 s


def estimate_stream(
    source: str | Path, topic: str, origin_ns: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps ns after step 0 (N,), poses (N, 3), covariance entries (N, 6)) of a CSV
    `t,x,y,theta[,cov_…]` or a bag topic of PoseWithCovarianceStamped, PoseStamped or
    Odometry messages, in time order."""
    path = Path(source)
    if path.suffix == ".csv":
        times, poses, covs = read_pose_csv(path)
        return np.round(times * 1e9).astype(np.int64), poses, covs
    stamps, poses, covs = read_topics(path, None, [topic]).poses[topic].arrays()
    if len(stamps) == 0:
        raise BagError(path, topic, "no messages: expected pose estimates")
    back = np.flatnonzero(np.diff(stamps) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise BagError(
            path,
            topic,
            f"clock goes back at message {k}: stamp {stamps[k]} ns after {stamps[k - 1]} ns; "
            "expected non-decreasing header stamps",
        )
    return stamps - origin_ns, poses, covs


def latest_estimates(
    stamps_ns: np.ndarray, poses: np.ndarray, covs: np.ndarray, step_ns: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per step, the latest estimate at or before it: poses (T, 3), covariances (T, 3, 3)."""
    index = np.searchsorted(stamps_ns, step_ns + STAMP_SLACK_NS, side="right") - 1
    have = index >= 0
    out_poses = np.full((len(step_ns), 3), np.nan)
    out_covs = np.full((len(step_ns), 3, 3), np.nan)
    out_poses[have] = poses[index[have]]
    for k, (i, j) in enumerate(COV_INDEX.values()):
        out_covs[have, i, j] = out_covs[have, j, i] = covs[index[have], k]
    return out_poses, out_covs


def score_estimates(
    run_dir: str | Path,
    source: str | Path,
    topic: str,
    name: str,
    out_csv: str | Path,
    metrics_path: str | Path,
) -> dict[str, Any]:
    """Write the aligned estimate table (`out_csv`) and its metrics (`metrics_path`, the
    evaluate stage's JSON for one method); return the metrics (unrounded)."""
    run = Path(run_dir)
    traj, _ = load_trajectory(run)
    meta_path = run / "meta.json"
    meta = read_json(meta_path) if meta_path.is_file() else {}
    stamps, poses, covs = estimate_stream(source, topic, int(meta.get("time_origin_ns", EPOCH_NS)))
    step_ns = np.round(np.asarray(traj.times) * 1e9).astype(np.int64)
    means, cov = latest_estimates(stamps, poses, covs, step_ns)
    table = estimate_table(np.arange(len(step_ns)), traj.times, means, cov, 1)
    with atomic_path(out_csv) as tmp:
        table.to_csv(tmp, index=False, float_format="%.9g")
    written = read_estimates(Path(out_csv))  # scored as the evaluate stage reads it
    metrics = evaluate_all(traj.truth, {name: written}, {name: str(out_csv)}, traj.kidnap_steps)
    with atomic_path(metrics_path) as tmp:
        tmp.write_text(metrics_json(metrics), encoding="utf-8")
    return metrics[name]
