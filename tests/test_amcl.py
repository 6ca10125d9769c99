"""The amcl particle filter: KLD bound, clusters, convergence, configs and bad input."""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scanloc.estimates import TABLE_COLUMNS
from scanloc.localize.catalog import raw_config
from scanloc.localize.clustering import cluster_estimate
from scanloc.localize.kld_resampling import kld_limit
from scanloc.localize.mcl.config import MclConfig, build_filter, run_mcl
from scanloc.localize.mcl.filter import FilterParams, ParticleFilter
from scanloc.localize.mcl.sensor_models import SENSOR_MODELS
from scanloc.pose import compose, inverse
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import Trajectory
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import UNKNOWN, OccupancyGrid
from small_world import SPEC, small_map, ug01_scans

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf" / "localizer"


def ros(**params: object) -> MclConfig:
    """The filter's parts from ROS-named parameters (ROS 1's defaults for the others)."""
    return MclConfig.from_ros(params, where="test")


def shipped(name: str) -> MclConfig:
    """The filter's parts of conf/localizer/<name>.yaml (its `filter`, `motion`, `sensor`)."""
    return MclConfig.from_sections(raw_config(name, CONF), f"conf/localizer/{name}.yaml")


def amcl_filter(grid: OccupancyGrid, seed: int = 0, **params: object) -> ParticleFilter:
    """amcl (the particle filter with amcl's parts) from ROS-named parameters."""
    return build_filter(grid, SPEC, ros(**params), seed=seed)


@pytest.fixture(scope="module")
def drive() -> tuple[OccupancyGrid, Trajectory, np.ndarray]:
    grid = small_map()
    traj = drive_trajectory(grid, 300, seed=2, clearance=0.25)
    return grid, traj, ug01_scans(grid, traj.truth, seed=5)


