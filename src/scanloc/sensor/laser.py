"""The laser scanner's specification: beam geometry, range limits and "no return" encoding."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# How far beam angles may pass ±pi: a LaserScan's float32 angle_max for a 360° laser is
# float32(pi) = pi + 8.7e-8, and angles only ever enter cos and sin.
ANGLE_SLACK_RAD = 1e-6


@dataclass(frozen=True)
class LaserSpec:
    """A planar lidar. Defaults: Hokuyo URG-04LX-UG01 as simulated by STDR (paper-spec §2).

    Beam 0 points to angle_min (the robot's right), beams go counter-clockwise, and the
    increment is (angle_max - angle_min) / (num_beams - 1).
    """

    num_beams: int = 667
    angle_min: float = -2.09439510239
    angle_max: float = 2.09439510239
    range_min: float = 0.02
    range_max: float = 5.6
    rate_hz: float = 10.0
    no_return_value: float = 7.0

    def __post_init__(self) -> None:
        if self.num_beams < 2:
            raise ValueError(f"num_beams must be >= 2, got {self.num_beams}")
        if not self.angle_max > self.angle_min:
            raise ValueError(
                f"angle_max ({self.angle_max}) must exceed angle_min ({self.angle_min})"
            )
        limit = math.pi + ANGLE_SLACK_RAD
        if not (-limit <= self.angle_min and self.angle_max <= limit):
            raise ValueError(
                f"angle_min and angle_max must lie within [-pi, pi] (radians), got "
                f"{self.angle_min!r} and {self.angle_max!r}"
            )
        if not 0 <= self.range_min < self.range_max:
            raise ValueError(
                f"need 0 <= range_min < range_max, got {self.range_min}, {self.range_max}"
            )

    @property
    def angle_increment(self) -> float:
        return (self.angle_max - self.angle_min) / (self.num_beams - 1)

    def beam_angles(self) -> np.ndarray:
        """Beam angles in the sensor frame (radians), float64, shape (num_beams,)."""
        return self.angle_min + self.angle_increment * np.arange(self.num_beams, dtype=np.float64)
