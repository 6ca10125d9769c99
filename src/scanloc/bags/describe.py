"""The sensor config (conf/sensor/<name>.yaml, scanloc.sensor.laser.LaserSpec's fields) that a
bag's LaserScans imply, so that nobody has to copy beam counts and float32 angles by hand:

    python -m scanloc.bags.describe bag=/data/robot_2024-05-01 [scan_topic=/scan] > \\
        conf/sensor/robot_lidar.yaml

The bag stage's `sensor=auto` (conf/sensor/auto.yaml) takes its laser from the same function,
`sensor_from_scans`, and writes it to data/maps/<name>/sensor.yaml.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from scanloc.bags.cli import parse_key_values
from scanloc.bags.errors import BagError
from scanloc.bags.pairing import median_period_ns
from scanloc.bags.topics import read_topics
from scanloc.real.carmen_laser import NO_RETURN_FACTOR, default_no_return_value
from scanloc.sensor.laser import LaserSpec

# A LaserScan's float32 ±π passes ±π by 8.7e-8 rad: clipped when within this.
ANGLE_CLIP_RAD = 1e-6
AUTO_EXTRAS = {"mode": "exact", "unknown_blocks": False}  # what a bag cannot say


def _float32(value: float) -> float:
    """A LaserScan's float32 field as its shortest decimal (0.05, not 0.05000000074505806)."""
    return float(str(np.float32(value)))


def _clipped(angle: float) -> float:
    if math.pi < abs(angle) <= math.pi + ANGLE_CLIP_RAD:
        return math.copysign(math.pi, angle)
    return angle


def sensor_from_scans(
    bag: str | Path, topic: str, geometry: dict[str, Any], stamps_ns: Sequence[int]
) -> dict[str, Any]:
    """The sensor config of a bag's LaserScans of this geometry (topics.py `_scan_geometry`)
    and stamps: beams, angles and range limits as the scans say, the rate from their median
    period, no_return_value NO_RETURN_FACTOR x range_max, `mode` and `unknown_blocks` as
    AUTO_EXTRAS. BagError if they make no LaserSpec."""
    period = median_period_ns(stamps_ns)
    range_max = _float32(geometry["range_max"])
    sensor = {
        "num_beams": int(geometry["num_beams"]),
        "angle_min": _clipped(_float32(geometry["angle_min"])),
        "angle_max": _clipped(_float32(geometry["angle_max"])),
        "range_min": _float32(geometry["range_min"]),
        "range_max": range_max,
        "rate_hz": round(1e9 / period, 6) if period else LaserSpec().rate_hz,
        "no_return_value": round(default_no_return_value(range_max), 6),
    }
    try:
        LaserSpec(**sensor)
    except ValueError as err:
        raise BagError(bag, topic, f"the scans make no laser config: {err}") from None
    return sensor | AUTO_EXTRAS


def _yaml_float(value: float) -> str:
    """repr, with the '.0' YAML 1.1 needs to read 1e-06 as a float rather than a string."""
    text = repr(float(value))
    mantissa, e, exponent = text.partition("e")
    return f"{mantissa}.0e{exponent}" if e and "." not in mantissa else text


def sensor_yaml(sensor: dict[str, Any], bag: str | Path, topic: str, scans: int) -> str:
    """`sensor` as a commented conf/sensor file (yaml.safe_load gives `sensor` back)."""
    inc = (sensor["angle_max"] - sensor["angle_min"]) / (sensor["num_beams"] - 1)
    comments = {
        "num_beams": "ranges per LaserScan",
        "angle_min": "beam 0 (radians; counter-clockwise, 0 ahead of the laser)",
        "angle_max": f"the last beam; increment {inc:.9g} rad = {math.degrees(inc):.6g} deg",
        "range_min": "readings below it are no returns (REP 117)",
        "range_max": "readings above it are no returns",
        "rate_hz": "1 / the median time between the scans' header stamps",
        "no_return_value": f"a no-return beam's reading: above range_max, {NO_RETURN_FACTOR} x "
        "it as in conf/sensor/",
        "mode": "beams are cast exactly (stdr: STDR's whole-cell stepping)",
        "unknown_blocks": "unknown map cells do not stop a simulated beam",
    }
    lines = [
        f"# The laser of {bag} ({topic}: {scans} LaserScans), as scanloc.bags.describe reads",
        "# it: the fields of scanloc.sensor.laser.LaserSpec, plus how simulated beams are cast.",
    ]
    for key, value in sensor.items():
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, float):
            text = _yaml_float(value)
        else:
            text = str(value)
        note = comments.get(key)
        lines.append(f"{key}: {text}" + (f"  # {note}" if note else ""))
    return "\n".join(lines) + "\n"


def sensor_of_bag(bag: str | Path, scan_topic: str = "/scan") -> tuple[dict[str, Any], int]:
    """(the sensor config of the bag's scans on `scan_topic`, how many scans it has)."""
    scans = read_topics(bag, scan_topic).scans
    if not scans.stamps:
        raise BagError(bag, scan_topic, "no messages: expected LaserScans")
    return sensor_from_scans(bag, scan_topic, scans.geometry, scans.stamps), len(scans.stamps)


DEFAULTS = {"bag": "???", "scan_topic": "/scan"}
PROGRAM = "python -m scanloc.bags.describe"


def main(argv: Sequence[str] | None = None) -> str:
    """Print the bag's sensor file on stdout; a bad bag is one line on stderr, exit status 2."""
    values = parse_key_values(PROGRAM, __doc__ or "", argv, DEFAULTS)
    bag, topic = str(values["bag"]), str(values["scan_topic"])
    try:
        sensor, count = sensor_of_bag(bag, topic)
    except (ValueError, FileNotFoundError) as err:  # BagError is a ValueError
        print(f"{PROGRAM}: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    text = sensor_yaml(sensor, bag, topic, count)
    sys.stdout.write(text)
    return text


if __name__ == "__main__":
    main()
