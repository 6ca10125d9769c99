"""The CARMEN log reader on hand-made lines (plain and gzipped), its error messages, beam
angles, "no return" cleaning, odometry interpolation, and the two Radish logs in ../shared."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pytest

from scanloc.real.carmen import (
    CarmenFormatError,
    CarmenLog,
    angle_units,
    carmen_beam_angles,
    read_carmen_log,
)
from scanloc.real.carmen_laser import clean_ranges, laser_spec
from scanloc.real.carmen_odometry import odometry_at, scan_odometry

CARMEN_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen"


def flaser(ranges: list[float], pose: tuple, t: float, tag: str = "FLASER", odom=None) -> str:
    """An old-format laser line; the logger timestamp is t, the ipc one t - 0.5."""
    odom = pose if odom is None else odom
    fields = [tag, len(ranges), *ranges, *pose, *odom, t - 0.5, "host", t]
    return " ".join(str(f) for f in fields)


def odom(x: float, y: float, theta: float, t: float) -> str:
    return f"ODOM {x} {y} {theta} 0.1 0.2 0 {t - 0.5} host {t}"


def robotlaser(ranges: list[float], laser: tuple, robot: tuple, t: float) -> str:
    head = ["ROBOTLASER1", 0, -1.5, 3.0, 0.5, 20.0, 0.01, 0, len(ranges), *ranges]
    tail = [2, 7.0, 8.0, *laser, *robot, 0.3, 0.1, 0.5, 0.2, 0.0, t - 0.5, "host", t]
    return " ".join(str(f) for f in head + tail)


def write_log(path: Path, lines: list[str]) -> Path:
    text = "\n".join(lines) + "\n"
    if path.suffix == ".gz":
        path.write_bytes(gzip.compress(text.encode()))
    else:
        path.write_text(text)
    return path


GOOD_LOG = [
    "# message formats defined: PARAM SYNC ODOM FLASER RLASER",
    "PARAM robot_frontlaser_offset 0.0 10.0 host 10.0",
    "PARAM laser_front_laser_type LMS nohost 0",  # intel's short PARAM lines
    "",
    odom(0.0, 0.0, 0.0, 1.0),
    flaser([1.0, 2.0, 81.91], (0.1, 0.2, 0.3), 1.5, odom=(0.0, 0.1, 0.2)),
    "NEFF 15",
    odom(0.5, 0.0, 0.1, 2.0),
    flaser([1.5, 2.5, 3.5], (0.6, 0.2, 0.4), 2.5),
    flaser([4.0, 5.0, 6.0, 7.0], (0.0, 0.0, math.pi), 2.6, tag="RLASER"),
    "SYNC 3 host 3",
    "NEFF 14.8",
    "TRUEPOS 0 0 0 0 0 0 3 host 3",
    "  # an indented comment",
    odom(1.0, 0.0, 0.2, 3.0),
]


@pytest.mark.parametrize("name", ["plain.log", "packed.log.gz"])
def test_reads_every_record_type(tmp_path: Path, name: str) -> None:
    log = read_carmen_log(write_log(tmp_path / name, GOOD_LOG))
    assert log.path == tmp_path / name
    front, rear = log.front, log.rear
    assert front is not None and rear is not None
    assert front.message == "FLASER" and rear.message == "RLASER"
    assert front.ranges.dtype == np.float32
    np.testing.assert_array_equal(front.ranges, np.float32([[1.0, 2.0, 81.91], [1.5, 2.5, 3.5]]))
    np.testing.assert_array_equal(front.times, [1.5, 2.5])  # logger, not ipc, timestamps
    np.testing.assert_array_equal(front.laser_poses, [[0.1, 0.2, 0.3], [0.6, 0.2, 0.4]])
    np.testing.assert_array_equal(front.odom_poses, [[0.0, 0.1, 0.2], [0.6, 0.2, 0.4]])
    np.testing.assert_array_equal(front.odom_index, [1, 2])  # ODOM lines before each scan
    assert rear.ranges.shape == (1, 4) and rear.times.tolist() == [2.6]
    np.testing.assert_array_equal(log.odometry.times, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(log.odometry.poses[:, 2], [0.0, 0.1, 0.2])
    assert not log.odometry.echo.any()
    assert log.params == {"robot_frontlaser_offset": "0.0", "laser_front_laser_type": "LMS"}
    assert log.skipped == {"NEFF": 2, "SYNC": 1, "TRUEPOS": 1}


def test_times_fall_back_to_ipc_and_params_keep_spaces(tmp_path: Path) -> None:
    lines = [
        "FLASER 2 1.0 2.0 0 0 0 0 0 0 12.5 host",  # no logger timestamp (old logs)
        "ODOM 0 0 0 0 0 0 13.5 host",
        "PARAM robot_name my robot 1.0 host 1.0",
        "PARAM robot_name_2 x 1.0 host 1.0",
    ]
    log = read_carmen_log(write_log(tmp_path / "old.log", lines))
    assert log.front is not None and log.front.times.tolist() == [12.5]
    assert log.odometry.times.tolist() == [13.5]
    assert log.params == {"robot_name": "my robot", "robot_name_2": "x"}
    assert log.rear is None


def test_robotlaser_brings_its_own_geometry(tmp_path: Path) -> None:
    lines = [
        flaser([1.0, 2.0], (0, 0, 0), 0.5),
        robotlaser([1.0, 2.0, 3.0, 4.0], (1.1, 2.1, 0.1), (1.0, 2.0, 0.1), 1.0),
        robotlaser([1.5, 2.5, 3.5, 4.5], (1.2, 2.1, 0.1), (1.1, 2.0, 0.1), 2.0),
    ]
    log = read_carmen_log(write_log(tmp_path / "robot.log", lines))
    front = log.front
    assert front is not None and front.message == "ROBOTLASER1"
    assert (front.angle_min, front.angle_increment, front.max_range) == (-1.5, 0.5, 20.0)
    np.testing.assert_allclose(front.beam_angles(), [-1.5, -1.0, -0.5, 0.0])
    np.testing.assert_array_equal(front.laser_poses[:, 0], [1.1, 1.2])
    np.testing.assert_array_equal(front.odom_poses[:, 0], [1.0, 1.1])  # the robot pose
    np.testing.assert_array_equal(front.times, [1.0, 2.0])
    assert log.skipped == {"FLASER": 1}  # superseded by the richer message


GOOD = flaser([1.0, 2.0, 3.0], (0, 0, 0), 1.0)
MALFORMED = [
    (
        flaser([1.0, 2.0, 3.0], (0, 0, "abc"), 1.0),
        r"bad\.log:3: FLASER field 'theta': expected a number, got 'abc'",
    ),
    ("FLASER -3 0 0 0 0 0 0 1 host 1", r"bad\.log:3: FLASER field 'n': expected a count"),
    ("FLASER 2.5 1 2 0 0 0 0 0 0 1 host 1", r"bad\.log:3: FLASER field 'n': expected a count"),
    ("FLASER 3 1 2 x 0 0 0 0 0 0 1 host 1", r"bad\.log:3: FLASER field 'r3': expected a number"),
    ("FLASER 3 1 2 3 0 0 0 0 0 0", r"bad\.log:3: FLASER field 'ipc_timestamp': missing"),
    ("FLASER 3 1 2", r"bad\.log:3: FLASER field 'r3': missing"),
    (  # two readings short: the pose slides into them and the host name into odom_theta
        "FLASER 5 1 2 3 0 0 0 0 0 0 1 host 1",
        r"bad\.log:3: FLASER field 'odom_theta': expected a number, got 'host'",
    ),
    (
        GOOD + " 7 8",
        r"bad\.log:3: FLASER: 2 field\(s\) after field 'logger_timestamp'.*'7'",
    ),
    (
        flaser([1.0, 2.0, 3.0, 4.0], (0, 0, 0), 2.0),
        r"bad\.log:3: FLASER field 'n': expected 3 readings like the stream's first scan "
        r"\(.*bad\.log:2\), got '4'",
    ),
    ("ODOM 0 0 0 fast 0 0 1 host 1", r"bad\.log:3: ODOM field 'tv': expected a number"),
    ("ODOM 0 0 0 0 0", r"bad\.log:3: ODOM field 'accel': missing"),
    ("ODOM 0 0 0 0 0 0 1 host one", r"bad\.log:3: ODOM field 'logger_timestamp'"),
    ("PARAM robot_width", r"bad\.log:3: PARAM field 'value': missing"),
    (
        robotlaser([1.0, 2.0], (0, 0, 0), (0, 0, 0), 1.0).replace(" 2 7.0 8.0 ", " -2 7.0 8.0 "),
        r"bad\.log:3: ROBOTLASER1 field 'num_remissions': expected a count",
    ),
    (
        robotlaser([1.0, 2.0], (0, 0, 0), (0, 0, 0), 1.0).replace(" 1.0 2.0 ", " 1.0 nan? "),
        r"bad\.log:3: ROBOTLASER1 field 'range2': expected a number, got 'nan\?'",
    ),
]


@pytest.mark.parametrize(("line", "message"), MALFORMED)
def test_malformed_lines_name_file_line_and_field(tmp_path: Path, line: str, message: str) -> None:
    path = write_log(tmp_path / "bad.log", ["# a comment counts as a line", GOOD, line])
    with pytest.raises(CarmenFormatError, match=message):
        read_carmen_log(path)


def test_format_errors_are_value_errors(tmp_path: Path) -> None:
    path = write_log(tmp_path / "bad.log.gz", [GOOD, "ODOM 0 0 zero 0 0 0 1 host 1"])
    with pytest.raises(ValueError, match=r"bad\.log\.gz:2: ODOM field 'theta'"):
        read_carmen_log(path)


def test_robotlaser_geometry_must_not_change(tmp_path: Path) -> None:
    first = robotlaser([1.0, 2.0], (0, 0, 0), (0, 0, 0), 1.0)
    lines = [first, first.replace(" 0.5 20.0 ", " 0.25 20.0 ")]
    with pytest.raises(CarmenFormatError, match=r":2: ROBOTLASER1 field 'angular_resolution'"):
        read_carmen_log(write_log(tmp_path / "bad.log", lines))


@pytest.mark.parametrize(
    ("beams", "increment_deg", "last_deg"),
    [(180, 1.0, 89.0), (181, 1.0, 90.0), (360, 0.5, 89.5), (361, 0.5, 90.0)],
)
def test_beam_angles_from_the_beam_count(beams: int, increment_deg: float, last_deg: float) -> None:
    angle_min, increment = carmen_beam_angles(beams)
    assert angle_min == pytest.approx(math.radians(-90.0), abs=1e-15)
    assert increment == pytest.approx(math.radians(increment_deg), abs=1e-15)
    assert angle_min + (beams - 1) * increment == pytest.approx(math.radians(last_deg))


def test_beam_angles_from_params() -> None:
    angle_min, increment = carmen_beam_angles(401, fov_deg=100.0, resolution_deg=0.25)
    assert (math.degrees(angle_min), math.degrees(increment)) == pytest.approx((-50.0, 0.25))
    assert carmen_beam_angles(360, resolution_deg=0.5) == pytest.approx(carmen_beam_angles(360))
    assert math.degrees(carmen_beam_angles(90, fov_deg=90.0)[1]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match=r"181 beams at 2.0° do not fit in a 180.0°"):
        carmen_beam_angles(181, resolution_deg=2.0)
    with pytest.raises(ValueError, match="at least one beam"):
        carmen_beam_angles(0)


def test_log_params_set_the_beam_angles(tmp_path: Path) -> None:
    lines = [
        "PARAM laser_front_laser_fov 100 0 host 0",
        "PARAM laser_front_laser_resolution 0.5 0 host 0",
        "PARAM laser_rear_laser_resolution 1.0 0 host 0",
        flaser([1.0] * 203, (0, 0, 0), 1.0),  # 101° of beams in a 100° field of view
        flaser([1.0] * 101, (0, 0, 0), 1.0, tag="RLASER"),
    ]
    with pytest.raises(CarmenFormatError, match=r"a\.log: FLASER beam angles from PARAM.*203"):
        read_carmen_log(write_log(tmp_path / "a.log", lines))
    lines[3] = flaser([1.0] * 201, (0, 0, 0), 1.0)
    log = read_carmen_log(write_log(tmp_path / "b.log", lines))
    assert log.front is not None and log.rear is not None
    assert np.degrees(log.front.beam_angles()[[0, -1]]) == pytest.approx([-50.0, 50.0])
    assert np.degrees(log.rear.beam_angles()[[0, 1, -1]]) == pytest.approx([-90.0, -89.0, 10.0])
    lines[0] = "PARAM laser_front_laser_fov wide 0 host 0"
    with pytest.raises(CarmenFormatError, match=r"c\.log:1: PARAM 'laser_front_laser_fov'"):
        read_carmen_log(write_log(tmp_path / "c.log", lines))


def test_clean_ranges_fills_no_return_above_max_range() -> None:
    readings = np.array([0.5, 5.0, 5.6, 81.91, 0.0, -1.0, np.nan, np.inf])
    cleaned = clean_ranges(readings, max_range=5.6)
    assert cleaned.dtype == np.float32
    np.testing.assert_array_equal(cleaned, np.float32([0.5, 5.0] + [7.0] * 6))
    np.testing.assert_array_equal(clean_ranges(readings, 50.0, 60.0)[2:4], np.float32([5.6, 60]))
    assert clean_ranges(readings, 40.0)[3] == np.float32(50.0)  # 1.25 x max_range
    with pytest.raises(ValueError, match="must exceed max_range"):
        clean_ranges(readings, 5.6, no_return_value=5.0)


def test_laser_spec_of_a_stream(tmp_path: Path) -> None:
    lines = [flaser([1.0] * 181, (0, 0, 0), 1.0 + 0.2 * k) for k in range(5)]
    log = read_carmen_log(write_log(tmp_path / "spec.log", lines))
    assert log.front is not None
    spec = laser_spec(log.front, max_range=30.0)
    assert (spec.num_beams, spec.range_min, spec.range_max) == (181, 0.0, 30.0)
    assert (spec.no_return_value, spec.rate_hz) == pytest.approx((37.5, 5.0))
    np.testing.assert_allclose(spec.beam_angles(), log.front.beam_angles(), atol=1e-12)
    assert laser_spec(log.front, 30.0, no_return_value=31.0).no_return_value == 31.0


def odometry_log(tmp_path: Path, lines: list[str]) -> CarmenLog:
    return read_carmen_log(write_log(tmp_path / "odom.log", lines))


def test_odometry_at_interpolates_position_and_heading(tmp_path: Path) -> None:
    log = odometry_log(
        tmp_path,
        [odom(0.0, 0.0, 3.0, 10.0), odom(2.0, -4.0, -3.0, 11.0), odom(2.0, -4.0, -1.0, 13.0)],
    )
    times = np.array([9.0, 10.0, 10.25, 10.5, 11.0, 12.0, 14.0])
    poses = odometry_at(log, times)
    np.testing.assert_allclose(poses[:, 0], [0.0, 0.0, 0.5, 1.0, 2.0, 2.0, 2.0])
    np.testing.assert_allclose(poses[:, 1], [0.0, 0.0, -1.0, -2.0, -4.0, -4.0, -4.0])
    # 3.0 -> -3.0 rad turns 0.28 rad through ±π, not 6 rad the other way
    short = 2.0 * math.pi - 6.0
    expected = np.array([3.0, 3.0, 3.0 + short / 4, math.pi, -3.0, -2.0, -1.0])
    assert np.abs(np.angle(np.exp(1j * (poses[:, 2] - expected)))).max() < 1e-12
    assert np.all((poses[:, 2] > -math.pi) & (poses[:, 2] <= math.pi))


def test_odometry_at_skips_echoes_and_orders_by_time(tmp_path: Path) -> None:
    lines = [
        odom(0.0, 0.0, 0.0, 1.0),
        odom(3.0, 0.0, 0.0, 3.0),
        odom(2.0, 0.0, 0.0, 2.0),  # logged late: placed by its time
        flaser([1.0, 1.0], (7.0, 7.0, 0.5), 2.0),
        "ODOM 7.0 7.0 0.5 0 0 0 0 host 0",  # the corrected pose repeated, time 0: an echo
        odom(2.5, 0.0, 0.0, 2.0),  # same time as an earlier line: the later one wins
    ]
    log = odometry_log(tmp_path, lines)
    assert log.odometry.echo.tolist() == [False, False, False, True, False]
    poses = odometry_at(log, np.array([0.0, 1.5, 2.0, 2.5]))
    np.testing.assert_allclose(poses[:, 0], [0.0, 1.25, 2.5, 2.75])
    with pytest.raises(ValueError, match="no ODOM lines"):
        odometry_at(odometry_log(tmp_path, [GOOD]), np.array([1.0]))


def test_scan_odometry_chains_the_increments_of_a_corrected_log(tmp_path: Path) -> None:
    c, s = math.cos(0.1), math.sin(0.1)
    lines = [
        flaser([1.0, 1.0], (0.0, 0.0, 0.0), 1.0),
        "ODOM 0.0 0.0 0.0 0 0 0 0 host 0",  # echo
        odom(0.25, 0.0, 0.0, 1.5),
        odom(0.5, 0.0, 0.0, 2.0),  # the wheels: 0.5 m ahead
        flaser([1.0, 1.0], (0.4, 0.1, 0.1), 2.0),  # the scan matcher: here instead
        "ODOM 0.4 0.1 0.1 0 0 0 1e-42 host 1e-42",  # echo with a garbage time
        odom(0.4 + c, 0.1 + s, 0.1 + 0.2, 3.0),  # 1 m ahead of the correction, turned 0.2
        flaser([1.0, 1.0], (1.3, 0.3, 0.2), 3.0),
        flaser([1.0, 1.0], (1.3, 0.3, 0.2), 3.1),  # no ODOM in between: no motion
    ]
    log = odometry_log(tmp_path, lines)
    expected = [[0, 0, 0], [0.5, 0, 0], [1.5, 0, 0.2], [1.5, 0, 0.2]]
    np.testing.assert_allclose(scan_odometry(log), expected, atol=1e-12)
    with pytest.raises(ValueError, match="no rear laser scans"):
        scan_odometry(log, "rear")


def real_log(name: str) -> CarmenLog:
    path = CARMEN_DATA / name
    if not path.is_file():
        pytest.skip(f"CARMEN log {name} not available at {CARMEN_DATA}")
    return read_carmen_log(path)


@pytest.fixture(scope="module")
def intel() -> CarmenLog:
    return real_log("intel-corrected.log.gz")


@pytest.fixture(scope="module")
def freiburg() -> CarmenLog:
    return real_log("freiburg-079-corrected.log.gz")


def test_intel_log(intel: CarmenLog) -> None:
    front = intel.front
    assert front is not None and intel.rear is None
    assert (front.message, front.ranges.shape, len(intel.odometry.times)) == (
        "FLASER",
        (910, 180),
        14541,
    )
    assert intel.skipped == {"NEFF": 910} and len(intel.params) == 2
    # 180 beams, no geometry PARAMs: 1° steps from -90° to +89°
    assert np.degrees(front.beam_angles()[[0, 1, -1]]) == pytest.approx([-90.0, -89.0, 89.0])
    # timestamps grow, but four scans are stamped up to 0.86 s before the one before them
    steps = np.diff(front.times)
    assert front.times[-1] > front.times[0] and (steps <= 0).sum() == 4 and steps.min() > -1.0
    assert float(front.ranges.max()) == pytest.approx(81.83)  # the max-range marker
    assert float(np.sort(np.unique(front.ranges))[-2]) < 26.0


def test_freiburg_log(freiburg: CarmenLog) -> None:
    front = freiburg.front
    assert front is not None and freiburg.rear is None
    assert (front.ranges.shape, len(freiburg.odometry.times), len(freiburg.params)) == (
        (4791, 360),
        9725,
        187,
    )
    assert freiburg.skipped == {"NEFF": 4791}
    assert freiburg.params["laser_front_laser_resolution"] == "0.5"
    assert math.degrees(front.angle_increment) == pytest.approx(0.5)
    assert math.degrees(front.angle_min) == pytest.approx(-90.0)
    assert np.all(np.diff(front.times) > 0)
    real = ~freiburg.odometry.echo
    assert np.all(np.diff(freiburg.odometry.times[real]) > 0)
    assert float(front.ranges.max()) == pytest.approx(81.91)


@pytest.mark.parametrize("name", ["intel", "freiburg"])
def test_corrected_logs_carry_corrected_poses_only(
    name: str, request: pytest.FixtureRequest
) -> None:
    log: CarmenLog = request.getfixturevalue(name)
    front = log.front
    assert front is not None
    # the laser line's odom fields repeat its corrected pose, and so does one ODOM line each
    np.testing.assert_array_equal(front.laser_poses, front.odom_poses)
    assert log.odometry.echo.sum() == front.num_scans
    # ODOM follows the corrected path closely; the chained increments drift far off it
    near = np.hypot(*(odometry_at(log, front.times)[:, :2] - front.laser_poses[:, :2]).T)
    assert np.median(near) < 0.1 and near.max() < 1.0
    wheels = scan_odometry(log)
    np.testing.assert_allclose(wheels[0], front.laser_poses[0], atol=1e-12)
    drift = np.hypot(*(wheels[:, :2] - front.laser_poses[:, :2]).T)
    assert drift[-1] > 10.0
    step_true = np.hypot(*np.diff(front.laser_poses[:, :2], axis=0).T)
    step_wheels = np.hypot(*np.diff(wheels[:, :2], axis=0).T)
    assert np.median(np.abs(step_wheels - step_true)) < 0.05


@pytest.mark.parametrize(
    ("beams", "fov", "resolution", "units"),
    [
        (361, None, None, ("degrees", "degrees")),
        (361, 180.0, 0.5, ("degrees", "degrees")),
        (361, 3.14159, None, ("radians", "degrees")),  # a fov alone under 2 pi: radians
        (361, 3.14159, 0.5, ("radians", "degrees")),
        (361, None, 0.00872665, ("degrees", "radians")),  # 0.5° in radians, default 180° fov
        (361, 3.14159, 0.00872665, ("radians", "radians")),
        (181, 3.14159, 1.0, ("radians", "degrees")),
        (541, 270.0, 0.5, ("degrees", "degrees")),
        (541, 4.71239, 0.00872665, ("radians", "radians")),  # a 270° Hokuyo, all in radians
    ],
)
def test_angle_params_in_degrees_or_radians(
    beams: int, fov: float | None, resolution: float | None, units: tuple[str, str]
) -> None:
    assert angle_units(beams, fov, resolution) == units


def test_a_log_with_its_fov_in_radians_reads_and_records_it(tmp_path: Path) -> None:
    lines = [
        "PARAM laser_front_laser_fov 3.14159 0 host 0",
        flaser([1.0] * 361, (0, 0, 0), 1.0),
    ]
    log = read_carmen_log(write_log(tmp_path / "radians.log", lines))
    assert log.front is not None
    assert np.degrees(log.front.beam_angles()[[0, 1, -1]]) == pytest.approx(
        [-90.0, -89.5, 90.0], abs=1e-3
    )
    assert log.angle_params == {
        "laser_front_laser_fov": {
            "value": 3.14159,
            "unit": "radians",
            "degrees": pytest.approx(179.9998, abs=1e-3),
        }
    }


def test_carmen_07_numbered_laser_params(tmp_path: Path) -> None:
    lines = [
        "PARAM laser_laser1_fov 100 0 host 0",
        "PARAM laser_laser1_resolution 0.25 0 host 0",
        flaser([1.0] * 401, (0, 0, 0), 1.0),
    ]
    log = read_carmen_log(write_log(tmp_path / "numbered.log", lines))
    assert log.front is not None
    assert np.degrees(log.front.beam_angles()[[0, 1, -1]]) == pytest.approx([-50.0, -49.75, 50.0])
    assert {p["unit"] for p in log.angle_params.values()} == {"degrees"}
    assert set(log.angle_params) == {"laser_laser1_fov", "laser_laser1_resolution"}
