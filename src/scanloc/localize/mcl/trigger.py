"""When amcl updates, resamples and publishes (amcl_node.cpp's laserReceived).

- Update: once the odometry has moved more than `update_min_d` along the odometry frame's x OR
  y axis (each on its own, as amcl compares them) or turned more than `update_min_a`.
- Resample: every `resample_interval`-th update.
- Publish an estimate: after a resampling (amcl), or after every update when
  `publish_every_update` (a scanloc switch).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanloc.localize.mcl.motion import odometry_delta


@dataclass(frozen=True)
class UpdateTrigger:
    """amcl's update, resample and publish rules."""

    update_min_d: float = 0.2
    update_min_a: float = 0.5235987755982988  # π/6
    resample_interval: int = 2
    publish_every_update: bool = False

    def __post_init__(self) -> None:
        if self.resample_interval < 1:
            raise ValueError(f"resample_interval must be >= 1, got {self.resample_interval}")
        if self.update_min_d < 0 or self.update_min_a < 0:
            raise ValueError("update_min_d and update_min_a must be >= 0")

    def moved(self, last_odom: np.ndarray, odom: np.ndarray) -> bool:
        """Whether the odometry moved enough since the last update for a new one."""
        delta = odometry_delta(last_odom, odom)
        return bool(
            abs(delta[0]) > self.update_min_d
            or abs(delta[1]) > self.update_min_d
            or abs(delta[2]) > self.update_min_a
        )

    def resample_due(self, updates: int) -> bool:
        """Whether the `updates`-th update since the initialisation resamples."""
        return updates % self.resample_interval == 0

    def publishes(self, updated: bool, resampled: bool) -> bool:
        """Whether this scan computes a new estimate."""
        return resampled or (updated and self.publish_every_update)
