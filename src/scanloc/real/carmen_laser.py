"""A CARMEN laser stream in the project's sensor conventions: its LaserSpec and its readings
with "no return" encoded as in the simulated scans."""

from __future__ import annotations

import numpy as np

from scanloc.real.carmen import LaserStream
from scanloc.sensor.laser import LaserSpec

# The project's simulated scans fill "no return" with 7.0 m for a 5.6 m laser (LaserSpec's
# defaults): a value 1.25 x range_max, above every real reading, in the same proportion here.
NO_RETURN_FACTOR = LaserSpec().no_return_value / LaserSpec().range_max


def default_no_return_value(max_range: float) -> float:
    """The fill value for "no return": NO_RETURN_FACTOR x max_range (7.0 m for 5.6 m)."""
    return NO_RETURN_FACTOR * float(max_range)


def clean_ranges(
    ranges: np.ndarray, max_range: float, no_return_value: float | None = None
) -> np.ndarray:
    """float32 readings with "no return" encoded as in the project's simulated scans.

    Readings >= max_range (the logs' max-range markers, 81.83 / 81.91 m, and anything the
    sensor could not measure reliably), <= 0 or NaN become `no_return_value` (default
    `default_no_return_value(max_range)`, above max_range).
    """
    if not max_range > 0:
        raise ValueError(f"max_range must be > 0, got {max_range}")
    fill = default_no_return_value(max_range) if no_return_value is None else no_return_value
    if not fill > max_range:
        raise ValueError(f"no_return_value ({fill}) must exceed max_range ({max_range})")
    readings = np.asarray(ranges, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        valid = (readings > 0) & (readings < np.float32(max_range))
    return np.where(valid, readings, np.float32(fill)).astype(np.float32)


def laser_spec(
    stream: LaserStream, max_range: float, no_return_value: float | None = None
) -> LaserSpec:
    """The LaserSpec of a stream: its beams and angles, range limits [0, max_range], the
    fill value for "no return" (see clean_ranges) and its scan rate (median, as logged)."""
    fill = default_no_return_value(max_range) if no_return_value is None else no_return_value
    steps = np.diff(stream.times)
    steps = steps[steps > 0]
    rate = 1.0 / float(np.median(steps)) if len(steps) else LaserSpec().rate_hz
    return LaserSpec(
        num_beams=stream.num_beams,
        angle_min=stream.angle_min,
        angle_max=stream.angle_min + (stream.num_beams - 1) * stream.angle_increment,
        range_min=0.0,
        range_max=float(max_range),
        rate_hz=rate,
        no_return_value=float(fill),
    )
