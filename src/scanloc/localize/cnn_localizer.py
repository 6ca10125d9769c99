"""Localize every scan of a trajectory with one trained network or an ensemble of them.

The paper (Section 4.4) predicts each time step's pose from that step's scan alone and, for the
"multi model CNN", takes the plain mean of several networks' predictions, noting that the
spread of the members also yields a covariance. Two details the paper leaves open are fixed
here: θ is averaged on the circle (an arithmetic mean of −179° and +179° would point backwards)
and the members' covariance uses θ deviations wrapped around that circular mean.

Output: the per-step table shared by all localizers (`estimates.py`). A single network has
no covariance (NaN columns) and `n_particles` = 1, the number of hypotheses behind the
estimate; an ensemble reports its number of members there.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scanloc.estimates import Localization, estimate_table
from scanloc.pose import wrap_angle


def ensemble_mean_and_cov(preds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean pose and covariance of M members' predictions per time step.

    Args:
        preds: (M, T, 3) predicted (x, y, θ); θ in radians, any range.
    Returns:
        mean (T, 3): arithmetic mean of x and y, circular mean of θ in (−π, π];
        cov (T, 3, 3): unbiased (divisor M − 1) covariance of the members about that mean,
        θ deviations wrapped to (−π, π]; all NaN when M == 1 (a spread needs two members).
    """
    preds = np.asarray(preds, dtype=np.float64)
    if preds.ndim != 3 or preds.shape[2] != 3 or preds.shape[0] < 1:
        raise ValueError(f"preds must have shape (M >= 1, T, 3), got {preds.shape}")
    members = preds.shape[0]
    mean = np.empty(preds.shape[1:], dtype=np.float64)
    mean[:, :2] = preds[:, :, :2].mean(axis=0)
    theta = preds[:, :, 2]
    heading = np.arctan2(np.sin(theta).mean(axis=0), np.cos(theta).mean(axis=0))
    mean[:, 2] = np.where(heading == -np.pi, np.pi, heading)  # arctan2(-0.0, x < 0) is -π
    if members == 1:
        return mean, np.full((preds.shape[1], 3, 3), np.nan)
    dev = preds - mean[None]
    dev[:, :, 2] = wrap_angle(dev[:, :, 2])
    cov = np.einsum("mti,mtj->tij", dev, dev) / (members - 1)
    return mean, cov


def localize_cnn(
    model_paths: Sequence[Path], ranges: np.ndarray, times: np.ndarray
) -> Localization:
    """Predict each step's pose from its scan with one model (`cnn_single`) or several
    (`cnn_ensemble`: circular mean and members' covariance).

    Scans are localized one at a time, as on a robot: each scan's time is the inference of all
    members on that scan alone. Loading the models and a first (warm-up) inference are setup.
    """
    # Imported here so that the table maths can be used without loading torch.
    from scanloc.models.model_files import load_model, predict

    paths = [Path(p) for p in model_paths]
    if not paths:
        raise ValueError("model_paths is empty: need at least one trained model")
    for path in paths:
        if not path.is_file():
            raise FileNotFoundError(f"{path}: model checkpoint not found")
    ranges = np.asarray(ranges, dtype=np.float32)
    times = np.asarray(times, dtype=np.float64)
    if ranges.ndim != 2 or ranges.shape[0] < 1:
        raise ValueError(f"ranges must have shape (T >= 1, beams), got {ranges.shape}")
    if times.shape != (ranges.shape[0],):
        raise ValueError(f"times must have shape ({ranges.shape[0]},), got {times.shape}")
    start = time.perf_counter()
    models = [load_model(path) for path in paths]
    for model in models:
        predict(model, ranges[:1], 1)
    setup_s = time.perf_counter() - start
    preds = np.empty((len(paths), ranges.shape[0], 3))
    seconds = np.empty(ranges.shape[0])
    for step in range(ranges.shape[0]):
        tick = time.perf_counter()
        for k, model in enumerate(models):
            preds[k, step] = np.asarray(predict(model, ranges[step : step + 1], 1))[0]
        seconds[step] = time.perf_counter() - tick
    mean, cov = ensemble_mean_and_cov(preds)
    table = estimate_table(np.arange(len(times)), times, mean, cov, len(paths))
    return Localization(table, setup_s, seconds)
