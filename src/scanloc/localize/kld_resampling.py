"""amcl's resampler: KLD sampling (Fox 2003) with random-pose injection (amcl's pf_update_resample).

Particles are drawn one by one in proportion to their weights, each into amcl's histogram bins
(`clustering.py`: 0.5 m × 0.5 m × 10°), until the count exceeds the KLD bound of the number of
occupied bins k,
    n = ⌈(k-1)/(2ε) · (1 - 2/(9(k-1)) + sqrt(2/(9(k-1)))·z)³⌉,
clamped to [min_particles, max_particles] (k = 1 gives max_particles). amcl feeds `kld_z` (0.99)
into the formula as the normal quantile z itself; that is kept.

Recovery (Augmented MCL): each draw is, with probability w_diff = max(0, 1 - w_fast / w_slow), a
pose from the injection proposal instead of a resampled particle. amcl injects uniform free
poses; the poses to inject are the caller's (`proposals.py`), drawn beforehand, so that a
learned proposal plugs in without touching the resampler. Injected draws carry the weight the
proposal gives them (1 for amcl's uniform injection: every resampled particle weighs the same);
the caller normalises.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from scanloc.localize.clustering import bin_of


def kld_limit(k: int, min_particles: int, max_particles: int, kld_err: float, kld_z: float) -> int:
    """amcl's pf_resample_limit: particles needed for k occupied bins (KLD bound, clamped)."""
    return int(_kld_limit(k, min_particles, max_particles, kld_err, kld_z))


@numba.njit(cache=True)
def _kld_limit(k: int, min_n: int, max_n: int, err: float, z: float) -> int:
    if k < 1 or k > max_n or k == 1:
        return max_n
    b = 2.0 / (9.0 * (k - 1))
    x = 1.0 - b + math.sqrt(b) * z
    n = math.ceil((k - 1) / (2.0 * err) * x * x * x)
    return min(max(n, min_n), max_n)


@numba.njit(cache=True, parallel=True)
def _pick_indices(cum: np.ndarray, u_pick: np.ndarray, n: int) -> np.ndarray:
    """The particle each uniform picks: the last j < n with cum[j] <= u (cum: cumulative
    weights, n + 1 entries), what a right bisection gives. Every draw's uniform is known before
    the draws begin, so they are looked up in parallel, each from a guide table (Devroye's
    method: guide[b] = the pick of b / n) and a short forward scan, O(1) expected per draw."""
    guide = np.empty(n, dtype=np.int64)
    j = 0
    for b in range(n):
        while j + 1 < n and cum[j + 1] <= b / n:
            j += 1
        guide[b] = j
    picks = np.empty(u_pick.shape[0], dtype=np.int64)
    for i in numba.prange(u_pick.shape[0]):
        u = u_pick[i]
        # One bucket early: u * n may round up past its bucket; the scan catches up.
        k = guide[min(max(int(u * n) - 1, 0), n - 1)]
        while k + 1 < n and cum[k + 1] <= u:
            k += 1
        picks[i] = k
    return picks


def pick_indices(weights: np.ndarray, u_pick: np.ndarray) -> np.ndarray:
    """The particle each uniform in [0, 1) picks in proportion to the normalised `weights`."""
    cum = np.concatenate([[0.0], np.cumsum(weights)])
    return _pick_indices(cum, np.ascontiguousarray(u_pick), len(weights))


@numba.njit(cache=True)
def resample_kld(
    poses: np.ndarray,
    weights: np.ndarray,
    u_pick: np.ndarray,
    u_inject: np.ndarray,
    w_diff: float,
    inject_poses: np.ndarray,
    inject_weights: np.ndarray,
    min_n: int,
    max_n: int,
    err: float,
    z: float,
    dims: np.ndarray,
    occupied: np.ndarray,
    out: np.ndarray,
    out_weights: np.ndarray,
) -> int:
    """Draw into `out` until the KLD bound of the occupied bins is exceeded; returns the count.

    Draw i injects inject_poses[i] (weight inject_weights[i]) when u_inject[i] < w_diff, else
    picks the particle where the cumulative weights pass u_pick[i] (weight 1). `occupied` is a
    zeroed work array over all bins; it is left zeroed.
    """
    n = poses.shape[0]
    cum = np.empty(n + 1)
    cum[0] = 0.0
    for i in range(n):
        cum[i + 1] = cum[i] + weights[i]
    picks = _pick_indices(cum, u_pick, n)
    lo_x, lo_y, nx, ny, nt = dims[0], dims[1], dims[2], dims[3], dims[4]
    touched = np.empty(max_n, dtype=np.int64)
    k = 0
    limit = _kld_limit(0, min_n, max_n, err, z)
    count = 0
    while count < max_n:
        if u_inject[count] < w_diff:
            out[count, 0] = inject_poses[count, 0]
            out[count, 1] = inject_poses[count, 1]
            out[count, 2] = inject_poses[count, 2]
            out_weights[count] = inject_weights[count]
        else:
            j = picks[count]
            out[count, 0] = poses[j, 0]
            out[count, 1] = poses[j, 1]
            out[count, 2] = poses[j, 2]
            out_weights[count] = 1.0
        b = bin_of(out[count, 0], out[count, 1], out[count, 2], lo_x, lo_y, nx, ny, nt)
        if occupied[b] == 0:
            occupied[b] = 1
            touched[k] = b
            k += 1
            limit = _kld_limit(k, min_n, max_n, err, z)
        count += 1
        if count > limit:
            break
    for i in range(k):
        occupied[touched[i]] = 0
    return count
