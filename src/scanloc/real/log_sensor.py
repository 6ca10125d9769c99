"""What a CARMEN log says about its laser: the sensor (beams, angles, maximum range, the
"no return" marker, the rate) and the laser's pose on the robot (the mount), so that a
`real_logs` entry needs no hand-written sensor file.

The mount is read from the PARAM lines `robot_<front|rear>laser_offset` (forward, m),
`..._side_offset` (left, m) and `..._angular_offset` (rad) where the log has them. A log
without them gets it estimated from motion (`estimate_mount_offset`): on a robot turning about
its base, a laser d ahead of the base moves along an arc, so the corrected laser poses'
increments v and the wheel increments u satisfy v ≈ m⁻¹ ⊕ u ⊕ m for m = (d, 0, 0); d is the
least-squares fit over the steps given (the mapping part only).
"""

from __future__ import annotations

import numpy as np

from scanloc.real.carmen import CarmenFormatError, CarmenLog, LaserStream

MOUNT_PARAMS = ("offset", "side_offset", "angular_offset")
# A value counts as the "no return" marker when it is the largest reading, at least this share
# of all readings is exactly it, and every other reading is at least MARKER_GAP_M below it.
MARKER_MIN_SHARE = 1e-3
MARKER_GAP_M = 1.0
# A log without a marker: range_max this far above its longest reading.
RANGE_HEADROOM = 1.25


def log_stream(log: CarmenLog, which: str) -> LaserStream:
    """The log's `which` ('front' | 'rear') laser stream; a clear error when it has none."""
    if which not in ("front", "rear"):
        raise ValueError(f"stream must be 'front' or 'rear', got {which!r}")
    stream = log.front if which == "front" else log.rear
    if stream is None or stream.num_scans == 0:
        tags = "FLASER or ROBOTLASER1" if which == "front" else "RLASER or ROBOTLASER2"
        raise CarmenFormatError(
            f"{log.path}: no {which} laser scans: expected {tags} lines, found none"
        )
    if stream.num_scans < 2:
        raise CarmenFormatError(f"{log.path}: expected at least 2 {which} laser scans, got 1")
    return stream


def no_return_marker(ranges: np.ndarray) -> float | None:
    """The log's "no return" reading (intel 81.83 m, fr079 81.91 m), None when it has none."""
    values = np.asarray(ranges, dtype=np.float64).ravel()
    values = values[np.isfinite(values) & (values > 0)]
    if len(values) == 0:
        return None
    top = float(values.max())
    at_top = values == top
    rest = values[~at_top]
    if at_top.mean() >= MARKER_MIN_SHARE and (len(rest) == 0 or rest.max() <= top - MARKER_GAP_M):
        return top
    return None


def sensor_from_log(stream: LaserStream, defaults: dict) -> dict:
    """The sensor config (conf/sensor/ fields) of a stream: beams and angles as read, range_max
    the no-return marker (readings at or above it are no returns; without a marker,
    RANGE_HEADROOM x the longest reading), no_return_value and rate as laser_spec derives
    them; `defaults` gives the fields a log cannot say (mode, unknown_blocks)."""
    from scanloc.real.carmen_laser import default_no_return_value

    marker = no_return_marker(stream.ranges)
    if stream.max_range is not None and stream.max_range > 0:
        range_max = float(stream.max_range)
    elif marker is not None:
        range_max = marker
    else:
        range_max = RANGE_HEADROOM * float(np.nanmax(stream.ranges))
    steps = np.diff(stream.times)
    steps = steps[steps > 0]
    rate = 1.0 / float(np.median(steps)) if len(steps) else 1.0
    return dict(defaults) | {
        "num_beams": stream.num_beams,
        "angle_min": float(stream.angle_min),
        "angle_max": float(stream.angle_min + (stream.num_beams - 1) * stream.angle_increment),
        "range_min": 0.0,
        "range_max": round(range_max, 6),
        "rate_hz": round(rate, 6),
        "no_return_value": round(default_no_return_value(range_max), 6),
    }


def mount_from_params(log: CarmenLog, which: str = "front") -> np.ndarray | None:
    """The mount (x, y, θ) from the log's robot_<which>laser_* PARAMs; None when it has none."""
    prefix = f"robot_{which}laser_"
    found = {name: log.params.get(prefix + name) for name in MOUNT_PARAMS}
    if all(v is None for v in found.values()):
        return None
    mount = np.zeros(3)
    for k, name in enumerate(MOUNT_PARAMS):
        if found[name] is None:
            continue
        try:
            mount[k] = float(found[name])
        except ValueError:
            raise CarmenFormatError(
                f"{log.path}: PARAM '{prefix}{name}': expected a number, got {found[name]!r}"
            ) from None
    return mount


def estimate_mount_offset(laser_steps: np.ndarray, wheel_steps: np.ndarray) -> float | None:
    """The forward offset d (m) that best explains the laser poses' motion given the base's
    wheel increments (module doc), in closed form: m⁻¹ ⊕ u ⊕ m for m = (d, 0, 0) is
    (u_x + d (cos u_θ − 1), u_y + d sin u_θ), linear in d. laser_steps (S, 3): the corrected
    laser poses' increments, wheel_steps (S, 3): the wheels' over the same steps; None when the
    wheels never turn (the offset leaves no trace)."""
    v = np.asarray(laser_steps, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(wheel_steps, dtype=np.float64).reshape(-1, 3)
    if len(u) != len(v):
        raise ValueError(f"expected {len(v)} wheel steps, got {len(u)}")
    ax, ay = np.cos(u[:, 2]) - 1.0, np.sin(u[:, 2])
    denominator = float(np.sum(ax**2 + ay**2))
    if denominator < 1e-12:
        return None
    return float(np.sum((v[:, 0] - u[:, 0]) * ax + (v[:, 1] - u[:, 1]) * ay) / denominator)


# A PARAM offset that the motion contradicts by more than this is not used (intel's PARAM
# lines say 0.0 with host "nohost": placeholders; the motion says 8 cm).
MOUNT_AGREEMENT_M = 0.02


def resolve_mount(
    log: CarmenLog, which: str, laser_steps: np.ndarray, wheel_steps: np.ndarray
) -> tuple[np.ndarray, dict]:
    """The laser's mount (x, y, θ in the base frame) and how it was found: the PARAMs where
    present and the motion (estimate_mount_offset on the steps given: the mapping part)
    agrees within MOUNT_AGREEMENT_M, else the estimate (x only); the steps are increments
    (estimate_mount_offset) of the mapping part only."""
    found = estimate_mount_offset(laser_steps, wheel_steps)
    estimate = None if found is None else round(found, 4)
    param = mount_from_params(log, which)
    info: dict = {
        "estimated_offset_m": estimate,
        "param": None if param is None else param.tolist(),
    }
    if estimate is None:
        mount = np.zeros(3) if param is None else param
        return mount, info | {"source": "PARAM lines (the motion has no turns to check them)"}
    if param is not None and abs(param[0] - estimate) <= MOUNT_AGREEMENT_M:
        return param, info | {"source": "PARAM lines, agreeing with the motion"}
    source = "estimated from the mapping part's motion"
    if param is not None:
        source += f" (the PARAM's {param[0]} m disagrees with it)"
    return np.array([estimate, 0.0, 0.0]), info | {"source": source}
