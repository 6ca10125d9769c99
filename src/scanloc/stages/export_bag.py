"""Export a scanloc run as a ROS bag (scanloc.bags.write): ROS 2 (sqlite3 or mcap) or ROS 1.

    python -m scanloc.stages.export_bag run=data/trajectories/<name> \\
        map=data/maps/<map>/map.yaml out=<dir> format=ros2|ros1 [storage=sqlite3|mcap]

A plain command line, not a Hydra app: it is no pipeline stage (nothing of DVC's), and Hydra's
config groups conf/run/ and conf/map/ would claim the keys `run=` and `map=`. `sensor=<name>`
(conf/sensor/<name>.yaml) is used only for a run whose meta.json records no sensor.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import yaml

from scanloc.bags.cli import parse_key_values
from scanloc.bags.write import export_run
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages._app import conf_dir, reporting_user_errors

DEFAULTS = {
    "run": "???",
    "map": "",
    "out": "???",
    "format": "ros2",
    "storage": "sqlite3",
    "sensor": "urg04lx",
}


def main(argv: Sequence[str] | None = None) -> Path:
    values = parse_key_values("python -m scanloc.stages.export_bag", __doc__ or "", argv, DEFAULTS)
    sensor_path = Path(conf_dir()) / "sensor" / f"{values['sensor']}.yaml"
    fallback = None
    if sensor_path.is_file():
        fallback = laser_spec_from_config(yaml.safe_load(sensor_path.read_text()))
    out = export_run(
        values["run"],
        values["map"] or None,
        values["out"],
        fmt=str(values["format"]),
        storage=str(values["storage"]),
        sensor=fallback,
    )
    print(f"scanloc: wrote {out}", file=sys.stderr)
    return out


if __name__ == "__main__":
    reporting_user_errors("scanloc.stages.export_bag", main)()
