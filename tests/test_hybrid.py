"""The hybrid localizer (amcl with the learned proposal): the proposal's density, the importance
weights of proposed particles against a brute-force computation, and its behaviour with a
perfect and with a useless proposal, beside amcl with the uniform one."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from scanloc.evaluate.metrics import convergence_metrics
from scanloc.localize.catalog import raw_config
from scanloc.localize.hybrid import (
    AdaptiveMixing,
    AdaptiveMixingParams,
    ConstantMixing,
    ConstantMixingParams,
    ImportanceWeightParams,
    ImportanceWeights,
    LearnedProposal,
    LearnedProposalParams,
    VerifiedGate,
    VerifiedGateMixing,
    VerifiedGateParams,
)
from scanloc.localize.hybrid import _mixture_density as mixture_density
from scanloc.localize.hypothesis_verification import HypothesisVerifier, VerifierParams
from scanloc.localize.learned_localizer import LearnedParams
from scanloc.localize.mcl.config import build_filter, filter_from_sections
from scanloc.localize.mcl.filter import ParticleFilter, run_filter
from scanloc.localize.mcl.mixing import Mixing
from scanloc.localize.mcl.parts import PartsContext
from scanloc.localize.mcl.proposals import UniformProposal
from scanloc.pose import wrap_angle
from scanloc.scanlocnet.model import Hypotheses
from scanloc.trajectory.drive import drive_trajectory
from small_world import SPEC, small_map, ug01_scans
from test_amcl import CONF, amcl_filter, ros

GRID = small_map()
# conf/localizer/hybrid.yaml's departures from amcl's defaults
HYBRID_ROS = {"laser_model_type": "likelihood_field_prob", "resample_interval": 1}
# The settings these tests were written for: the kidnap probability 0.1 (the shipped 0.3 is
# ImportanceWeightParams' default) and 5 % of the particles proposed at every update.
WEIGHTS = ImportanceWeightParams(kidnap_probability=0.1)
CONSTANT = ConstantMixingParams(share=0.05)
PROPOSAL = LearnedProposalParams()


def hybrid_filter(
    proposal: LearnedProposal,
    mixing: Mixing | None = None,
    weights: ImportanceWeightParams = WEIGHTS,
    seed: int = 0,
    **ros_params: object,
) -> ParticleFilter:
    """The particle filter with the learned proposal, a mixing (default: the constant share)
    and the importance weights plugged in."""
    weighting = ImportanceWeights(proposal, weights)
    config = ros(**HYBRID_ROS, publish_every_update=True, **ros_params)
    mixing = mixing or ConstantMixing(CONSTANT)
    return build_filter(
        GRID, SPEC, config, seed, proposal=proposal, weighting=weighting, mixing=mixing
    )


def hypotheses_from(poses_of: Callable[[np.ndarray], np.ndarray], std: float) -> Callable:
    """A stand-in for the network: the hypotheses `poses_of(scan)` (K, 3), equal weights."""

    def hypotheses_of(scan: np.ndarray) -> Hypotheses:
        poses = np.atleast_2d(poses_of(scan))
        k = len(poses)
        return Hypotheses(
            poses[None], np.full((1, k), 1.0 / k), np.full((1, k, 3), [std, std, std / 2])
        )

    return hypotheses_of


def proposal_at(
    poses: np.ndarray, params: LearnedProposalParams = PROPOSAL, std: float = 0.2
) -> LearnedProposal:
    proposal = LearnedProposal(hypotheses_from(lambda _: poses, std), UniformProposal(GRID), params)
    proposal.observe(np.zeros(SPEC.num_beams, dtype=np.float32))
    return proposal


def brute_mixture(poses, means, stds, weights) -> np.ndarray:
    """Σ_k w_k Π_axis N(axis; μ, σ) with the heading difference wrapped, by scipy."""
    out = np.zeros(len(poses))
    for mean, std, w in zip(means, stds, weights, strict=True):
        dt = np.angle(np.exp(1j * (poses[:, 2] - mean[2])))
        out += (
            w
            * stats.norm.pdf(poses[:, 0], mean[0], std[0])
            * stats.norm.pdf(poses[:, 1], mean[1], std[1])
            * stats.norm.pdf(dt, 0.0, std[2])
        )
    return out


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(1, 6))
def test_mixture_density_equals_a_brute_force_sum(seed: int, k: int) -> None:
    rng = np.random.default_rng(seed)
    means = np.column_stack([rng.uniform(0, 6, k), rng.uniform(0, 5, k), rng.uniform(-3, 3, k)])
    stds = rng.uniform(0.05, 0.5, (k, 3))
    weights = rng.dirichlet(np.ones(k))
    poses = means[rng.integers(0, k, 200)] + rng.normal(0, 0.4, (200, 3))
    poses[:, 2] = wrap_angle(poses[:, 2])
    fast = mixture_density(poses, means, stds, weights)
    slow = brute_mixture(poses, means, stds, weights)
    np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-9 * slow.max())


def test_proposal_density_is_normalised_over_the_map() -> None:
    """E_q[u(x) / q(x)] = ∫ u = 1 when q covers the free space (the uniform share does): the
    sampler and the density describe the same, normalised distribution."""
    params = LearnedProposalParams(uniform_share=0.1)
    proposal = proposal_at(np.array([[1.0, 1.0, 0.5], [4.8, 3.9, -3.1], [3.0, 4.5, 3.1]]), params)
    rng = np.random.default_rng(0)
    poses = proposal.sample(200_000, rng)
    ratio = proposal.uniform.density(poses) / proposal.density(poses)
    assert ratio.mean() == pytest.approx(1.0, rel=0.03)
    assert proposal.inferences == 1  # one network run per observed scan, however often used


def test_proposed_particles_get_the_mixture_weights() -> None:
    """After the filter's mixing step (the mixing's share drawn from the proposal, the union
    weighted by the weighting), every weight is its carried weight (α w_j for a motion
    particle, β / m for a proposed one) times bel⁻(x) / d(x), bel⁻ = (1 - ε) b + ε u and
    d = α b + β q, with b the kernel density of the weighted particles: recomputed here
    particle by particle with scipy."""
    traj = drive_trajectory(GRID, 30, seed=1, clearance=0.25)
    ranges = ug01_scans(GRID, traj.truth, seed=2)
    proposal = proposal_at(traj.truth[:1] + np.array([0.3, -0.2, 0.1]))
    mixing = ConstantMixing(ConstantMixingParams(share=0.2))
    weights_params = ImportanceWeightParams(kidnap_probability=0.05)
    amcl = hybrid_filter(proposal, mixing, weights_params)
    amcl.initialize_pose(traj.truth[0])
    amcl.update(traj.odometry[0], ranges[0])
    before_poses = amcl.poses.copy()
    before_weights = np.random.default_rng(3).dirichlet(np.ones(len(before_poses)))
    amcl.poses, amcl.weights = before_poses.copy(), before_weights.copy()
    amcl.mix_in_proposal()
    poses, weights = amcl.poses, amcl.weights
    assert mixing.counts() == {"n_updates": 1, "n_mixed_updates": 1}
    n, m = len(before_poses), round(0.2 * len(before_poses))
    assert len(poses) == n + m
    np.testing.assert_array_equal(poses[:n], before_poses)
    stds = np.broadcast_to([0.05, 0.05, 0.05], before_poses.shape)
    bel = brute_mixture(poses, before_poses, stds, before_weights)
    q = 0.9 * brute_mixture(poses, proposal.means, proposal.stds, proposal.weights)
    u = proposal.uniform.density(poses)
    q += 0.1 * u
    alpha, beta = n / (n + m), m / (n + m)
    carried = np.concatenate([alpha * before_weights, np.full(m, beta / m)])
    expected = carried * (0.95 * bel + 0.05 * u) / (alpha * bel + beta * q)
    # (atol: the density drops kernel terms below e⁻²⁵ of their peak)
    np.testing.assert_allclose(weights, expected / expected.sum(), rtol=1e-6, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(
    b=st.floats(1e-6, 1e3),
    err=st.floats(-3.0, 3.0),
    q=st.floats(1e-6, 1e3),
    u=st.floats(1e-3, 1.0),
    eps=st.floats(0.0, 0.9),
    share=st.floats(0.01, 0.99),
)
def test_a_misestimated_motion_density_moves_the_weight_factor_no_more_than_itself(
    b: float, err: float, q: float, u: float, eps: float, share: float
) -> None:
    """The bound of hybrid.py's docstring: |ln r(b̂) - ln r(b)| <= |ln(b̂ / b)| for the factor
    r(b) = ((1 - ε) b + ε u) / (α b + β q), and r stays between its two limits."""
    alpha, beta = 1.0 - share, share

    def r(bel: float) -> float:
        return ((1.0 - eps) * bel + eps * u) / (alpha * bel + beta * q)

    b_hat = b * math.exp(err)
    assert abs(math.log(r(b_hat)) - math.log(r(b))) <= abs(err) + 1e-9
    low, high = sorted(((1.0 - eps) / alpha, eps * u / (beta * q)))
    assert low * (1 - 1e-9) <= r(b_hat) <= high * (1 + 1e-9)


def test_injected_and_initial_particles_are_weighted_u_over_q() -> None:
    proposal = proposal_at(np.array([[2.0, 2.0, 0.0]]))
    amcl = hybrid_filter(proposal)
    poses, weights = amcl.injection(500)
    u = proposal.uniform.density(poses)
    q = 0.9 * brute_mixture(poses, proposal.means, proposal.stds, proposal.weights) + 0.1 * u
    np.testing.assert_allclose(weights, u / q, rtol=1e-6)  # the density drops terms < e⁻²⁵


@pytest.fixture(scope="module")
def drive() -> tuple:
    traj = drive_trajectory(GRID, 260, seed=3, clearance=0.25, kidnap_steps=(180,))
    return traj, ug01_scans(GRID, traj.truth, seed=4)


def truth_of_scan(traj, ranges, noise: float) -> Callable[[np.ndarray], np.ndarray]:
    """The true pose of a scan, plus noise: a perfect learned localizer."""
    rng = np.random.default_rng(5)
    by_scan = {r.tobytes(): p for r, p in zip(ranges, traj.truth, strict=True)}
    return lambda scan: by_scan[np.asarray(scan).tobytes()] + rng.normal(0, noise, 3)


def learned_proposal(poses_of, params: LearnedProposalParams = PROPOSAL):
    """The learned proposal of the stand-in network `poses_of` (standard deviations 0.1)."""
    return LearnedProposal(hypotheses_from(poses_of, 0.1), UniformProposal(GRID), params)


def run_hybrid(traj, ranges, poses_of, seed: int = 0):
    pf = hybrid_filter(learned_proposal(poses_of), seed=seed)
    return run_filter(pf, traj, ranges, "global").table


def test_a_perfect_proposal_localizes_on_the_first_update_and_after_a_kidnap(drive) -> None:
    traj, ranges = drive
    table = run_hybrid(traj, ranges, truth_of_scan(traj, ranges, 0.05))
    m = convergence_metrics(traj.truth, table, traj.kidnap_steps)
    assert m["steps_to_converge"] == 0 and m["converged"] == 1
    assert m["recovered"] == 1 and m["recovery_steps_1"] <= 5
    err = np.hypot(table.x - traj.truth[:, 0], table.y - traj.truth[:, 1])
    assert err.iloc[0] < 0.2


def test_a_useless_proposal_is_no_worse_than_the_uniform_one(drive) -> None:
    """Hypotheses always in the same wrong corner: the defensive uniform share and the u/q
    weights leave the filter as good as amcl's global localization with uniform particles."""
    traj, ranges = drive
    far = np.array([5.5, 4.5, 0.0])
    assert np.hypot(*(traj.truth[:180, :2] - far[:2]).T).min() > 0.5
    uniform = []
    useless = []
    for seed in (0, 1):
        amcl = amcl_filter(GRID, seed=seed, laser_model_type="likelihood_field_prob")
        table = run_filter(amcl, traj, ranges, "global").table
        uniform.append(convergence_metrics(traj.truth[:180], table.iloc[:180]))
        table = run_hybrid(traj, ranges, lambda _: far, seed=seed)
        useless.append(convergence_metrics(traj.truth[:180], table.iloc[:180]))
    for u, h in zip(uniform, useless, strict=True):
        assert u["converged"] == 1 and h["converged"] == 1
        assert h["steps_to_converge"] <= u["steps_to_converge"] + 20
        assert h["tracking_pos_err_mean_m"] <= 1.5 * u["tracking_pos_err_mean_m"] + 0.02


