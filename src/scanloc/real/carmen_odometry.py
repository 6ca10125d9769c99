"""Poses out of a corrected CARMEN log (see scanloc.real.carmen): the ODOM stream
interpolated, the wheel odometry rebuilt per scan, and the logged headings wrapped."""

from __future__ import annotations

import math

import numpy as np

from scanloc.pose import compose, inverse, wrap_angle
from scanloc.real.carmen import CarmenLog, LaserStream


def wrap_logged_headings(theta: np.ndarray) -> np.ndarray:
    """Headings (N,) wrapped to (-π, π] as atan2(sin θ, cos θ): corrected logs' headings stray
    past ±π.

    One value at a time through libm (math), not numpy's arctan2: on a CPU with AVX-512, numpy
    takes SIMD kernels whose last bits differ from the libm results it gives elsewhere, and the
    truth written from a log must be the same bytes on every machine.
    """
    values = np.asarray(theta, dtype=np.float64).tolist()
    return np.array([math.atan2(math.sin(t), math.cos(t)) for t in values], dtype=np.float64)


def _laser(log: CarmenLog, which: str) -> LaserStream:
    stream = {"front": log.front, "rear": log.rear}.get(which)
    if stream is None or stream.num_scans == 0:
        raise ValueError(f"{log.path}: no {which} laser scans (stream must be 'front' or 'rear')")
    return stream


def odometry_at(log: CarmenLog, times: np.ndarray) -> np.ndarray:
    """ODOM poses interpolated at `times` (T,): float64 (T, 3), θ wrapped to (-π, π].

    x, y are linear in time, θ follows the shorter way round the circle. Echo lines (module
    doc) are left out; the rest are ordered by timestamp (intel's jitter by up to 0.9 s against
    the file order), lines with equal times resolve to the last in the file, and times outside
    the ODOM stream get its first / last pose. In a corrected log the result stays close to
    the corrected path; see `scan_odometry` for the wheel odometry.
    """
    keep = ~log.odometry.echo
    stamps, poses = log.odometry.times[keep], log.odometry.poses[keep]
    if len(stamps) == 0:
        raise ValueError(f"{log.path}: no ODOM lines to interpolate")
    order = np.argsort(stamps, kind="stable")
    stamps, poses = stamps[order], poses[order]
    last = np.append(stamps[1:] != stamps[:-1], True)  # of each run of equal times
    stamps, poses = stamps[last], poses[last]
    query = np.asarray(times, dtype=np.float64)
    if query.ndim != 1:
        raise ValueError(f"times must have shape (T,), got {query.shape}")
    i = np.clip(np.searchsorted(stamps, query, side="right") - 1, 0, len(stamps) - 1)
    j = np.minimum(i + 1, len(stamps) - 1)
    span = stamps[j] - stamps[i]
    w = np.divide(query - stamps[i], span, out=np.zeros_like(query), where=span > 0)
    w = np.clip(w, 0.0, 1.0)
    out = np.empty((len(query), 3))
    out[:, :2] = poses[i, :2] + w[:, None] * (poses[j, :2] - poses[i, :2])
    out[:, 2] = wrap_angle(poses[i, 2] + w * wrap_angle(poses[j, 2] - poses[i, 2]))
    return out


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose b in the frame of pose a."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, b[2] - a[2]])


def _compose(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * u[0] - s * u[1], a[1] + s * u[0] + c * u[1], a[2] + u[2]])


def base_poses(laser_poses: np.ndarray, mount: np.ndarray) -> np.ndarray:
    """Robot base poses (N, 3) of laser poses: laser ⊕ mount⁻¹, θ wrapped; `mount` is the
    laser's pose (x, y, θ) in the base frame."""
    unmount = inverse(np.asarray(mount, dtype=np.float64))
    out = np.array([compose(p, unmount) for p in np.asarray(laser_poses)]).reshape(-1, 3)
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def scan_odometry(
    log: CarmenLog, stream: str = "front", mount: np.ndarray | None = None
) -> np.ndarray:
    """Wheel odometry of the robot base at each scan of a corrected log, float64 (N, 3), θ in
    (-π, π].

    A corrected log's ODOM lines restart from each scan's corrected pose (module doc), so the
    last ODOM line before scan k+1 is scan k's pose moved by the wheels' motion between the
    scans: a base increment, in a frame parallel to the base's (the anchor is the laser pose,
    whose heading is the base's plus the mount's). Chaining those increments in the robot frame
    from the first scan's base pose (laser pose ⊕ mount⁻¹) gives the base's odometry with its
    drift, in the frame `drive_trajectory` uses (odometry[0] == truth[0]). Scans with no ODOM
    line since the previous one add no motion.
    """
    laser = _laser(log, stream)
    mount = np.zeros(3) if mount is None else np.asarray(mount, dtype=np.float64)
    real = np.flatnonzero(~log.odometry.echo)
    before = np.searchsorted(real, laser.odom_index, side="left")  # real ODOM lines before
    anchors = laser.odom_poses
    out = np.empty((laser.num_scans, 3))
    out[0] = base_poses(anchors[:1], mount)[0]
    for k in range(1, laser.num_scans):
        step = np.zeros(3)
        if before[k] > before[k - 1]:
            step = _relative(anchors[k - 1], log.odometry.poses[real[before[k] - 1]])
            # the anchor frame is the laser's, turned by the mount's θ from the base's
            step = _rotate(step, mount[2])
        out[k] = _compose(out[k - 1], step)
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def _rotate(u: np.ndarray, angle: float) -> np.ndarray:
    """An increment's translation turned by `angle` (from the laser's to the base's axes)."""
    if angle == 0.0:
        return u
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * u[0] - s * u[1], s * u[0] + c * u[1], u[2]])
