"""scanloc's learned localizer along a trajectory: ranked hypotheses from each scan alone.

Each scan is localized on its own, as the paper's CNNs are, but by ScanLocNet
(scanloc.scanlocnet.model): the exact top `k_raw` (cell, heading-bin) hypotheses, then
non-maximum suppression (a hypothesis within `nms_distance` m and `nms_angle_deg` of a better
one of the same scan adds its weight to it and is dropped), keeping the `k` best. The per-step
table holds the best hypothesis with its predicted (diagonal) covariance; all k go to the
hypotheses side file for the top-K recall and for localizers built on them.

With a `verifier` (localize.hypothesis_verification) each scan's hypotheses are refined against
the map, scored and re-ranked; `fit_calibration` fits the verifier's calibrated probability on
scans that are never scored (the map's validation scans), and the side file then also holds
each hypothesis' `scores`.

Frames: the network and the verifier see the laser, so their hypotheses are laser poses;
`in_base_frame` turns them into poses of the robot's base (laser ⊕ mount⁻¹), the frame of a
run's truth and odometry, before anything scores or tracks them.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanloc.estimates import Localization, estimate_table
from scanloc.localize.hypothesis_verification import HypothesisVerifier
from scanloc.localize.score_calibration import ScoreCalibration
from scanloc.pose import compose, inverse, recall_within


@dataclass(frozen=True)
class LearnedParams:
    """The `learned` section of a localizer config: the model, how its hypotheses are decoded
    (the `k` best after suppressing duplicates among the `k_raw` best within `nms_distance` m
    and `nms_angle_deg`), and whether they are `verified` against the map (the `verifier`
    section), with the calibration fitted on `calibration_count` of the `calibration_scans`
    dataset's validation scans."""

    model: str = ""
    k: int = 20
    k_raw: int = 50
    nms_distance: float = 0.5
    nms_angle_deg: float = 10.0
    verified: bool = False
    calibration_scans: str = ""
    calibration_count: int = 500

    def __post_init__(self) -> None:
        if not 1 <= self.k <= self.k_raw:
            raise ValueError(f"need 1 <= k <= k_raw, got {self.k}, {self.k_raw}")
        if self.calibration_count < 1:
            raise ValueError(f"calibration_count must be >= 1, got {self.calibration_count}")


def scan_hypotheses(model_path: Path, ranges: np.ndarray, params: LearnedParams = LearnedParams()):
    """(model, per-scan hypotheses function, setup seconds): the function maps one scan
    (beams,) to Hypotheses of one row, decoded as `params` say (torch is imported here, not at
    module load)."""
    from scanloc.models.model_files import load_model
    from scanloc.scanlocnet.model import suppress_duplicates, top_k

    start = time.perf_counter()
    model = load_model(model_path)
    angle = math.radians(params.nms_angle_deg)

    def localize(scan: np.ndarray):
        raw = top_k(model, np.asarray(scan, dtype=np.float32)[None], params.k_raw)
        return suppress_duplicates(raw, params.nms_distance, angle, params.k)

    localize(ranges[0])  # warm-up: the first call builds oneDNN's kernels
    return model, localize, time.perf_counter() - start


def verified(hypotheses_of: Callable, verifier: HypothesisVerifier) -> Callable:
    """The per-scan hypotheses function with every scan's hypotheses verified."""
    return lambda scan: verifier.verify(scan, hypotheses_of(scan))


def in_base_frame(hypotheses_of: Callable, laser_mount: Sequence[float]) -> Callable:
    """The per-scan hypotheses function with its laser poses turned into the robot base's
    (laser ⊕ mount⁻¹, scalar trigonometry: the same bits on every CPU); the function itself
    where the laser sits at the base (a simulated map's runs). The predicted standard
    deviations are kept: the mount's lever arm adds |mount| · σθ (< 1 mm for a 10 cm mount
    and σθ of half a degree)."""
    if not any(laser_mount):
        return hypotheses_of
    unmount = inverse(np.asarray(laser_mount, dtype=np.float64))

    def of_base(scan: np.ndarray):
        hyp = hypotheses_of(scan)
        flat = np.asarray(hyp.poses, dtype=np.float64).reshape(-1, 3)
        base = np.array([compose(p, unmount) for p in flat]).reshape(hyp.poses.shape)
        return dataclasses.replace(hyp, poses=base)

    return of_base


def fit_calibration(
    localize, verifier: HypothesisVerifier, ranges: np.ndarray, poses: np.ndarray
) -> tuple[ScoreCalibration, dict[str, float]]:
    """The verifier's calibration fitted on scans with known poses: the best hypothesis of each
    scan after verification (the highest inlier fraction), labelled by whether it lies within
    the recall thresholds of the truth after refinement; also how many scans it saw and how
    many of their best hypotheses were right. Where all are right, or all wrong (an untrained
    model), the calibration is their smoothed share."""
    features, hits = [], []
    for scan, truth in zip(ranges, poses, strict=True):
        hyp = localize(scan)
        real = hyp.weights[0] > 0
        refined, feats = verifier.features(scan, hyp.poses[0][real], hyp.weights[0][real])
        best = int(np.argmax(feats[:, 0])) if len(feats) else 0
        features.append(feats[best : best + 1])
        hits.append(recall_within(refined[best : best + 1, None], truth[None]))
    features_all, hits_all = np.concatenate(features), np.concatenate(hits)
    summary = {"calibration_scans": len(ranges), "calibration_hit_rate": float(hits_all.mean())}
    return ScoreCalibration.fit(features_all, hits_all), summary


def localize_learned(
    hypotheses_of: Callable, setup_s: float, ranges: np.ndarray, times: np.ndarray
) -> Localization:
    """The learned localizer (`hypotheses_of`, from scan_hypotheses, maybe `verified`) on every
    scan of a trajectory (see the module docstring)."""
    ranges = np.asarray(ranges, dtype=np.float32)
    if ranges.ndim != 2 or ranges.shape[0] < 1:
        raise ValueError(f"ranges must have shape (T >= 1, beams), got {ranges.shape}")
    steps = ranges.shape[0]
    rows, seconds = [], np.empty(steps)
    for step in range(steps):
        tick = time.perf_counter()
        rows.append(hypotheses_of(ranges[step]))
        seconds[step] = time.perf_counter() - tick
    poses = np.concatenate([h.poses for h in rows])
    weights = np.concatenate([h.weights for h in rows])
    stds = np.concatenate([h.stds for h in rows])
    cov = np.zeros((steps, 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = stds[:, 0] ** 2
    table = estimate_table(np.arange(steps), times, poses[:, 0], cov, poses.shape[1])
    hypotheses = {"poses": poses, "weights": weights, "stds": stds}
    if rows[0].scores is not None:
        hypotheses["scores"] = np.concatenate([h.scores for h in rows])
    return Localization(table, setup_s, seconds, hypotheses=hypotheses)