def test_bad_parameters_are_rejected() -> None:
    with pytest.raises(ValueError, match="uniform_share"):
        LearnedProposalParams(uniform_share=1.0)
    with pytest.raises(ValueError, match="std_inflation > 0"):
        LearnedProposalParams(min_std_xy=0.0)
    with pytest.raises(ValueError, match="1 <= k"):  # the hypotheses' count: `learned` section
        LearnedParams(k=0)
    with pytest.raises(ValueError, match="kidnap_probability"):
        ImportanceWeightParams(kidnap_probability=1.0)
    with pytest.raises(ValueError, match="kernel_centres >= 1"):
        ImportanceWeightParams(kernel_centres=0)
    for params in (ConstantMixingParams, AdaptiveMixingParams, VerifiedGateParams):
        with pytest.raises(ValueError, match="share"):
            params(share=1.0)
    with pytest.raises(ValueError, match="threshold"):
        AdaptiveMixingParams(threshold=1.0)
    with pytest.raises(ValueError, match="alpha_slow / alpha_fast"):
        AdaptiveMixingParams(alpha_slow=0.0)
    with pytest.raises(RuntimeError, match="observe"):
        learned_proposal(lambda _: np.zeros(3)).sample(3, np.random.default_rng(0))
    assert math.isfinite(ImportanceWeightParams().kidnap_probability)


