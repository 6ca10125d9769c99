"""Read CARMEN laser logs (the Radish data sets: intel, freiburg-079, ...) into arrays.

One message per line, fields separated by white space, `#` lines are comments:
- `FLASER` / `RLASER` (front / rear laser, the old format): `n r1 … rn x y θ odom_x odom_y
  odom_θ ipc_timestamp ipc_hostname logger_timestamp`;
- `ROBOTLASER1` (front; `ROBOTLASER2` rear): `laser_type start_angle field_of_view
  angular_resolution maximum_range accuracy remission_mode n r1 … rn m e1 … em laser_x laser_y
  laser_θ robot_x robot_y robot_θ tv rv forward_safety_dist side_safety_dist turn_axis
  ipc_timestamp ipc_hostname logger_timestamp`;
- `ODOM x y θ tv rv accel ipc_timestamp ipc_hostname logger_timestamp`;
- `PARAM name value ipc_timestamp ipc_hostname logger_timestamp`.
Other messages (NEFF, SYNC, TRUEPOS, RAWLASER1, ...) are counted in `CarmenLog.skipped`.
Times are logger timestamps; a line without one (old logs) uses its ipc timestamp.

Corrected logs (Radish's `*-corrected.log`, written by a scan matcher) differ from raw ones:
- a laser line's pose AND its "odom" fields both hold the corrected pose (usable as truth);
- the ODOM stream is not raw odometry either: it is re-anchored at every scan. After each laser
  line the matcher wrote an ODOM line repeating the corrected pose (an "echo", with timestamp 0
  or garbage such as 1e-42), and the ODOM lines up to the next scan continue from that pose with
  the wheel odometry's motion. So ODOM stays within centimetres of the corrected path, and
  `carmen_odometry.odometry_at` interpolates a nearly corrected track; `scan_odometry`
  there rebuilds the drifting wheel odometry from the per-scan increments.
Angles are as logged (the corrected headings stray slightly past ±π).

This module holds the data types and the reader; `carmen_fields` reads one line's fields,
`carmen_laser` turns a stream into the project's sensor conventions.
"""

from __future__ import annotations

import gzip
import io
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanloc.real.carmen_fields import CarmenFormatError, LineFields

__all__ = [
    "CarmenFormatError",
    "CarmenLog",
    "LaserStream",
    "Odometry",
    "carmen_beam_angles",
    "read_carmen_log",
]

DEFAULT_FOV_DEG = 180.0
# Which message feeds each stream; the first one present wins (ROBOTLASER carries its angles).
STREAM_MESSAGES = {"front": ("ROBOTLASER1", "FLASER"), "rear": ("ROBOTLASER2", "RLASER")}
# PARAM names of the old-format lasers' geometry, as in carmen.ini: CARMEN 0.5's
# `laser_front_laser_*` and CARMEN 0.7's numbered `laser_laser1_*` (laser 1 is the front one);
# the first present wins.
PARAM_PREFIXES = {
    "front": ("laser_front_laser", "laser_laser1"),
    "rear": ("laser_rear_laser", "laser_laser2"),
}
# A field of view or resolution PARAM no larger than this is in radians: no scanning laser
# has a field of view of under 2 pi degrees, and CARMEN's degrees never go above 360.
MAX_RADIANS_VALUE = 2.0 * math.pi + 1e-6
_OLD_LASER_FIELDS = ("x", "y", "theta", "odom_x", "odom_y", "odom_theta")
_ROBOT_LASER_FIELDS = (
    "laser_pose_x",
    "laser_pose_y",
    "laser_pose_theta",
    "robot_pose_x",
    "robot_pose_y",
    "robot_pose_theta",
    "laser_tv",
    "laser_rv",
    "forward_safety_dist",
    "side_safety_dist",
    "turn_axis",
)
_ODOM_FIELDS = ("x", "y", "theta", "tv", "rv", "accel")


@dataclass(frozen=True)
class LaserStream:
    """The scans of one laser, in file order.

    Attributes:
        message: the message type read ("FLASER", "ROBOTLASER1", ...).
        times: float64 (N,) logger timestamps (ipc where a line has none).
        ranges: float32 (N, B) readings in metres as logged (no-return markers included).
        laser_poses: float64 (N, 3) laser pose on each line (corrected, in corrected logs).
        odom_poses: float64 (N, 3) the line's odometry / robot pose fields.
        angle_min: angle of beam 0 in the laser frame (radians).
        angle_increment: angle between neighbouring beams (radians, counter-clockwise).
        odom_index: int64 (N,) number of ODOM lines before each scan's line (to pair them).
        max_range: the laser's maximum range when the line states it (ROBOTLASER), else None.
    """

    message: str
    times: np.ndarray
    ranges: np.ndarray
    laser_poses: np.ndarray
    odom_poses: np.ndarray
    angle_min: float
    angle_increment: float
    odom_index: np.ndarray
    max_range: float | None = None

    @property
    def num_scans(self) -> int:
        return int(self.ranges.shape[0])

    @property
    def num_beams(self) -> int:
        return int(self.ranges.shape[1])

    def beam_angles(self) -> np.ndarray:
        """Beam angles in the laser frame (radians), float64 (B,)."""
        return self.angle_min + self.angle_increment * np.arange(self.num_beams, dtype=np.float64)


