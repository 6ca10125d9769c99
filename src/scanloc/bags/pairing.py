"""Poses of a timestamped stream at other times (the scans'): linear in x, y, the shorter way
round the circle in θ, within a stated tolerance.

A query time needs a sample within `tolerance_ns` before it and one within `tolerance_ns`
after it (one at the exact time is enough, and its pose is taken as is, bit for bit); before
the first or after the last sample, the nearest one within the tolerance is held.
"""

from __future__ import annotations

import numpy as np

from scanloc.pose import wrap_angle


def first_decrease(stamps_ns: np.ndarray, strict: bool = False) -> int:
    """Index of the first stamp that goes back in time (or repeats, if `strict`), else -1."""
    steps = np.diff(np.asarray(stamps_ns, dtype=np.int64))
    bad = np.flatnonzero(steps <= 0 if strict else steps < 0)
    return int(bad[0]) + 1 if bad.size else -1


def pose_at(
    stamps_ns: np.ndarray, poses: np.ndarray, query_ns: np.ndarray, tolerance_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """(poses (Q, 3), paired (Q,) bool) of a stream with non-decreasing stamps at `query_ns`.

    Unpaired queries (no sample within the tolerance, module doc) get NaN. Of samples with
    equal stamps the last one counts.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    poses = np.asarray(poses, dtype=np.float64)
    query = np.asarray(query_ns, dtype=np.int64)
    last = np.append(stamps[1:] != stamps[:-1], True)
    stamps, poses = stamps[last], poses[last]
    count = len(stamps)
    out = np.full((len(query), 3), np.nan)
    if count == 0:
        return out, np.zeros(len(query), dtype=bool)
    i = np.searchsorted(stamps, query, side="right") - 1  # last sample at or before
    j = i + 1  # first sample after
    ic, jc = np.clip(i, 0, count - 1), np.clip(j, 0, count - 1)
    before = np.where(i >= 0, query - stamps[ic], np.iinfo(np.int64).max)
    after = np.where(j < count, stamps[jc] - query, np.iinfo(np.int64).max)
    exact = (i >= 0) & (before == 0)
    near_before, near_after = before <= tolerance_ns, after <= tolerance_ns
    inside = (i >= 0) & (j < count) & near_before & near_after
    held_first = (i < 0) & near_after
    held_last = (j >= count) & near_before
    span = np.maximum(after + before, 1).astype(np.float64)
    w = np.where(inside, before / span, 0.0)[:, None]
    a, b = poses[ic], poses[jc]
    mixed = np.empty_like(out)
    mixed[:, :2] = a[:, :2] + w * (b[:, :2] - a[:, :2])
    mixed[:, 2] = wrap_angle(a[:, 2] + w[:, 0] * wrap_angle(b[:, 2] - a[:, 2]))
    out[inside] = mixed[inside]
    out[held_first] = poses[jc[held_first]]
    out[held_last | exact] = poses[ic[held_last | exact]]
    return out, exact | inside | held_first | held_last
