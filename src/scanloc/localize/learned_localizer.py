"""scanloc's learned localizer along a trajectory: ranked hypotheses from each scan alone.

Each scan is localized on its own, as the paper's CNNs are, but by ScanLocNet
(scanloc.scanlocnet.model): the exact top `k_raw` (cell, heading-bin) hypotheses, then
non-maximum suppression (a hypothesis within `nms_distance` m and `nms_angle_deg` of a better
one of the same scan adds its weight to it and is dropped), keeping the `k` best. The per-step
table holds the best hypothesis with its predicted (diagonal) covariance; all k go to the
hypotheses side file for the top-K recall and for localizers built on them.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from scanloc.estimates import Localization, estimate_table


def scan_hypotheses(
    model_path: Path,
    ranges: np.ndarray,
    k: int = 20,
    k_raw: int = 50,
    nms_distance: float = 0.5,
    nms_angle_deg: float = 10.0,
):
    """(model, per-scan hypotheses function, setup seconds): the function maps one scan
    (beams,) to Hypotheses of one row (torch is imported here, not at module load)."""
    from scanloc.models.training import load_model
    from scanloc.scanlocnet.model import suppress_duplicates, top_k

    start = time.perf_counter()
    model = load_model(model_path)
    angle = math.radians(nms_angle_deg)

    def localize(scan: np.ndarray):
        raw = top_k(model, np.asarray(scan, dtype=np.float32)[None], k_raw)
        return suppress_duplicates(raw, nms_distance, angle, k)

    localize(ranges[0])  # warm-up: the first call builds oneDNN's kernels
    return model, localize, time.perf_counter() - start


def localize_learned(
    model_path: Path, ranges: np.ndarray, times: np.ndarray, **options: float
) -> Localization:
    """The learned localizer on every scan of a trajectory (see the module docstring)."""
    ranges = np.asarray(ranges, dtype=np.float32)
    if ranges.ndim != 2 or ranges.shape[0] < 1:
        raise ValueError(f"ranges must have shape (T >= 1, beams), got {ranges.shape}")
    _, localize, setup_s = scan_hypotheses(Path(model_path), ranges, **options)
    steps = ranges.shape[0]
    rows, seconds = [], np.empty(steps)
    for step in range(steps):
        tick = time.perf_counter()
        rows.append(localize(ranges[step]))
        seconds[step] = time.perf_counter() - tick
    poses = np.concatenate([h.poses for h in rows])
    weights = np.concatenate([h.weights for h in rows])
    stds = np.concatenate([h.stds for h in rows])
    cov = np.zeros((steps, 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = stds[:, 0] ** 2
    table = estimate_table(np.arange(steps), times, poses[:, 0], cov, poses.shape[1])
    hypotheses = {"poses": poses, "weights": weights, "stds": stds}
    return Localization(table, setup_s, seconds, hypotheses=hypotheses)