@dataclass(frozen=True)
class Odometry:
    """The ODOM lines in file order: times (M,), poses (M, 3), and `echo` (M,) marking lines
    that repeat the preceding laser line's pose (a corrected log's re-anchoring; their times are
    0 or garbage)."""

    times: np.ndarray
    poses: np.ndarray
    echo: np.ndarray


@dataclass(frozen=True)
class CarmenLog:
    """A parsed log: laser streams (None where absent), odometry, parameters, skipped counts."""

    path: Path
    front: LaserStream | None
    rear: LaserStream | None
    odometry: Odometry
    params: dict[str, str]
    skipped: dict[str, int]
    # How the beam-angle PARAMs were read, where a log has them: name -> {value, unit, degrees}
    angle_params: dict[str, dict[str, object]] = field(default_factory=dict)


def carmen_beam_angles(
    num_beams: int, fov_deg: float | None = None, resolution_deg: float | None = None
) -> tuple[float, float]:
    """(angle_min, angle_increment) in radians of an old-format (FLASER/RLASER) scan.

    Those lines carry no angles; CARMEN starts the scan at -fov/2 (fov 180° unless the
    PARAMs say otherwise) and, without a resolution PARAM, guesses the increment from the beam
    count: an odd count (181, 361) spans the fov inclusively, fov/(n-1); an even count (180,
    360) is a SICK scan with its last beam dropped, fov/n. Raises ValueError when the beams
    would not fit in the fov.
    """
    if num_beams < 1:
        raise ValueError(f"a scan needs at least one beam, got {num_beams}")
    fov = DEFAULT_FOV_DEG if fov_deg is None else float(fov_deg)
    if not 0.0 < fov <= 360.0:
        raise ValueError(f"laser fov must be in (0, 360] degrees, got {fov}")
    if resolution_deg is None:
        gaps = max(num_beams - 1, 1) if num_beams % 2 == 1 else num_beams
        resolution = fov / gaps
    else:
        resolution = float(resolution_deg)
    if not resolution > 0.0 or (num_beams - 1) * resolution > fov * (1.0 + 1e-9):
        raise ValueError(f"{num_beams} beams at {resolution}° do not fit in a {fov}° field of view")
    return math.radians(-0.5 * fov), math.radians(resolution)


def _fits(num_beams: int, fov_deg: float, resolution_deg: float) -> bool:
    """Whether n beams at the resolution fill the fov: inclusively, or as a SICK scan with its
    last beam dropped (carmen_beam_angles), within 1 %."""
    spans = ((num_beams - 1) * resolution_deg, num_beams * resolution_deg)
    return any(abs(span - fov_deg) <= 0.01 * fov_deg for span in spans)


def angle_units(num_beams: int, fov: float | None, resolution: float | None) -> tuple[str, str]:
    """("degrees" | "radians") of a log's fov and resolution PARAMs (either may be None).

    CARMEN writes degrees, but some logs write radians (a 180° fov as 3.14159). A fov of at
    most 2 pi is radians: no laser scans less than 6.3°. A resolution is degrees unless only
    radians make the beam count fill the fov (the default 180° without a fov PARAM), as
    carmen_beam_angles lays beams out.
    """

    def could_be_radians(value: float | None) -> bool:
        return value is not None and 0 < value <= MAX_RADIANS_VALUE

    fov_unit = "radians" if could_be_radians(fov) else "degrees"
    if resolution is None or not could_be_radians(resolution):
        return fov_unit, "degrees"
    fov_deg = (
        DEFAULT_FOV_DEG
        if fov is None
        else fov * (math.degrees(1.0) if fov_unit == "radians" else 1.0)
    )
    if not _fits(num_beams, fov_deg, resolution) and _fits(
        num_beams, fov_deg, math.degrees(resolution)
    ):
        return fov_unit, "radians"
    return fov_unit, "degrees"