def test_score_weights_follow_the_verified_scores_and_need_them() -> None:
    """weights_from 'score': the mixture is weighted by the verified hypotheses' calibrated
    scores (zero-score ones dropped), not by the network's probabilities."""
    poses = np.array([[1.0, 1.0, 0.0], [3.0, 1.0, 1.0], [2.0, 2.0, -1.0]])

    def scored(_: np.ndarray) -> Hypotheses:
        stds = np.full((1, 3, 3), 0.1)
        return Hypotheses(
            poses[None], np.array([[0.7, 0.2, 0.1]]), stds, np.array([[0.1, 0.6, 0.0]])
        )

    by_score = LearnedProposalParams(weights_from="score")
    proposal = LearnedProposal(scored, UniformProposal(GRID), by_score)
    proposal.observe(np.zeros(SPEC.num_beams, dtype=np.float32))
    proposal.sample(1, np.random.default_rng(0))
    np.testing.assert_allclose(proposal.weights, [1 / 7, 6 / 7])
    np.testing.assert_allclose(proposal.means, poses[:2])
    unscored = learned_proposal(lambda _: poses, by_score)
    unscored.observe(np.zeros(SPEC.num_beams, dtype=np.float32))
    with pytest.raises(ValueError, match="verified hypotheses"):
        unscored.sample(1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="weights_from"):
        LearnedProposalParams(weights_from="votes")


