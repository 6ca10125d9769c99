"""Which topics and frames a bag uses: the ROS defaults (REP 105), configurable per bag."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any


@dataclass(frozen=True)
class BagLayout:
    """Topic names and frame ids, read and written alike.

    `odom` is read from the odometry topic when it is in the bag, else from the tf transform
    odom_frame → base_frame (`odom_source` = "auto"; "topic" or "tf" force one). The laser's
    mounting is the static transform base_frame → the scans' frame (`laser_frame` when the
    scans name none).
    """

    scan: str = "/scan"
    odom: str = "/odom"
    tf: str = "/tf"
    tf_static: str = "/tf_static"
    map: str = "/map"
    ground_truth: str = "/ground_truth"
    map_frame: str = "map"
    odom_frame: str = "odom"
    base_frame: str = "base_link"
    laser_frame: str = "laser"
    odom_source: str = "auto"

    def __post_init__(self) -> None:
        if self.odom_source not in ("auto", "topic", "tf"):
            raise ValueError(
                f"bag layout field 'odom_source': expected auto, topic or tf, got "
                f"{self.odom_source!r}"
            )


def layout_from_config(cfg: Mapping[str, Any] | None) -> BagLayout:
    """A BagLayout from a config mapping (conf/bag.yaml `topics` and `frames` merged)."""
    cfg = dict(cfg or {})
    names = {f.name for f in fields(BagLayout)}
    unknown = sorted(set(cfg) - names)
    if unknown:
        raise ValueError(
            f"bag layout: unknown field(s) {unknown}; expected some of {sorted(names)}"
        )
    for key, value in cfg.items():
        if not isinstance(value, str) or not value:
            raise ValueError(
                f"bag layout field '{key}': expected a non-empty string, got {value!r}"
            )
    return BagLayout(**cfg)
