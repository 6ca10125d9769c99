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
  `odometry_at` interpolates a nearly corrected track; `scan_odometry` rebuilds the drifting
  wheel odometry from the per-scan increments.
Angles are as logged (the corrected headings stray slightly past ±π).
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

from scanloc.pose import wrap_angle
from scanloc.sensor.laser import LaserSpec

DEFAULT_FOV_DEG = 180.0
# The project's simulated scans fill "no return" with 7.0 m for a 5.6 m laser (LaserSpec's
# defaults): a value 1.25 x range_max, above every real reading, in the same proportion here.
NO_RETURN_FACTOR = LaserSpec().no_return_value / LaserSpec().range_max
# Which message feeds each stream; the first one present wins (ROBOTLASER carries its angles).
STREAM_MESSAGES = {"front": ("ROBOTLASER1", "FLASER"), "rear": ("ROBOTLASER2", "RLASER")}
# PARAM names of the old-format lasers' geometry (degrees), as in carmen.ini.
PARAM_PREFIX = {"front": "laser_front_laser", "rear": "laser_rear_laser"}
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


class CarmenFormatError(ValueError):
    """A line that breaks the CARMEN log format; the message names file, line and field."""


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


class _Line:
    """The fields of one line, read left to right; errors name file, line number and field."""

    def __init__(self, where: str, tokens: list[str]) -> None:
        self.where = where
        self.tag = tokens[0]
        self.tokens = tokens
        self.pos = 1
        self.last = self.tag

    def error(self, name: str, expected: str, got: object) -> CarmenFormatError:
        return CarmenFormatError(
            f"{self.where}: {self.tag} field '{name}': expected {expected}, got {got!r}"
        )

    def _missing(self, name: str) -> CarmenFormatError:
        return CarmenFormatError(
            f"{self.where}: {self.tag} field '{name}': missing (the line ends after "
            f"{len(self.tokens)} fields)"
        )

    def word(self, name: str) -> str:
        if self.pos >= len(self.tokens):
            raise self._missing(name)
        self.pos += 1
        self.last = name
        return self.tokens[self.pos - 1]

    def number(self, name: str) -> float:
        token = self.word(name)
        try:
            return float(token)
        except ValueError:
            raise self.error(name, "a number", token) from None

    def count(self, name: str) -> int:
        token = self.word(name)
        try:
            value = int(token)
        except ValueError:
            raise self.error(name, "a count (a whole number >= 0)", token) from None
        if value < 0:
            raise self.error(name, "a count (a whole number >= 0)", token)
        return value

    def numbers(self, n: int, prefix: str) -> np.ndarray:
        """n numbers named prefix1 … prefixn."""
        chunk = self.tokens[self.pos : self.pos + n]
        if len(chunk) < n:
            raise self._missing(f"{prefix}{len(chunk) + 1}")
        try:
            values = np.fromiter(map(float, chunk), dtype=np.float64, count=n)
        except ValueError:
            for k, token in enumerate(chunk):
                try:
                    float(token)
                except ValueError:
                    raise self.error(f"{prefix}{k + 1}", "a number", token) from None
            raise
        self.pos += n
        self.last = f"{prefix}{n}" if n else self.last
        return values

    def timestamp(self) -> float:
        """`ipc_hostname [logger_timestamp]` after the ipc timestamp: the time to use."""
        ipc = self.number("ipc_timestamp")
        self.word("ipc_hostname")
        logger = self.number("logger_timestamp") if self.pos < len(self.tokens) else ipc
        if self.pos < len(self.tokens):
            raise CarmenFormatError(
                f"{self.where}: {self.tag}: {len(self.tokens) - self.pos} field(s) after field "
                f"'{self.last}', the last one, starting with {self.tokens[self.pos]!r}"
            )
        return logger


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
        self.param_where: dict[str, str] = {}
        self.skipped: dict[str, int] = {}
        self.last_laser: tuple[tuple[float, ...], tuple[float, ...]] | None = None
        self.laser_before = self.last_laser
        self.handlers: dict[str, Callable[[_Line], None]] = {
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
        handler(_Line(f"{self.path}:{lineno}", tokens))

    def _scans(self, line: _Line, count_field: str, n: int) -> _Scans:
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

    def old_laser(self, line: _Line) -> None:
        n = line.count("n")
        ranges = line.numbers(n, "r")
        values = tuple(line.number(name) for name in _OLD_LASER_FIELDS)
        scans = self._scans(line, "n", n)
        self._add(scans, line.timestamp(), ranges, values[:3], values[3:])

    def robot_laser(self, line: _Line) -> None:
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

    def odom(self, line: _Line) -> None:
        pose = tuple(line.number(name) for name in _ODOM_FIELDS)[:3]
        self.odom_times.append(line.timestamp())
        self.odom_poses.append(pose)
        # an echo repeats the laser line just before it (its laser or its robot pose)
        self.odom_echo.append(self.laser_before is not None and pose in self.laser_before)

    def param(self, line: _Line) -> None:
        name = line.word("name")
        line.word("value")
        # name value ipc_timestamp ipc_hostname logger_timestamp; a value may hold spaces, and
        # intel's two PARAM lines have only `host logger_timestamp` after the value
        tokens = line.tokens
        self.params[name] = " ".join(tokens[2:-3]) if len(tokens) > 6 else tokens[2]
        self.param_where[name] = line.where

    def _param_degrees(self, name: str) -> float | None:
        if name not in self.params:
            return None
        try:
            return float(self.params[name])
        except ValueError:
            raise CarmenFormatError(
                f"{self.param_where[name]}: PARAM '{name}': expected a number of degrees, "
                f"got {self.params[name]!r}"
            ) from None

    def stream(self, which: str) -> LaserStream | None:
        present = [m for m in STREAM_MESSAGES[which] if m in self.scans]
        if not present:
            return None
        for message in present[1:]:  # the preferred message supersedes the old format
            self.skipped[message] = len(self.scans[message].times)
        scans = self.scans[present[0]]
        if scans.angle_min is not None and scans.angle_increment is not None:
            return scans.stream(scans.angle_min, scans.angle_increment)
        fov_name = f"{PARAM_PREFIX[which]}_fov"
        res_name = f"{PARAM_PREFIX[which]}_resolution"
        fov, resolution = self._param_degrees(fov_name), self._param_degrees(res_name)
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
    try:
        with _open_text(path) as text:
            for lineno, line in enumerate(text, start=1):
                reader.feed(lineno, line)
    except (OSError, EOFError) as exc:
        raise CarmenFormatError(f"{path}: cannot read log ({exc})") from exc
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
    )