def test_the_proposal_uses_every_hypothesis_it_gets() -> None:
    """How many hypotheses there are is the `learned` section's `k` (the decoding): the
    proposal keeps all those with a positive weight."""
    poses = np.column_stack([np.linspace(0.5, 5.5, 30), np.full(30, 2.0), np.zeros(30)])
    proposal = learned_proposal(lambda _: poses)
    proposal.observe(np.zeros(SPEC.num_beams, dtype=np.float32))
    proposal.sample(1, np.random.default_rng(0))
    np.testing.assert_array_equal(proposal.means, poses)
    assert proposal.counts() == {"n_network_runs": 1}


# The adaptive settings these tests were written for (alphas 0.05 / 0.5, threshold 0.7; the
# shipped defaults are 0.05 / 0.8, 0.3). On this drive's clean stretch w_fast / w_slow falls to
# 0.36 at its lowest (lost 0.64), after the kidnap to 0.13.
ADAPTIVE = AdaptiveMixingParams(share=0.5, threshold=0.7, alpha_slow=0.05, alpha_fast=0.5)


def adaptive_hybrid(traj, ranges, poses_of, seed: int = 0) -> ParticleFilter:
    """The adaptive hybrid with amcl's recovery off (the adaptive share is its recovery)."""
    mixing = AdaptiveMixing(ADAPTIVE)
    return hybrid_filter(learned_proposal(poses_of), mixing, seed=seed, recovery_alpha_slow=0.0)