@dataclass
class _Scans:
    """One message type's scans as they are read, with the checks that keep a stream regular."""

    message: str
    first_where: str
    num_beams: int
    angle_min: float | None = None
    angle_increment: float | None = None
    max_range: float | None = None
    times: list[float] = field(default_factory=list)
    ranges: list[np.ndarray] = field(default_factory=list)
    laser_poses: list[tuple[float, ...]] = field(default_factory=list)
    odom_poses: list[tuple[float, ...]] = field(default_factory=list)
    odom_index: list[int] = field(default_factory=list)

    def stream(self, angle_min: float, angle_increment: float) -> LaserStream:
        return LaserStream(
            message=self.message,
            times=np.asarray(self.times, dtype=np.float64),
            ranges=np.asarray(self.ranges, dtype=np.float32).reshape(-1, self.num_beams),
            laser_poses=np.asarray(self.laser_poses, dtype=np.float64).reshape(-1, 3),
            odom_poses=np.asarray(self.odom_poses, dtype=np.float64).reshape(-1, 3),
            angle_min=angle_min,
            angle_increment=angle_increment,
            odom_index=np.asarray(self.odom_index, dtype=np.int64),
            max_range=self.max_range,
        )


class _Reader:
    """Parses a log line by line into per-message accumulators."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.scans: dict[str, _Scans] = {}
        self.odom_times: list[float] = []
        self.odom_poses: list[tuple[float, float, float]] = []
        self.odom_echo: list[bool] = []
        self.params: dict[str, str] = {}
        self.angle_params: dict[str, dict[str, object]] = {}
        self.param_where: dict[str, str] = {}
        self.skipped: dict[str, int] = {}
        self.last_laser: tuple[tuple[float, ...], tuple[float, ...]] | None = None
        self.laser_before = self.last_laser
        self.handlers: dict[str, Callable[[LineFields], None]] = {
            "FLASER": self.old_laser,
            "RLASER": self.old_laser,
            "ROBOTLASER1": self.robot_laser,
            "ROBOTLASER2": self.robot_laser,
            "ODOM": self.odom,
            "PARAM": self.param,
        }

    def feed(self, lineno: int, text: str) -> None:
        tokens = text.split()
        if not tokens or tokens[0].startswith("#"):
            return
        handler = self.handlers.get(tokens[0])
        if handler is None:
            self.skipped[tokens[0]] = self.skipped.get(tokens[0], 0) + 1
            self.last_laser = None
            return
        self.laser_before, self.last_laser = self.last_laser, None
        handler(LineFields(f"{self.path}:{lineno}", tokens))

    def _scans(self, line: LineFields, count_field: str, n: int) -> _Scans:
        scans = self.scans.get(line.tag)
        if scans is None:
            scans = self.scans[line.tag] = _Scans(line.tag, line.where, n)
        elif n != scans.num_beams:
            raise line.error(
                count_field,
                f"{scans.num_beams} readings like the stream's first scan ({scans.first_where})",
                str(n),
            )
        return scans

    def _add(
        self, scans: _Scans, time: float, ranges: np.ndarray, laser: tuple, odom: tuple
    ) -> None:
        scans.times.append(time)
        scans.ranges.append(ranges.astype(np.float32))
        scans.laser_poses.append(laser)
        scans.odom_poses.append(odom)
        scans.odom_index.append(len(self.odom_times))
        self.last_laser = (laser, odom)

    def old_laser(self, line: LineFields) -> None:
        n = line.count("n")
        ranges = line.numbers(n, "r")
        values = tuple(line.number(name) for name in _OLD_LASER_FIELDS)
        scans = self._scans(line, "n", n)
        self._add(scans, line.timestamp(), ranges, values[:3], values[3:])

    def robot_laser(self, line: LineFields) -> None:
        line.number("laser_type")
        start = line.number("start_angle")
        line.number("field_of_view")
        resolution = line.number("angular_resolution")
        max_range = line.number("maximum_range")
        line.number("accuracy")
        line.number("remission_mode")
        n = line.count("num_readings")
        ranges = line.numbers(n, "range")
        line.numbers(line.count("num_remissions"), "remission")
        values = tuple(line.number(name) for name in _ROBOT_LASER_FIELDS)
        scans = self._scans(line, "num_readings", n)
        if scans.angle_min is None:
            scans.angle_min, scans.angle_increment, scans.max_range = start, resolution, max_range
        for name, value, first in (
            ("start_angle", start, scans.angle_min),
            ("angular_resolution", resolution, scans.angle_increment),
        ):
            if value != first:
                raise line.error(name, f"{first} like the stream's first scan", value)
        self._add(scans, line.timestamp(), ranges, values[:3], values[3:6])

    def odom(self, line: LineFields) -> None:
        pose = tuple(line.number(name) for name in _ODOM_FIELDS)[:3]
        self.odom_times.append(line.timestamp())
        self.odom_poses.append(pose)
        # an echo repeats the laser line just before it (its laser or its robot pose)
        self.odom_echo.append(self.laser_before is not None and pose in self.laser_before)

    def param(self, line: LineFields) -> None:
        name = line.word("name")
        line.word("value")
        # name value ipc_timestamp ipc_hostname logger_timestamp; a value may hold spaces, and
        # intel's two PARAM lines have only `host logger_timestamp` after the value
        tokens = line.tokens
        self.params[name] = " ".join(tokens[2:-3]) if len(tokens) > 6 else tokens[2]
        self.param_where[name] = line.where

    def _param_number(self, name: str) -> float | None:
        if name not in self.params:
            return None
        try:
            return float(self.params[name])
        except ValueError:
            raise CarmenFormatError(
                f"{self.param_where[name]}: PARAM '{name}': expected a number of degrees or "
                f"radians, got {self.params[name]!r}"
            ) from None

    def _angle_params(self, which: str) -> tuple[str, str]:
        """The (fov, resolution) PARAM names of a laser in the log's spelling."""
        for prefix in PARAM_PREFIXES[which]:
            names = f"{prefix}_fov", f"{prefix}_resolution"
            if any(name in self.params for name in names):
                return names
        prefix = PARAM_PREFIXES[which][0]
        return f"{prefix}_fov", f"{prefix}_resolution"

    def _degrees(self, name: str, value: float | None, unit: str) -> float | None:
        """A beam-angle PARAM in degrees, its unit recorded in angle_params."""
        if value is None:
            return None
        degrees = math.degrees(value) if unit == "radians" else value
        self.angle_params[name] = {"value": value, "unit": unit, "degrees": degrees}
        return degrees

    def stream(self, which: str) -> LaserStream | None:
        present = [m for m in STREAM_MESSAGES[which] if m in self.scans]
        if not present:
            return None
        for message in present[1:]:  # the preferred message supersedes the old format
            self.skipped[message] = len(self.scans[message].times)
        scans = self.scans[present[0]]
        if scans.angle_min is not None and scans.angle_increment is not None:
            return scans.stream(scans.angle_min, scans.angle_increment)
        fov_name, res_name = self._angle_params(which)
        fov, resolution = self._param_number(fov_name), self._param_number(res_name)
        fov_unit, res_unit = angle_units(scans.num_beams, fov, resolution)
        fov = self._degrees(fov_name, fov, fov_unit)
        resolution = self._degrees(res_name, resolution, res_unit)
        try:
            angle_min, increment = carmen_beam_angles(scans.num_beams, fov, resolution)
        except ValueError as err:
            raise CarmenFormatError(
                f"{self.path}: {scans.message} beam angles from PARAM {fov_name}={fov}, "
                f"{res_name}={resolution}: {err}"
            ) from None
        return scans.stream(angle_min, increment)


