"""When the filter updates, resamples and publishes: policies as parts (Beluga's `on_motion`,
`every_n`), chosen by the `filter` section.

- Update (`update_trigger`): `on_motion`, amcl's rule, once the odometry has moved more than
  `update_min_d` along the odometry frame's x OR y axis (each on its own, as amcl compares
  them) or turned more than `update_min_a`; `every_scan`, on every scan, standing still too.
- Resample: every `resample_interval`-th update (amcl; `selective_resampling` may still skip
  it: resampler.py).
- Publish an estimate: after every update that was due to resample (amcl), or after every
  update when `publish_every_update` (a scanloc switch).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from scanloc.localize.mcl.motion import odometry_delta


class UpdateTrigger(Protocol):
    """Whether a scan updates the filter, given the odometry since the last update."""

    def moved(self, last_odom: np.ndarray, odom: np.ndarray) -> bool: ...


@dataclass(frozen=True)
class OnMotion:
    """amcl's update rule: a move of `update_min_d` in x or y, or a turn of `update_min_a`."""

    update_min_d: float
    update_min_a: float

    def __post_init__(self) -> None:
        if self.update_min_d < 0 or self.update_min_a < 0:
            raise ValueError("update_min_d and update_min_a must be >= 0")

    def moved(self, last_odom: np.ndarray, odom: np.ndarray) -> bool:
        delta = odometry_delta(last_odom, odom)
        return bool(
            abs(delta[0]) > self.update_min_d
            or abs(delta[1]) > self.update_min_d
            or abs(delta[2]) > self.update_min_a
        )


class EveryScan:
    """Update on every scan, whether the robot moved or not."""

    def moved(self, last_odom: np.ndarray, odom: np.ndarray) -> bool:
        return True


# name -> trigger from (update_min_d, update_min_a)
UPDATE_TRIGGERS: dict[str, Callable[[float, float], UpdateTrigger]] = {
    "on_motion": OnMotion,
    "every_scan": lambda update_min_d, update_min_a: EveryScan(),
}


@dataclass(frozen=True)
class Schedule:
    """amcl's resample and publish rules."""

    resample_interval: int
    publish_every_update: bool

    def __post_init__(self) -> None:
        if self.resample_interval < 1:
            raise ValueError(f"resample_interval must be >= 1, got {self.resample_interval}")

    def resample_due(self, updates: int) -> bool:
        """Whether the `updates`-th update since the initialisation resamples."""
        return updates % self.resample_interval == 0

    def publishes(self, updated: bool, resample_due: bool) -> bool:
        """Whether this scan computes a new estimate."""
        return resample_due or (updated and self.publish_every_update)