def test_adaptive_mixing_leaves_a_localized_filter_as_amcl(drive) -> None:
    """On a clean drive from a known pose the likelihood never falls below the threshold: no
    proposal particle is drawn and the network never runs, so the estimates equal amcl's with
    the same sensor model and settings exactly (tolerance 0)."""
    traj, all_ranges = drive
    poses_of = truth_of_scan(traj, all_ranges, 0.05)
    clean = traj.__class__(traj.times[:180], traj.truth[:180], traj.odometry[:180])
    ranges = all_ranges[:180]
    amcl = build_filter(
        GRID, SPEC, ros(**HYBRID_ROS, publish_every_update=True, recovery_alpha_slow=0.0), 0
    )
    plain = run_filter(amcl, clean, ranges, "tracking").table
    pf = adaptive_hybrid(clean, ranges, poses_of)
    hybrid = run_filter(pf, clean, ranges, "tracking").table
    assert pf.mixing.mixed_updates == 0 and pf.proposal.inferences == 0
    assert pf.mixing.updates >= 30
    assert hybrid.equals(plain)


def test_adaptive_mixing_draws_proposals_after_a_kidnap(drive) -> None:
    traj, ranges = drive
    pf = adaptive_hybrid(traj, ranges, truth_of_scan(traj, ranges, 0.05))
    table = run_filter(pf, traj, ranges, "tracking").table
    m = convergence_metrics(traj.truth, table, traj.kidnap_steps)
    assert m["recovered"] == 1 and m["recovery_steps_1"] <= 30
    assert 0 < pf.mixing.mixed_updates < 0.2 * pf.mixing.updates


# The verified gate with amcl's recovery off (the gate is the only way proposals come in), with
# the settings these tests were written for (margin 0.2, one scan, no warm-up; the shipped
# defaults are 0.4, 3 and 20).
GATED = VerifiedGateParams(share=0.5, margin=0.2, persistence=1, warmup=0)
# A look-alike the network might offer beside the truth: the room's far corner.
ELSEWHERE = np.array([5.3, 4.4, 2.5])


def gated_hybrid(poses_of) -> ParticleFilter:
    proposal = learned_proposal(poses_of)
    verifier = HypothesisVerifier(GRID, SPEC, VerifierParams())
    gate = VerifiedGate(verifier, GATED.margin, persistence=GATED.persistence)
    mixing = VerifiedGateMixing(GATED, proposal, gate)
    return hybrid_filter(proposal, mixing, recovery_alpha_slow=0.0)