def _open_text(path: Path) -> io.TextIOBase:
    with open(path, "rb") as probe:
        gzipped = probe.read(2) == b"\x1f\x8b"
    if gzipped:
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8", errors="replace")
    return open(path, encoding="utf-8", errors="replace")


def read_carmen_log(path: str | os.PathLike[str]) -> CarmenLog:
    """Parse a CARMEN log, plain or gzipped (detected from its first bytes).

    Raises CarmenFormatError naming the file, the 1-based line number and the field for a
    malformed line, a stream whose scans change beam count, or unusable beam-angle PARAMs.
    """
    path = Path(path)
    reader = _Reader(path)
    lineno = 0
    try:
        with _open_text(path) as text:
            for lineno, line in enumerate(text, start=1):
                reader.feed(lineno, line)
    except (OSError, EOFError) as exc:
        raise CarmenFormatError(
            f"{path}:{lineno + 1}: cannot read line {lineno + 1} (expected a readable plain or "
            f"gzipped CARMEN log after line {lineno}): {exc}"
        ) from exc
    front, rear = reader.stream("front"), reader.stream("rear")
    odometry = Odometry(
        times=np.asarray(reader.odom_times, dtype=np.float64),
        poses=np.asarray(reader.odom_poses, dtype=np.float64).reshape(-1, 3),
        echo=np.asarray(reader.odom_echo, dtype=bool),
    )
    return CarmenLog(
        path=path,
        front=front,
        rear=rear,
        odometry=odometry,
        params=reader.params,
        skipped=dict(sorted(reader.skipped.items())),
        angle_params=reader.angle_params,
    )
