"""Laser odometry on the real logs: small_gicp's ICP / PLANE_ICP / GICP on consecutive scans
(seeded with the wheel increment), flat (z = 0) or extruded to a wall (`GICP@0.1`: layers at
z = ±0.1 m), against the wheel odometry, per-step errors and drift against
the corrected poses, and the time per scan pair. Prints one JSON line last.

    python benchmarks/laser_odometry.py [--logs intel fr079] [--max-scans N] [--quick]

--quick: intel's first 100 scans, flat ICP against extruded GICP (seconds; for the tests).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from scanloc.real.carmen import read_carmen_log
from scanloc.real.carmen_laser import clean_ranges
from scanloc.real.carmen_odometry import base_poses, scan_odometry, wrap_logged_headings
from scanloc.real.log_sensor import resolve_mount
from scanloc.trajectory.laser_odometry import LaserOdometryConfig, drift, increments, laser_odometry

LOGS = {
    "intel": "../shared/data/carmen/intel-corrected.log.gz",
    "fr079": "../shared/data/carmen/freiburg-079-corrected.log.gz",
}
RANGE_MAX = 50.0


def run(name: str, max_scans: int | None, methods: list[str]) -> dict:
    log = read_carmen_log(LOGS[name])
    stream = log.front
    count = stream.num_scans if max_scans is None else min(max_scans, stream.num_scans)
    truth = stream.laser_poses[:count].copy()
    truth[:, 2] = wrap_logged_headings(truth[:, 2])
    mount, _ = resolve_mount(
        log, "front", increments(truth), increments(scan_odometry(log)[:count])
    )
    wheel = scan_odometry(log, "front", mount)[:count]
    ranges = clean_ranges(stream.ranges[:count], RANGE_MAX)
    base = base_poses(truth, mount)
    out = {"scans": count, "mount": [float(v) for v in mount], "wheel": drift(wheel, base)}
    for method in methods:
        registration, _, layers = method.partition("@")
        cfg = replace(
            LaserOdometryConfig(), registration=registration, extrude_m=float(layers or 0)
        )
        start = time.perf_counter()
        odo, fallbacks = laser_odometry(ranges, stream.beam_angles(), RANGE_MAX, wheel, mount, cfg)
        ms = 1000.0 * (time.perf_counter() - start) / max(count - 1, 1)
        out[method] = drift(odo, base) | {"ms_per_pair": round(ms, 3), "fallbacks": fallbacks}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--logs", nargs="+", default=list(LOGS))
    parser.add_argument("--max-scans", type=int, default=None)
    parser.add_argument(  # <small_gicp registration>[@<extrusion m>]
        "--methods", nargs="+", default=["ICP", "GICP", "ICP@0.1", "PLANE_ICP@0.1", "GICP@0.1"]
    )
    parser.add_argument("--quick", action="store_true", help=__doc__.split("--quick: ")[1])
    args = parser.parse_args()
    if args.quick:
        args.logs, args.max_scans, args.methods = ["intel"], 100, ["ICP", "GICP@0.1"]
    if not all(Path(LOGS[n]).is_file() for n in args.logs):
        raise SystemExit(f"logs not found: {[LOGS[n] for n in args.logs]}")
    result = {name: run(name, args.max_scans, args.methods) for name in args.logs}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
