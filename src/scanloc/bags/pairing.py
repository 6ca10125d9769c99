"""Poses of a timestamped stream at other times (the scans'), as ROS's tf does it: linear in
x, y and the shorter way round the circle in θ between the two samples that bracket a query.

A sample at the exact query time is taken as is, bit for bit (a run scanloc exported has its
odometry at every scan stamp). Otherwise the bracketing samples must be at most a bound apart;
the bound comes from the stream itself, GAP_FACTOR x its median period (a 7.5 Hz odometry
may be interpolated across 0.4 s, a 100 Hz one across 30 ms), unless the user gives one. A
query before the first or after the last sample is outside the stream: nothing is held or
extrapolated, the caller decides (drop the scan, or give it no truth).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanloc.pose import wrap_angle

GAP_FACTOR = 3.0  # a gap of up to 3 median periods (two messages lost) is interpolated

PAIRED, BEFORE, AFTER, GAP = 0, 1, 2, 3  # Pairing.status of each query


def first_decrease(stamps_ns: np.ndarray, strict: bool = False) -> int:
    """Index of the first stamp that goes back in time (or repeats, if `strict`), else -1."""
    steps = np.diff(np.asarray(stamps_ns, dtype=np.int64))
    bad = np.flatnonzero(steps <= 0 if strict else steps < 0)
    return int(bad[0]) + 1 if bad.size else -1


def median_period_ns(stamps_ns: np.ndarray) -> int | None:
    """The median time between a stream's distinct stamps; None for fewer than two."""
    steps = np.diff(np.unique(np.asarray(stamps_ns, dtype=np.int64)))
    return int(np.median(steps)) if steps.size else None


@dataclass(frozen=True)
class GapBound:
    """How far apart two bracketing samples may be, and why (for meta.json and errors)."""

    bound_ns: int
    median_period_ns: int | None
    rule: str

    def describe(self) -> dict[str, float | str | None]:
        period = self.median_period_ns
        return {
            "median_period_s": None if period is None else period / 1e9,
            "bound_s": self.bound_ns / 1e9,
            "bound_rule": self.rule,
        }


def gap_bound(
    stamps_ns: np.ndarray, override_s: float | None = None, setting: str = "pairing_tolerance_s"
) -> GapBound:
    """GAP_FACTOR x the stream's median period, or `override_s` (the user's `setting`)."""
    period = median_period_ns(stamps_ns)
    if override_s is not None:
        return GapBound(round(float(override_s) * 1e9), period, f"{setting} (given)")
    if period is None:
        return GapBound(0, None, "exact stamps only (the stream has a single stamp)")
    return GapBound(round(GAP_FACTOR * period), period, f"{GAP_FACTOR:g} x the median period")


@dataclass(frozen=True)
class Pairing:
    """Poses (Q, 3) at the queries (NaN where not PAIRED), each query's status (PAIRED, BEFORE,
    AFTER, GAP) and the gap between its bracketing samples in ns (0 when exact)."""

    poses: np.ndarray
    status: np.ndarray
    gaps_ns: np.ndarray

    @property
    def paired(self) -> np.ndarray:
        return self.status == PAIRED

    def count(self, status: int) -> int:
        return int((self.status == status).sum())


def pair_poses(
    stamps_ns: np.ndarray, poses: np.ndarray, query_ns: np.ndarray, bound_ns: int
) -> Pairing:
    """A stream with non-decreasing stamps at `query_ns` (module doc). Of samples with equal
    stamps the last one counts."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    query = np.asarray(query_ns, dtype=np.int64)
    last = np.append(stamps[1:] != stamps[:-1], True) if len(stamps) else np.zeros(0, bool)
    stamps, poses = stamps[last], poses[last]
    count = len(stamps)
    out = np.full((len(query), 3), np.nan)
    if count == 0:
        return Pairing(out, np.full(len(query), BEFORE, np.int8), np.zeros(len(query), np.int64))
    i = np.searchsorted(stamps, query, side="right") - 1  # last sample at or before
    ic, jc = np.clip(i, 0, count - 1), np.clip(i + 1, 0, count - 1)
    exact = (i >= 0) & (stamps[ic] == query)
    inside = (i >= 0) & (i + 1 < count) & ~exact
    gaps = np.where(inside, stamps[jc] - stamps[ic], 0)
    mixed = inside & (gaps <= bound_ns)
    status = np.full(len(query), PAIRED, np.int8)
    status[i < 0] = BEFORE
    status[(i >= count - 1) & ~exact] = AFTER
    status[inside & ~mixed] = GAP
    w = np.where(mixed, (query - stamps[ic]) / np.maximum(gaps, 1), 0.0)[:, None]
    a, b = poses[ic], poses[jc]
    between = np.empty_like(out)
    between[:, :2] = a[:, :2] + w * (b[:, :2] - a[:, :2])
    between[:, 2] = wrap_angle(a[:, 2] + w[:, 0] * wrap_angle(b[:, 2] - a[:, 2]))
    out[mixed] = between[mixed]
    out[exact] = poses[ic[exact]]
    return Pairing(out, status, gaps)