def with_elsewhere(poses_of) -> Callable[[np.ndarray], np.ndarray]:
    return lambda scan: np.vstack([poses_of(scan), ELSEWHERE])


def test_the_gate_opens_only_for_a_hypothesis_that_explains_more_of_the_scan(drive) -> None:
    traj, ranges = drive
    gate = VerifiedGate(HypothesisVerifier(GRID, SPEC, VerifierParams()), 0.2)
    truth, scan, one = traj.truth[10], ranges[10], np.ones(1)
    at_truth, elsewhere = truth[None], ELSEWHERE[None]
    assert not gate.opens(scan, at_truth, one, elsewhere)  # the estimate is right
    assert gate.opens(scan, elsewhere, one, at_truth)  # the truth is offered elsewhere
    assert not gate.opens(scan, elsewhere, one, elsewhere + np.array([0.05, 0.0, 0.02]))  # not away
    assert not gate.opens(scan, elsewhere, one, np.zeros((0, 3)))  # nothing offered
    shifted = VerifiedGate(gate.verifier, 0.2, laser_mount=(1.0, 0.0, 0.0))
    base_behind = (truth - [np.cos(truth[2]), np.sin(truth[2]), 0.0])[None]
    assert not shifted.opens(scan, base_behind, one, elsewhere)  # the laser pose is scored
    # hypotheses are base poses too: with a laser turned 90° on the robot, the base pose whose
    # laser sees the scan opens a strict gate; taken for a laser pose, it is 90° off
    turned = VerifiedGate(gate.verifier, 0.5, laser_mount=(0.0, 0.0, np.pi / 2))
    base_turned = (truth - [0.0, 0.0, np.pi / 2])[None]
    assert turned.opens(scan, elsewhere, one, base_turned)
    assert not VerifiedGate(gate.verifier, 0.5).opens(scan, elsewhere, one, base_turned)


def test_the_gate_waits_for_persistent_evidence(drive) -> None:
    traj, ranges = drive
    gate = VerifiedGate(HypothesisVerifier(GRID, SPEC, VerifierParams()), 0.2, persistence=2)
    one, elsewhere = np.ones(1), ELSEWHERE[None]
    wrong = [gate.opens(ranges[k], elsewhere, one, traj.truth[k][None]) for k in (10, 11)]
    assert wrong == [False, True]
    assert not gate.opens(ranges[12], traj.truth[12][None], one, elsewhere)  # resets the count
    assert not gate.opens(ranges[13], elsewhere, one, traj.truth[13][None])


def test_the_verified_gate_leaves_a_localized_filter_as_amcl(drive) -> None:
    """On a clean drive the estimate explains the scan better than the look-alike: no
    proposal particle is drawn, and the estimates equal amcl's exactly (tolerance 0)."""
    traj, all_ranges = drive
    clean = traj.__class__(traj.times[:180], traj.truth[:180], traj.odometry[:180])
    ranges = all_ranges[:180]
    amcl = build_filter(
        GRID, SPEC, ros(**HYBRID_ROS, publish_every_update=True, recovery_alpha_slow=0.0), 0
    )
    plain = run_filter(amcl, clean, ranges, "tracking").table
    pf = gated_hybrid(with_elsewhere(truth_of_scan(traj, all_ranges, 0.05)))
    gated = run_filter(pf, clean, ranges, "tracking").table
    assert pf.mixing.mixed_updates == 0 and pf.mixing.updates >= 30
    assert pf.proposal.inferences == pf.mixing.updates  # the gate asks on every update
    assert gated.equals(plain)


