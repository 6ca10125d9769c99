"""Localizer configs in sections (issue 43): each section read by its part, unknown keys named
with their file and section, every default written once, and the filter's policies as parts."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from scanloc.localize.catalog import raw_config
from scanloc.localize.kinds import LocalizeInputs, run_localizer
from scanloc.localize.mcl.averages import LikelihoodAverages
from scanloc.localize.mcl.config import MclConfig, build_filter, filter_from_sections
from scanloc.localize.mcl.estimator import ClusterEstimator, WeightedMeanEstimator, map_bins
from scanloc.localize.mcl.parts import PROPOSALS, NoParams, PartsContext
from scanloc.localize.mcl.resampler import FixedResampler, KldResampler, SelectiveResampling
from scanloc.localize.show import resolved
from scanloc.trajectory.format import Trajectory
from small_world import SPEC, small_map

CONF = Path(__file__).resolve().parents[1] / "conf" / "localizer"
NAMES = sorted(p.stem for p in CONF.glob("*.yaml"))


def _own(name: str) -> dict:
    own = yaml.safe_load((CONF / f"{name}.yaml").read_text())
    own.pop("defaults", None)
    return own


def _without(cfg: dict, section: str, key: str) -> dict:
    """`cfg` with `section.key` as it would be if the file did not write it: the parents'
    value, else nothing (the part's default)."""
    out = copy.deepcopy(cfg)
    parents = [
        p
        for p in yaml.safe_load((CONF / f"{cfg['meta']['name']}.yaml").read_text()).get(
            "defaults", []
        )
        if p != "_self_"
    ]
    inherited = {}
    for parent in parents:
        inherited = {**inherited, **(raw_config(parent, CONF).get(section) or {})}
    if key in inherited:
        out[section][key] = inherited[key]
    else:
        del out[section][key]
    return out


@pytest.mark.parametrize("name", NAMES)
def test_every_key_a_config_writes_changes_it(name: str) -> None:
    """0 defaults written twice: removing any key a config file writes changes what the config
    amounts to (every key's value with the parts' defaults filled in), so no file repeats its
    parts' defaults or its parents' values."""
    cfg = raw_config(name, CONF)
    whole = resolved(cfg)
    for section, values in _own(name).items():
        for key in values:
            if section == "meta" and key == "name":
                continue
            try:
                without = resolved(_without(cfg, section, key))
            except (ValueError, KeyError):
                continue  # a key the config cannot do without
            assert without != whole, f"{name}.yaml: {section}.{key} repeats a default"


@pytest.mark.parametrize("name", NAMES)
def test_every_shipped_config_resolves(name: str) -> None:
    cfg = resolved(raw_config(name, CONF))
    assert cfg["meta"]["name"] == name


def _sections_error(cfg: dict, match: str) -> None:
    grid = small_map()
    context = PartsContext(grid, SPEC, hypotheses=lambda: lambda scan: None)
    with pytest.raises(ValueError, match=match):
        filter_from_sections(cfg, "conf/localizer/mine.yaml", context)


@pytest.mark.parametrize(
    ("section", "key"),
    [("filter", "max_particle"), ("motion", "alpha1"), ("sensor", "z_hit")],
)
def test_an_unknown_key_names_the_file_the_section_and_the_key(section: str, key: str) -> None:
    _sections_error({section: {key: 1}}, rf"mine\.yaml: section '{section}': unknown key '{key}'")


def test_a_typed_section_checks_its_keys_against_its_type() -> None:
    _sections_error(
        {"mixing": {"type": "constant", "threshold": 0.3}},
        r"mine\.yaml: section 'mixing': unknown key 'threshold'; known: share",
    )
    _sections_error(
        {"mixing": {"type": "sometimes"}},
        r"mine\.yaml: section 'mixing': key 'type': expected one of .*'verified_gate'",
    )
    _sections_error(
        {"weighting": {"type": "importance"}},
        r"section 'weighting': type 'importance' needs the proposal of type 'learned'",
    )
    _sections_error(
        {"filter": {"resample_interval": 1.5}},
        r"mine\.yaml: section 'filter': the parameter 'resample_interval' must be of type int",
    )
    _sections_error({"filter": {"estimator": "mode"}}, r"section 'filter': estimator must be")


def test_a_section_no_part_of_the_kind_reads_is_an_error() -> None:
    cfg = {"meta": {"name": "mine", "kind": "learned"}, "filter": {"max_particles": 10}}
    traj = Trajectory(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)))
    inputs = LocalizeInputs(traj, np.zeros((1, SPEC.num_beams)), Path("map.yaml"), SPEC)
    with pytest.raises(ValueError, match=r"mine\.yaml: section 'filter': a localizer of kind"):
        run_localizer(cfg, inputs)


def test_a_users_flat_ros_parameters_read_across() -> None:
    ros = {"min_particles": 500, "laser_z_hit": 0.5, "odom_model_type": "diff-corrected"}
    config = MclConfig.from_ros(ros, where="amcl.yaml")
    assert config.filter.min_particles == 500
    assert config.sensor.laser_z_hit == 0.5
    assert config.odometry.odom_model_type == "diff-corrected"
    with pytest.raises(ValueError, match=r"amcl\.yaml: unknown parameter 'pf_err'"):
        MclConfig.from_ros({"pf_err": 0.05}, where="amcl.yaml")