def errors(table: pd.DataFrame, traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    pos = np.hypot(table.x - traj.truth[:, 0], table.y - traj.truth[:, 1]).to_numpy()
    head = np.abs(np.angle(np.exp(1j * (table.theta.to_numpy() - traj.truth[:, 2]))))
    return pos, np.degrees(head)


def test_kld_limit_is_fox_bound_clamped() -> None:
    err, z = 0.01, 0.99
    for k in (2, 3, 10, 57, 200, 1000):
        b = 2.0 / (9.0 * (k - 1))
        n = math.ceil((k - 1) / (2 * err) * (1 - b + math.sqrt(b) * z) ** 3)
        assert kld_limit(k, 1, 10**9, err, z) == n
        assert kld_limit(k, 100, 5000, err, z) == min(max(n, 100), 5000)
    assert kld_limit(1, 100, 5000, err, z) == 5000  # amcl: a single bin asks for max_particles
    assert kld_limit(2, 100, 5000, err, z) == 100


def test_cluster_mean_of_headings_straddling_pi() -> None:
    rng = np.random.default_rng(0)
    theta = np.angle(np.exp(1j * (math.pi + rng.normal(0.0, 0.05, 400))))
    poses = np.column_stack([rng.normal(3.0, 0.05, 400), rng.normal(2.0, 0.05, 400), theta])
    mean, cov, labels = cluster_estimate(poses, np.full(400, 1 / 400))
    assert len(set(labels)) == 1  # the heading bins wrap: one cluster, not two
    assert abs(np.angle(np.exp(1j * (mean[2] - math.pi)))) < 0.01  # an arithmetic mean: ~0
    assert cov[2, 2] == pytest.approx(0.05**2, rel=0.2)
    assert cov[0, 0] == pytest.approx(0.05**2, rel=0.2)
    np.testing.assert_allclose(cov, cov.T)


def test_heaviest_cluster_wins() -> None:
    rng = np.random.default_rng(1)
    a = np.column_stack([rng.normal(1, 0.05, 300), rng.normal(1, 0.05, 300), np.zeros(300)])
    b = np.column_stack([rng.normal(5, 0.05, 100), rng.normal(4, 0.05, 100), np.ones(100)])
    poses = np.vstack([a, b])
    w = np.concatenate([np.full(300, 0.5 / 300), np.full(100, 0.5 / 100 + 1e-6)])
    mean, _, labels = cluster_estimate(poses, w / w.sum())
    assert len(set(labels)) == 2
    np.testing.assert_allclose(mean, [5, 4, 1], atol=0.03)


def test_resampling_keeps_the_kld_count() -> None:
    grid = small_map()
    params = FilterParams(resample_interval=1, update_min_d=0.0, update_min_a=0.0)
    amcl = amcl_filter(grid, resample_interval=1, update_min_d=0.0, update_min_a=0.0)
    truth = np.array([[2.5, 2.0, 0.3]])
    amcl.initialize_pose(truth[0], np.diag([0.2**2, 0.2**2, 0.1**2]))  # a few dozen bins
    scan = ug01_scans(grid, truth, seed=1)[0]
    amcl.update(np.zeros(3), scan)
    est = amcl.update(np.array([0.01, 0.0, 0.0]), scan)  # moved: update and resample
    assert est.updated
    assert len(amcl.poses) == est.n_particles
    assert np.all(np.abs(amcl.poses[:, 2]) <= math.pi)
    # KLD sampling draws until the count exceeds the bound for the bins occupied so far: the
    # set it keeps is one particle more than the bound of its own occupied bins (amcl's
    # 0.5 m x 0.5 m x 10° histogram, counted here independently).
    bins = np.column_stack(
        [
            np.floor(amcl.poses[:, 0] / 0.5),
            np.floor(amcl.poses[:, 1] / 0.5),
            np.floor((amcl.poses[:, 2] + math.pi) / math.radians(10.0)) % 36,
        ]
    )
    k = len(np.unique(bins, axis=0))
    bound = kld_limit(k, params.min_particles, params.max_particles, params.kld_err, params.kld_z)
    assert 1 < k and bound < params.max_particles, k  # the bound, not the cap, ended the draw
    assert est.n_particles == bound + 1


def test_tracking_converges(drive: tuple[OccupancyGrid, Trajectory, np.ndarray]) -> None:
    grid, traj, ranges = drive
    table = run_mcl(grid, SPEC, traj, ranges, ros(), mode="tracking", seed=0).table
    assert list(table.columns) == list(TABLE_COLUMNS)
    assert len(table) == len(traj.times)
    pos, head = errors(table, traj)
    assert pos[100:].mean() < 0.06
    assert head[100:].mean() < 2.0
    # the carried-forward estimate between updates, not a stale one: errors stay small everywhere
    assert pos.max() < 0.5
    assert (table.n_particles >= FilterParams().min_particles).all()  # KLD never goes below it
    rerun = run_mcl(grid, SPEC, traj, ranges, ros(), mode="tracking", seed=0).table
    pd.testing.assert_frame_equal(table, rerun)


def test_global_localization_converges(drive: tuple[OccupancyGrid, Trajectory, np.ndarray]) -> None:
    grid, traj, ranges = drive
    table = run_mcl(grid, SPEC, traj, ranges, ros(), mode="global", seed=0).table
    pos, head = errors(table, traj)
    assert pos[0] > 0.5  # it did start lost
    assert pos[150:].max() < 0.5
    assert pos[200:].mean() < 0.08
    assert head[200:].mean() < 3.0


def test_estimate_is_carried_by_odometry_between_updates() -> None:
    grid = small_map()
    amcl = amcl_filter(grid, seed=0)
    truth = np.array([[2.5, 2.0, 0.3], [2.55, 2.0, 0.3]])
    scans = ug01_scans(grid, truth, seed=2)
    amcl.initialize_pose(truth[0], np.diag([1e-4, 1e-4, 1e-4]))
    first = amcl.update(np.array([1.0, 1.0, 0.5]), scans[0])  # odometry frame != map frame
    second = amcl.update(
        np.array([1.0 + 0.05 * math.cos(0.5), 1.0 + 0.05 * math.sin(0.5), 0.5]), scans[1]
    )
    assert first.updated and not second.updated
    moved = compose(first.mean, np.array([0.05, 0.0, 0.0]))
    np.testing.assert_allclose(second.mean, moved, atol=1e-12)
    np.testing.assert_allclose(compose(inverse(moved), moved), np.zeros(3), atol=1e-12)


# Keys each shipped config writes, of each of its sections: what the test below must reach.
WRITTEN = {
    "amcl": {"initial_cov_xx"},
    "amcl_nav2": {"resample_interval", "odom_model_type", "laser_max_beams", "laser_z_hit"},
    "amcl_ros_exact": {"initial_cov_aa", "map_half_cell_offset"},
    "amcl_best": {"update_min_d", "laser_model_type", "odom_model_type"},
}


@pytest.mark.parametrize("name", sorted(WRITTEN))
def test_shipped_config_sets_every_parameter_it_names(name: str) -> None:
    """Every filter parameter of a shipped config reaches the part that owns it, with the
    type of its default (the `meta` section is the catalog's, not the filter's)."""
    cfg = raw_config(name, CONF)
    config = shipped(name)
    parts = {
        "filter": (config.filter,),
        "motion": (config.odometry,),
        "sensor": (config.laser, config.sensor, config),
    }
    model_keys = {f.name for model in SENSOR_MODELS.values() for f in fields(model.Params)}
    reached = set()
    for section, section_parts in parts.items():
        for key, value in (cfg.get(section) or {}).items():
            owners = [part for part in section_parts if hasattr(part, key)]
            if not owners:  # a key of a sensor model this config does not choose
                assert section == "sensor" and key in model_keys, (section, key)
                continue
            for part in owners:
                assert getattr(part, key) == value, key
                assert type(getattr(part, key)) is type(getattr(type(part)(), key)), key
            reached.add(key)
    assert WRITTEN[name] <= reached
    assert set(cfg) <= {"meta", "filter", "motion", "sensor"}, set(cfg)


def test_configs_load_and_unknown_keys_are_rejected() -> None:
    # The ROS 1 config differs from the built-in (ROS 1) defaults only where it says so.
    amcl = shipped("amcl")
    assert amcl.with_filter(initial_cov_xx=0.25, initial_cov_yy=0.25) != ros()
    assert (
        amcl.with_filter(
            initial_cov_xx=0.25, initial_cov_yy=0.25, initial_cov_aa=(math.pi / 12) ** 2
        )
        == ros()
    )
    # The `meta` section is the catalog's, not the filter's; the start (`mode`) and the seed
    # are the `filter` section's; an int is accepted for a float parameter, stored as a float.
    meta = {"name": "x", "kind": "particle_filter", "group": "global"}
    loaded = MclConfig.from_sections(
        {
            "meta": meta,
            "filter": {"mode": "global", "seed": 3, "update_min_d": 1},
            "sensor": {"laser_max_beams": 40},
        },
        "conf/localizer/x.yaml",
    )
    assert loaded.filter == FilterParams(mode="global", seed=3, update_min_d=1.0)
    assert loaded.laser.laser_max_beams == 40
    assert isinstance(loaded.filter.update_min_d, float)
    # A flat ROS mapping holds ROS parameters only: a meta key there is an unknown one.
    with pytest.raises(ValueError, match=r"x\.yaml: unknown parameter 'name'"):
        MclConfig.from_ros({"name": "x", "update_min_d": 1.0}, where="x.yaml")
    # Errors name the config file, the section and the key.
    where = "conf/localizer/amcl.yaml"
    with pytest.raises(ValueError, match=r"x\.yaml: section 'sensor': unknown key 'max_beams'"):
        MclConfig.from_sections({"sensor": {"max_beams": 60}}, "conf/localizer/x.yaml")
    with pytest.raises(ValueError, match=r"x\.yaml: section 'filter': unknown key 'max_beams'"):
        MclConfig.from_sections({"filter": {"max_beams": 60}}, "conf/localizer/x.yaml")
    with pytest.raises(ValueError, match=r"x\.yaml: unknown parameter 'max_beams'"):
        MclConfig.from_ros({"max_beams": 60}, where="conf/localizer/x.yaml")
    with pytest.raises(
        ValueError, match=r"amcl\.yaml: section 'filter': .*'max_particles' must be of type"
    ):
        MclConfig.from_sections({"filter": {"max_particles": 10.5}}, where)
    with pytest.raises(ValueError, match=r"amcl\.yaml: section 'motion': odom_model_type must be"):
        MclConfig.from_sections({"motion": {"odom_model_type": "omni"}}, where)
    with pytest.raises(ValueError, match=r"amcl\.yaml: section 'sensor': key 'laser_model_type'"):
        MclConfig.from_sections({"sensor": {"laser_model_type": "ray"}}, where)
    with pytest.raises(ValueError, match="min_particles"):
        FilterParams(min_particles=10, max_particles=5)
    # A key of a model not chosen is still checked (ROS reads every parameter).
    with pytest.raises(ValueError, match="laser_lambda_short"):
        MclConfig.from_ros({"laser_model_type": "likelihood_field", "laser_lambda_short": 0.0})
    with pytest.raises(ValueError, match=r"section 'sensor': .*laser_lambda_short"):
        MclConfig.from_sections(
            {"sensor": {"laser_model_type": "likelihood_field", "laser_lambda_short": 0.0}}, where
        )


def test_bad_input_is_rejected_clearly() -> None:
    grid = small_map()
    amcl = amcl_filter(grid, seed=0)
    scan = np.full(SPEC.num_beams, 2.0, dtype=np.float32)
    with pytest.raises(RuntimeError, match="initialize"):
        amcl.update(np.zeros(3), scan)
    amcl.initialize_global()
    with pytest.raises(ValueError, match=r"expected \(667,\) ranges"):
        amcl.update(np.zeros(3), scan[:100])
    with pytest.raises(ValueError, match="odom_pose"):
        amcl.update(np.array([0.0, np.inf, 0.0]), np.full(SPEC.num_beams, 2.0))
    blocked = OccupancyGrid(np.where(grid.free, UNKNOWN, grid.cells).astype(np.int8), 0.05)
    with pytest.raises(ValueError, match="no free cell"):
        amcl_filter(blocked)
    with pytest.raises(ValueError, match="symmetric PSD"):
        amcl.initialize_pose(np.zeros(3), -np.eye(3))


def test_benchmark_quick_run_reports_its_figures(quick_benchmark) -> None:
    figures = quick_benchmark("amcl.py")
    for model in ("likelihood_field", "likelihood_field_prob", "beam"):
        for key in ("hz_1k", "hz_5k", "hz_10k", "hz_10k_1thread", "reference_hz_10k"):
            assert figures[f"{model}_{key}"] > 0, (model, key)
    # the compiled and numpy field models agree; the beam model's table quantises ranges
    assert figures["likelihood_field_weights_max_rel_diff"] < 1e-9
    assert figures["likelihood_field_prob_weights_max_rel_diff"] < 1e-9
    assert figures["beam_weights_median_rel_diff"] < 0.2


def test_map1_accuracy_with_the_shipped_config(stdr_maps_dir: Path) -> None:
    """Paper map 1, the trajectory stage's seed and length, UG01 noise: the accuracy goal."""
    grid = load_map(stdr_maps_dir / "sparse_obstacles.yaml")
    traj = drive_trajectory(grid, 600, seed=7)
    ranges = ug01_scans(grid, traj.truth, seed=8)
    params = shipped("amcl")
    pos, head = errors(
        run_mcl(grid, SPEC, traj, ranges, params, mode="tracking", seed=0).table, traj
    )
    assert pos.mean() <= 0.05
    assert head.mean() <= 2.0
    pos, _ = errors(run_mcl(grid, SPEC, traj, ranges, params, mode="global", seed=0).table, traj)
    assert pos[0] > 0.5 and pos[300:].max() < 0.5