def test_the_verified_gate_draws_proposals_after_a_kidnap(drive) -> None:
    traj, ranges = drive
    pf = gated_hybrid(with_elsewhere(truth_of_scan(traj, ranges, 0.05)))
    table = run_filter(pf, traj, ranges, "tracking").table
    m = convergence_metrics(traj.truth, table, traj.kidnap_steps)
    assert m["recovered"] == 1 and m["recovery_steps_1"] <= 10
    assert 0 < pf.mixing.mixed_updates < 0.2 * pf.mixing.updates


def hybrid_from_sections(sections: dict) -> ParticleFilter:
    """The particle filter a sectioned config describes, the network a stand-in."""
    network = hypotheses_from(lambda _: ELSEWHERE, 0.1)
    context = PartsContext(GRID, SPEC, hypotheses=lambda: network)
    return filter_from_sections(sections, "conf/localizer/mine.yaml", context)


def test_the_gate_is_checked() -> None:
    # one mixing per config: a verified gate's keys in an adaptive mixing are unknown there
    with pytest.raises(ValueError, match=r"mine\.yaml: section 'mixing': unknown key 'margin'"):
        hybrid_from_sections(
            {"proposal": {"type": "learned"}, "mixing": {"type": "adaptive", "margin": 0.2}}
        )
    with pytest.raises(ValueError, match="margin"):
        VerifiedGateParams(margin=1.5)
    with pytest.raises(ValueError, match="persistence >= 1"):
        VerifiedGateParams(persistence=0)
    with pytest.raises(ValueError, match=r"mine\.yaml: section 'mixing': .*margin must lie"):
        hybrid_from_sections(
            {"proposal": {"type": "learned"}, "mixing": {"type": "verified_gate", "margin": 1.5}}
        )
    # the gate needs the learned proposal's hypotheses
    with pytest.raises(
        ValueError, match="type 'verified_gate' needs the proposal of type 'learned'"
    ):
        hybrid_from_sections({"mixing": {"type": "verified_gate"}})
    # and gets its verifier from the `verifier` section, its settings from its own
    pf = hybrid_from_sections(
        {
            "proposal": {"type": "learned"},
            "mixing": {"type": "verified_gate", "margin": 0.3, "persistence": 2},
            "verifier": {"iterations": 4},
        }
    )
    assert isinstance(pf.mixing, VerifiedGateMixing) and pf.mixing.proposal is pf.proposal
    gate = pf.mixing.gate
    assert (gate.margin, gate.persistence, gate.verifier.params.iterations) == (0.3, 2, 4)
    assert pf.mixing.params == VerifiedGateParams(margin=0.3, persistence=2)


@pytest.mark.parametrize(
    ("name", "mixing"),
    [
        ("hybrid", ConstantMixing),
        ("hybrid_adaptive", AdaptiveMixing),
        ("hybrid_real", VerifiedGateMixing),
    ],
)
def test_the_shipped_hybrids_plug_in_their_parts(name: str, mixing: type) -> None:
    """Each shipped hybrid's `proposal`, `mixing` and `weighting` sections build the learned
    parts, the importance weights around the filter's own proposal."""
    pf = hybrid_from_sections(raw_config(name, CONF))
    assert isinstance(pf.proposal, LearnedProposal)
    assert type(pf.mixing) is mixing
    assert isinstance(pf.weighting, ImportanceWeights) and pf.weighting.proposal is pf.proposal


@pytest.mark.slow
def test_benchmark_quick_run_reports_the_four_hybrids(quick_benchmark) -> None:
    figures = quick_benchmark("hybrid.py")
    assert figures["network_ms_median"] > 0 and figures["verification_ms_median"] > 0
    for label in ("hybrid", "adaptive_hybrid", "verified_hybrid", "gated_hybrid"):
        for size in ("1k", "5k"):
            assert figures[f"{label}_hz_{size}"] > 0
            assert 0.0 <= figures[f"{label}_network_share_{size}"] <= 1.0
    # the constant share runs the network on every update, verified or not
    assert figures["hybrid_network_share_5k"] == figures["verified_hybrid_network_share_5k"] == 1.0