def _laser(log: CarmenLog, which: str) -> LaserStream:
    stream = {"front": log.front, "rear": log.rear}.get(which)
    if stream is None or stream.num_scans == 0:
        raise ValueError(f"{log.path}: no {which} laser scans (stream must be 'front' or 'rear')")
    return stream


def odometry_at(log: CarmenLog, times: np.ndarray) -> np.ndarray:
    """ODOM poses interpolated at `times` (T,): float64 (T, 3), θ wrapped to (-π, π].

    x, y are linear in time, θ follows the shorter way round the circle. Echo lines (module
    doc) are left out; the rest are ordered by timestamp (intel's jitter by up to 0.9 s against
    the file order), lines with equal times resolve to the last in the file, and times outside
    the ODOM stream get its first / last pose. In a corrected log the result stays close to
    the corrected path; see `scan_odometry` for the wheel odometry.
    """
    keep = ~log.odometry.echo
    stamps, poses = log.odometry.times[keep], log.odometry.poses[keep]
    if len(stamps) == 0:
        raise ValueError(f"{log.path}: no ODOM lines to interpolate")
    order = np.argsort(stamps, kind="stable")
    stamps, poses = stamps[order], poses[order]
    last = np.append(stamps[1:] != stamps[:-1], True)  # of each run of equal times
    stamps, poses = stamps[last], poses[last]
    query = np.asarray(times, dtype=np.float64)
    if query.ndim != 1:
        raise ValueError(f"times must have shape (T,), got {query.shape}")
    i = np.clip(np.searchsorted(stamps, query, side="right") - 1, 0, len(stamps) - 1)
    j = np.minimum(i + 1, len(stamps) - 1)
    span = stamps[j] - stamps[i]
    w = np.divide(query - stamps[i], span, out=np.zeros_like(query), where=span > 0)
    w = np.clip(w, 0.0, 1.0)
    out = np.empty((len(query), 3))
    out[:, :2] = poses[i, :2] + w[:, None] * (poses[j, :2] - poses[i, :2])
    out[:, 2] = wrap_angle(poses[i, 2] + w * wrap_angle(poses[j, 2] - poses[i, 2]))
    return out


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose b in the frame of pose a."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, b[2] - a[2]])


def _compose(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * u[0] - s * u[1], a[1] + s * u[0] + c * u[1], a[2] + u[2]])


def scan_odometry(log: CarmenLog, stream: str = "front") -> np.ndarray:
    """Wheel odometry at each scan of a corrected log, float64 (N, 3), θ in (-π, π].

    A corrected log's ODOM lines restart from each scan's corrected robot pose (module doc),
    so the last ODOM line before scan k+1 is scan k's pose moved by the wheels' motion between
    the scans. Chaining those increments from the first scan's robot pose gives the odometry
    with its drift, in the frame `drive_trajectory` uses (odometry[0] == truth[0]). Scans with
    no ODOM line since the previous one add no motion.
    """
    laser = _laser(log, stream)
    real = np.flatnonzero(~log.odometry.echo)
    before = np.searchsorted(real, laser.odom_index, side="left")  # real ODOM lines before
    anchors = laser.odom_poses
    out = np.empty((laser.num_scans, 3))
    out[0] = anchors[0]
    for k in range(1, laser.num_scans):
        step = np.zeros(3)
        if before[k] > before[k - 1]:
            step = _relative(anchors[k - 1], log.odometry.poses[real[before[k] - 1]])
        out[k] = _compose(out[k - 1], step)
    out[:, 2] = wrap_angle(out[:, 2])
    return out
