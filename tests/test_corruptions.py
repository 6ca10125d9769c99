"""The real laser's corruptions (scanloc.sensor.corruptions): each corruption's statistics on
generated scans match its configured rate and run length, and measuring them back recovers
the configuration; bad configs name the field."""

from __future__ import annotations

import numpy as np
import pytest
from omegaconf import OmegaConf

from scanloc.scanlocnet.scan_stream import StreamSpec, simulate_epoch
from scanloc.sensor.corruptions import (
    LaserCorruptions,
    RunRate,
    corruptions_from_config,
    measure_corruptions,
    run_lengths,
    run_mask,
)
from scanloc.sensor.noise import noise_from_config
from scanloc.sensor.simulate import ScanSimulator, laser_spec_from_config
from small_world import SPEC

RANGE_MAX = 30.0
CONFIG = LaserCorruptions(
    no_return=RunRate(0.025, 2.0),
    short=RunRate(0.05, 6.0),
    long=RunRate(0.04, 3.0),
    short_ratio_low=0.2,
    short_ratio_high=0.8,
    long_excess_m=1.5,
    noise_scale_m=0.03,
    noise_dof=4.0,
)


@pytest.fixture(scope="module")
def rendered() -> np.ndarray:
    """Smooth scans between 2 and 8 m, as walls give (neighbouring beams read alike)."""
    phase = np.random.default_rng(1).uniform(0, 2 * np.pi, size=(4000, 1))
    return 5.0 + 3.0 * np.sin(phase + 0.02 * np.arange(180))


@pytest.mark.parametrize("runs", [RunRate(0.02, 1.0), RunRate(0.05, 4.0), RunRate(0.1, 10.0)])
def test_runs_cover_the_configured_share_in_runs_of_the_configured_length(runs) -> None:
    mask = run_mask(5000, 360, runs, np.random.default_rng(0))
    # overlapping runs merge: the share falls short by about rate² and runs get longer
    assert mask.mean() == pytest.approx(runs.rate, rel=0.12)
    assert run_lengths(mask).mean() == pytest.approx(runs.mean_run, rel=0.15)


def test_each_corruption_reads_as_configured(rendered) -> None:
    out = CONFIG.apply(rendered, np.random.default_rng(2))
    residual = out - rendered
    assert np.isinf(out).mean() == pytest.approx(0.025, rel=0.15)
    short = residual < -0.3
    assert short.mean() == pytest.approx(0.05, rel=0.15)
    ratio = (out / rendered)[short]
    assert ratio.min() >= 0.2 - 0.05 and np.quantile(ratio, 0.99) <= 0.8 + 0.05
    long = np.isfinite(out) & (residual > 0.3)
    assert long.mean() == pytest.approx(0.04 * np.exp(-0.3 / 1.5), rel=0.2)  # excess > 0.3 m
    inlier = np.abs(residual) <= 0.3
    assert np.median(np.abs(residual[inlier])) == pytest.approx(0.03 * 0.741, rel=0.1)


def test_measuring_recovers_the_configuration(rendered) -> None:
    out = CONFIG.apply(rendered, np.random.default_rng(3))
    fitted, measured = measure_corruptions(out, rendered, RANGE_MAX)
    assert fitted.no_return.rate == pytest.approx(0.025, rel=0.15)
    assert fitted.no_return.mean_run == pytest.approx(2.0, rel=0.15)
    assert fitted.short.rate == pytest.approx(0.05, rel=0.15)
    assert fitted.short.mean_run == pytest.approx(6.0, rel=0.2)
    assert fitted.noise_scale_m == pytest.approx(0.03, rel=0.1)
    assert fitted.noise_dof == pytest.approx(4.0, rel=0.3)
    assert measured["scans"] == 4000 and 0 < measured["within_5cm"] < 1


def test_no_corruption_changes_nothing(rendered) -> None:
    assert np.array_equal(LaserCorruptions().apply(rendered, np.random.default_rng(0)), rendered)
    assert corruptions_from_config(None, "x") == LaserCorruptions()


def test_the_same_seed_gives_the_same_scans(rendered) -> None:
    a = CONFIG.apply(rendered[:50], np.random.default_rng(9))
    b = CONFIG.apply(rendered[:50], np.random.default_rng(9))
    assert np.array_equal(a, b)


def test_bad_configs_name_the_source_and_field() -> None:
    with pytest.raises(ValueError, match=r"c\.yaml: unknown field 'shrt'"):
        corruptions_from_config({"shrt": {"rate": 0.1}}, "c.yaml")
    with pytest.raises(ValueError, match=r"c\.yaml: corruptions field 'short'"):
        corruptions_from_config({"short": {"rate": 1.5, "mean_run": 2}}, "c.yaml")
    with pytest.raises(ValueError, match=r"c\.yaml: field 'long': expected"):
        corruptions_from_config({"long": 0.1}, "c.yaml")


def test_the_training_stream_applies_the_corruptions(room) -> None:
    """The learned localizer's fresh scans carry the configured no returns, at the same poses."""
    sensor = OmegaConf.to_container(OmegaConf.load("conf/sensor/urg04lx.yaml"))
    noise = OmegaConf.to_container(OmegaConf.load("conf/noise/ug01.yaml"))
    simulator = ScanSimulator(room, laser_spec_from_config(sensor), noise_from_config(noise))
    corrupted = {"no_return": {"rate": 0.1, "mean_run": 3.0}, "noise_scale_m": 0.01}
    clean = StreamSpec("unused", sensor, noise, 0.15, 300, 4)
    dirty = StreamSpec("unused", sensor, noise, 0.15, 300, 4, corrupted)
    plain, poses = simulate_epoch(clean, 0, room, simulator)
    ranges, poses_again = simulate_epoch(dirty, 0, room, simulator)
    assert np.array_equal(poses, poses_again)  # the same poses, only the readings differ
    missing = (ranges == SPEC.no_return_value) & (plain != SPEC.no_return_value)
    assert missing.mean() == pytest.approx(0.1, rel=0.15)