def test_a_new_proposal_type_is_one_registration() -> None:
    class Corner:
        needs_scan = False

        def observe(self, scan: np.ndarray) -> None: ...

        def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
            return np.tile([1.0, 1.0, 0.0], (n, 1))

        def density(self, poses: np.ndarray) -> np.ndarray:
            return np.ones(len(poses))

        def counts(self) -> dict[str, int]:
            return {}

    PROPOSALS.register("corner_for_test", NoParams)(lambda params, context: Corner())
    try:
        cfg = {
            "filter": {"mode": "global", "min_particles": 50, "max_particles": 50},
            "proposal": {"type": "corner_for_test"},
        }
        pf = filter_from_sections(cfg, "mine.yaml", PartsContext(small_map(), SPEC))
        pf.initialize_global()
        np.testing.assert_array_equal(pf.poses, np.tile([1.0, 1.0, 0.0], (50, 1)))
    finally:
        del PROPOSALS.types["corner_for_test"]


def test_every_scan_updates_standing_still_on_motion_does_not() -> None:
    grid = small_map()
    scan = np.full(SPEC.num_beams, 2.0)
    for trigger, expected in (("on_motion", False), ("every_scan", True)):
        config = MclConfig.from_sections({"filter": {"update_trigger": trigger}}, "mine.yaml")
        pf = build_filter(grid, SPEC, config)
        pf.initialize_pose(np.array([3.0, 2.5, 0.0]))
        pf.update(np.zeros(3), scan)
        assert pf.update(np.zeros(3), scan).updated is expected


def test_fixed_resampler_keeps_its_count_and_injects_like_kld() -> None:
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(0, 5, 300), rng.uniform(0, 4, 300), np.zeros(300)])
    weights = np.full(300, 1 / 300)
    inject = lambda m: (np.tile([9.0, 9.0, 0.0], (m, 1)), np.ones(m))  # noqa: E731
    fixed = FixedResampler(max_particles=400)
    out, out_weights = fixed.resample(poses, weights, 0.25, inject, np.random.default_rng(1))
    assert len(out) == 400 and out_weights.sum() == pytest.approx(1.0)
    injected = np.all(out == [9.0, 9.0, 0.0], axis=1)
    assert fixed.injected == injected.sum() and 60 < injected.sum() < 140
    # the same uniforms: every draw KLD makes, the fixed resampler makes the same way
    kld = KldResampler(map_bins(small_map()), 10, 400)
    kld_out, _ = kld.resample(poses, weights, 0.25, inject, np.random.default_rng(1))
    np.testing.assert_array_equal(kld_out, out[: len(kld_out)])


def test_selective_resampling_skips_while_the_effective_size_is_large() -> None:
    poses = np.zeros((100, 3))
    wrapped = SelectiveResampling(FixedResampler(100))
    even = np.full(100, 0.01)
    assert wrapped.resample(poses, even, 0.0, None, np.random.default_rng(0)) is None
    peaked = np.r_[0.9, np.full(99, 0.1 / 99)]
    assert wrapped.resample(poses, peaked, 0.0, None, np.random.default_rng(0)) is not None


def test_weighted_mean_agrees_with_the_heaviest_cluster_on_one_mode() -> None:
    rng = np.random.default_rng(3)
    poses = np.column_stack(
        [rng.normal(2.0, 0.05, 500), rng.normal(3.0, 0.05, 500), rng.normal(3.1, 0.02, 500)]
    )
    poses[:, 2] = np.arctan2(np.sin(poses[:, 2]), np.cos(poses[:, 2]))  # across ±π
    weights = rng.uniform(0.5, 1.0, 500)
    weights /= weights.sum()
    mean, cov = WeightedMeanEstimator().estimate(poses, weights)
    cluster_mean, cluster_cov = ClusterEstimator(map_bins(small_map())).estimate(poses, weights)
    np.testing.assert_allclose(mean, cluster_mean, atol=1e-9)
    # amcl's heading variance is its own circular formula: equal to 1e-5 on this tight cloud
    np.testing.assert_allclose(cov, cluster_cov, rtol=1e-4, atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(
    st.floats(0, 1),
    st.floats(0, 1),
    st.lists(st.floats(1e-6, 10.0), min_size=1, max_size=20),
)
def test_likelihood_averages_follow_amcls_recurrence(slow: float, fast: float, values) -> None:
    averages = LikelihoodAverages(slow, fast)
    w_slow = w_fast = 0.0
    for w in values:
        averages.follow(w)
        w_slow = w if w_slow == 0.0 else w_slow + slow * (w - w_slow)
        w_fast = w if w_fast == 0.0 else w_fast + fast * (w - w_fast)
    assert (averages.slow, averages.fast) == (w_slow, w_fast)
    assert averages.lost() == 1.0 - w_fast / w_slow
