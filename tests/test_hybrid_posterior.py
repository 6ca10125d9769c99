"""The hybrid's importance weights against the exact posterior: a brute-force Bayes filter on a
fine grid of poses of a small room, with the same motion model (its transition histogrammed
from many draws), the same sensor model (evaluated at every grid pose) and the same prediction
bel⁻ = (1 - ε) b + ε u at every update where the filter draws proposed particles (where its
mixing's share is 0, the filter's prior is the motion alone, and so is the exact one's).

1. Moments: the filter's weighted particles, carried over several updates without
   resampling while a proposal adds particles near the truth and its mirror twin, have the
   posterior's moments and twin mass within a Monte-Carlo tolerance (over 4 seeds the
   filter's figures spread by sd <= 0.011). Measured: exact mean x 1.766 m, twin mass 0.054;
   this weighting 1.754 m, 0.050; the previous one (weights overwritten, shares (1 - φ, φ),
   motion density histogrammed in 0.5 m x 0.5 m x 10° bins) 1.657 m, 0.274, which fails.
2. The whole distribution (slow tests): the total variation between the filter's weighted
   particles and the exact posterior over 0.25 m cells, at every update up to and including
   a kidnap, for the initial weights (a global start from the proposal) and each way the
   proposed share is decided (constant, adaptive, the verified gate) and with resampling; a
   weighting that believes twice the proposed share it drew (u / 2q where the proposal alone
   put particles) fails at the kidnap, where the new place's mass comes from the proposal."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pytest

from scanloc.localize.hybrid import (
    AdaptiveMixing,
    AdaptiveMixingParams,
    ConstantMixing,
    ConstantMixingParams,
    ImportanceWeightParams,
    ImportanceWeights,
    LearnedProposal,
    LearnedProposalParams,
    VerifiedGateMixing,
    VerifiedGateParams,
)
from scanloc.localize.mcl.config import build_filter
from scanloc.localize.mcl.proposals import UniformProposal
from scanloc.pose import wrap_angle
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid
from small_world import SPEC, ug01_scans
from test_amcl import ros
from test_hybrid import hypotheses_from

RES = 0.05  # the posterior grid's cell (m), as the map's
HEADINGS = 72  # 5° heading bins
EPS = 0.2  # kidnap probability per update
INITIAL = np.array([0.9, 0.8, 0.0])
INITIAL_COV = np.diag([0.2**2, 0.2**2, 0.2**2])
STEP = np.array([0.25, 0.0, 0.05])  # odometry increment per update, robot frame
UPDATES = 4
SENSOR = {  # a broad likelihood, so that the posterior spans many grid cells
    "laser_model_type": "likelihood_field_prob",
    "laser_max_beams": 6,
    "laser_sigma_hit": 0.4,
    "laser_z_hit": 0.8,
    "laser_z_rand": 0.2,
    "odom_model_type": "diff-corrected",
    "odom_alpha1": 0.05,
    "odom_alpha2": 0.05,
    "odom_alpha3": 0.05,
    "odom_alpha4": 0.05,
    "update_min_d": 0.0,
    "update_min_a": 0.0,
    "resample_interval": 1000,  # carry the weights: no resampling in this test
    "publish_every_update": True,
}


def room() -> OccupancyGrid:
    """A 3 m x 2 m room with a block near one end: nearly, but not exactly, point-symmetric."""
    cells = np.zeros((round(2.0 / RES), round(3.0 / RES)), dtype=np.int8)
    cells[:2], cells[-2:], cells[:, :2], cells[:, -2:] = OCCUPIED, OCCUPIED, OCCUPIED, OCCUPIED
    cells[round(1.2 / RES) : round(1.5 / RES), round(2.3 / RES) : round(2.5 / RES)] = OCCUPIED
    return OccupancyGrid(cells, RES)


GRID = room()


def grid_poses() -> np.ndarray:
    """Every state of the brute-force filter: free cell centres x headings, (H, R, C, 3)."""
    xs = (np.arange(GRID.width) + 0.5) * RES
    ys = (np.arange(GRID.height) + 0.5) * RES
    ths = wrap_angle(np.arange(HEADINGS) * 2 * np.pi / HEADINGS)
    th, y, x = np.meshgrid(ths, ys, xs, indexing="ij")
    return np.stack([x, y, th], axis=-1)


def clean_drive(steps: int) -> np.ndarray:
    """INITIAL, then `steps` odometry increments STEP: poses (steps + 1, 3)."""
    poses = [INITIAL]
    for _ in range(steps):
        x, y, th = poses[-1]
        c, s = np.cos(th), np.sin(th)
        poses.append(np.array([x + c * STEP[0], y + s * STEP[0], wrap_angle(th + STEP[2])]))
    return np.array(poses)


def drive() -> tuple[np.ndarray, np.ndarray]:
    """Truth = odometry (a clean drive from INITIAL) and its scans."""
    truth = clean_drive(UPDATES)
    return truth, ug01_scans(GRID, truth, seed=7)


def transition(motion, old: np.ndarray, new: np.ndarray, draws: int = 20_000) -> list:
    """Per source heading bin: (d_col, d_row, target heading bin, probability) of the motion
    model's draws from that bin's centre, histogrammed on the grid."""
    rng = np.random.default_rng(11)
    stencils = []
    for h in range(HEADINGS):
        th = wrap_angle(h * 2 * np.pi / HEADINGS)
        poses = np.tile([0.0, 0.0, th], (draws, 1))
        poses[:, 2] = th + rng.uniform(-np.pi / HEADINGS, np.pi / HEADINGS, draws)
        poses[:, :2] = rng.uniform(-RES / 2, RES / 2, (draws, 2))
        local_old = np.array([0.0, 0.0, old[2]])
        local_new = local_old + np.r_[new[:2] - old[:2], wrap_angle(new[2] - old[2])]
        motion.sample(poses, local_old, local_new, rng)
        cols = np.round(poses[:, 0] / RES).astype(int)
        rows = np.round(poses[:, 1] / RES).astype(int)
        bins = np.round(wrap_angle(poses[:, 2]) / (2 * np.pi / HEADINGS)).astype(int) % HEADINGS
        keys, counts = np.unique(np.stack([cols, rows, bins], 1), axis=0, return_counts=True)
        stencils.append([(*key, c / draws) for key, c in zip(keys, counts, strict=True)])
    return stencils


def shifted(a: np.ndarray, dr: int, dc: int) -> np.ndarray:
    """a moved by (dr, dc) cells, what leaves the grid dropped."""
    out = np.zeros_like(a)
    rows, cols = a.shape
    out[max(dr, 0) : rows + min(dr, 0), max(dc, 0) : cols + min(dc, 0)] = a[
        max(-dr, 0) : rows + min(-dr, 0), max(-dc, 0) : cols + min(-dc, 0)
    ]
    return out


def bayes_filter(
    sensor, stencils: Sequence[list], scans: np.ndarray, epsilons: Sequence[float], prior: str
) -> list[np.ndarray]:
    """The Bayes filter on the grid: the normalised posterior after every scan. `prior`:
    `pose` (N(INITIAL, INITIAL_COV)) or `uniform` (over the free cells); `stencils[t - 1]`:
    the transition to update t; `epsilons[t]`: the uniform share of update t's prediction
    (one per update: as many updates as it has)."""
    states = grid_poses()
    flat = states.reshape(-1, 3)
    free = GRID.free[None].repeat(HEADINGS, 0).reshape(-1)
    uniform = free / free.sum()
    if prior == "uniform":
        bel = uniform.copy()
    else:
        d = flat - INITIAL
        d[:, 2] = wrap_angle(d[:, 2])
        bel = np.exp(-0.5 * np.einsum("ni,ij,nj->n", d, np.linalg.inv(INITIAL_COV), d))
    bel = bel * sensor(flat, scans[0], False)
    beliefs = [bel / bel.sum()]
    for t in range(1, len(epsilons)):
        cube = beliefs[-1].reshape(states.shape[:3])
        pred = np.zeros_like(cube)
        for h, stencil in enumerate(stencils[t - 1]):
            for dc, dr, target, p in stencil:
                pred[target] += p * shifted(cube[h], dr, dc)
        pred = (1 - epsilons[t]) * pred.reshape(-1) / pred.sum() + epsilons[t] * uniform
        bel = pred * sensor(flat, scans[t], False)
        beliefs.append(bel / bel.sum())
    return beliefs


def exact_posterior(sensor, motion, truth: np.ndarray, scans: np.ndarray) -> np.ndarray:
    """The Bayes filter on the grid after the drive's last scan, mixing at every update."""
    stencils = [transition(motion, truth[t - 1], truth[t]) for t in range(1, len(truth))]
    return bayes_filter(sensor, stencils, scans, [EPS] * len(truth), "pose")[-1]


def summary(poses: np.ndarray, weights: np.ndarray, twin_of: np.ndarray) -> np.ndarray:
    """Weighted mean x, y, cos θ, sin θ, and the mass within 0.5 m of the twin pose."""
    w = weights / weights.sum()
    near_twin = np.hypot(*(poses[:, :2] - twin_of[:2]).T) < 0.5
    return np.array(
        [
            w @ poses[:, 0],
            w @ poses[:, 1],
            w @ np.cos(poses[:, 2]),
            w @ np.sin(poses[:, 2]),
            w[near_twin].sum(),
        ]
    )


def filter_summary(truth, scans, twin, seed: int) -> np.ndarray:
    means = np.stack([truth[0], twin])
    hypotheses = hypotheses_from(lambda _: means, 0.15)
    params = LearnedProposalParams(uniform_share=0.1)
    proposal = LearnedProposal(hypotheses, UniformProposal(GRID), params)
    weighting = ImportanceWeights(proposal, ImportanceWeightParams(kidnap_probability=EPS))
    mixing = ConstantMixing(ConstantMixingParams(share=0.5))
    config = ros(**SENSOR, max_particles=4000, min_particles=4000)
    pf = build_filter(
        GRID, SPEC, config, seed, proposal=proposal, weighting=weighting, mixing=mixing
    )
    pf.initialize_pose(INITIAL, INITIAL_COV)
    for t in range(len(truth)):
        pf.update(truth[t], scans[t])
    return summary(pf.poses, pf.weights, twin)


@pytest.fixture(scope="module")
def case() -> tuple:
    truth, scans = drive()
    twin = np.array([3.0 - truth[-1, 0], 2.0 - truth[-1, 1], wrap_angle(truth[-1, 2] + np.pi)])
    pf = build_filter(GRID, SPEC, ros(**SENSOR))
    exact = exact_posterior(pf.sensor_model, pf.motion, truth, scans)
    return truth, scans, twin, summary(grid_poses().reshape(-1, 3), exact, twin)


def test_the_weighted_particles_match_the_exact_posterior(case) -> None:
    truth, scans, twin, exact = case
    runs = np.array([filter_summary(truth, scans, twin, seed) for seed in range(4)])
    mean = runs.mean(axis=0)
    print("exact", np.round(exact, 3), "filter", np.round(mean, 3), "sd", np.round(runs.std(0), 3))
    assert 0.02 < exact[4] < 0.9  # the twin holds a real share of the posterior
    np.testing.assert_allclose(mean[:2], exact[:2], atol=0.03)
    np.testing.assert_allclose(mean[2:4], exact[2:4], atol=0.02)
    assert mean[4] == pytest.approx(exact[4], abs=0.02)


# The whole distribution (module doc, 2): a kidnap after KIDNAP_AT updates of the drive above,
# odometry going on as if nothing happened; the stand-in network proposes the start and where
# the robot is carried. 16000 particles, half the proposal uniform, 4 seeds: the total
# variation of the seeds' mean histogram stays <= TV_BOUND with the shipped weighting at every
# update (measured: 0.006-0.08; the initial weights over 8 seeds 0.079) and exceeds it at the
# kidnap with the share doubled (0.146-0.178; initial weights of 1: 0.633).
KIDNAP_AT = 4
KIDNAP_TO = np.array([2.3, 0.5, np.pi / 2])
PARTICLES = 16_000
CELL = 0.25  # the histogram's cells (m), heading summed over
TV_BOUND = 0.1
SEEDS = range(4)


def kidnap_case() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(odometry, truth, scans): the drive's odometry for KIDNAP_AT + 1 updates; the truth
    jumps to KIDNAP_TO at the last."""
    odometry = clean_drive(KIDNAP_AT)
    truth = np.array([*odometry[:KIDNAP_AT], KIDNAP_TO])
    return odometry, truth, ug01_scans(GRID, truth, seed=7)


def histogram(poses: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The weights' mass per CELL x CELL cell of the room (headings summed)."""
    cols = np.clip((poses[:, 0] / CELL).astype(int), 0, round(3.0 / CELL) - 1)
    rows = np.clip((poses[:, 1] / CELL).astype(int), 0, round(2.0 / CELL) - 1)
    out = np.zeros((round(2.0 / CELL), round(3.0 / CELL)))
    np.add.at(out, (rows, cols), weights / weights.sum())
    return out


def total_variation(a: np.ndarray, b: np.ndarray) -> float:
    return 0.5 * float(np.abs(a - b).sum())


class SharesSeen:
    """The mixing under test, recording the share it decided at each update."""

    def __init__(self, mixing) -> None:
        self.mixing, self.shares = mixing, []

    def share(self, poses: np.ndarray, weights: np.ndarray) -> float:
        self.shares.append(self.mixing.share(poses, weights))
        return self.shares[-1]

    def observe_likelihood(self, w_avg: float) -> None:
        self.mixing.observe_likelihood(w_avg)

    def counts(self) -> dict[str, int]:
        return self.mixing.counts()


class GateFromTheKidnap:
    """A stand-in for the verified gate: shut until the kidnap's update, open from then on."""

    def __init__(self) -> None:
        self.update = 0

    def opens(self, scan, poses, weights, hypotheses) -> bool:
        self.update += 1  # the mixing asks from the second update on
        return self.update + 1 >= KIDNAP_AT


class PriorIgnored(ImportanceWeights):
    """Initial weights that forget the proposal is not the prior (1, not u / q)."""

    def initial_weights(self, poses: np.ndarray) -> np.ndarray:
        return np.ones(len(poses))


class ShareDoubled:
    """The proposal as a weighting sees it, its density doubled: the mixture density of a
    draw believed to hold twice the proposed share (u / q weights only change by a constant,
    which normalisation removes)."""

    def __init__(self, proposal: LearnedProposal) -> None:
        self.proposal, self.uniform = proposal, proposal.uniform

    def density(self, poses: np.ndarray) -> np.ndarray:
        return 2.0 * self.proposal.density(poses)


def mixing_of(mode: str, proposal: LearnedProposal):
    if mode == "adaptive":  # w_slow all but held where run_kidnap sets it: the share follows
        # how far each update's likelihood falls below it
        return AdaptiveMixing(
            AdaptiveMixingParams(share=0.5, threshold=0.0, alpha_slow=1e-6, alpha_fast=0.5)
        )
    if mode == "gated":
        params = VerifiedGateParams(share=0.5, warmup=0, persistence=1)
        return VerifiedGateMixing(params, proposal, GateFromTheKidnap())  # type: ignore[arg-type]
    return ConstantMixing(ConstantMixingParams(share=0.5))


def run_kidnap(mode: str, seed: int, doubled: bool) -> tuple[list[np.ndarray], list[float]]:
    """The hybrid over the kidnap case: its histogram after each update, and its shares."""
    odometry, truth, scans = kidnap_case()
    hypotheses = hypotheses_from(lambda _: np.stack([truth[0], KIDNAP_TO]), 0.15)
    proposal = LearnedProposal(
        hypotheses, UniformProposal(GRID), LearnedProposalParams(uniform_share=0.5)
    )
    seen = ShareDoubled(proposal) if doubled else proposal
    weighting = ImportanceWeights(seen, ImportanceWeightParams(kidnap_probability=EPS))  # type: ignore[arg-type]
    mixing = SharesSeen(mixing_of(mode, proposal))
    # resampling: once, after the third update, then mixing on the resampled particles
    every_third = {"resample_interval": 3} if mode == "resampling" else {}
    config = ros(**(SENSOR | every_third), max_particles=PARTICLES, min_particles=PARTICLES)
    if mode == "prior_ignored":
        weighting = PriorIgnored(proposal, ImportanceWeightParams(kidnap_probability=EPS))
    pf = build_filter(
        GRID, SPEC, config, seed, proposal=proposal, weighting=weighting, mixing=mixing
    )
    if mode in ("global", "prior_ignored"):
        pf.initialize_global()  # the initial weights: u / q of the first scan's proposal
    else:
        pf.initialize_pose(INITIAL, INITIAL_COV)
    if mode == "adaptive":  # a robot that was better explained before this stretch: the
        # long-term average at twice the first scan's mean likelihood
        mixing.observe_likelihood(2.0 * float(pf.sensor_model(pf.poses, scans[0], False).mean()))
    updates = 1 if mode in ("global", "prior_ignored") else len(truth)
    histograms = []
    for step in range(updates):
        pf.update(odometry[step], scans[step])
        histograms.append(histogram(pf.poses, pf.weights))
    return histograms, mixing.shares


@pytest.fixture(scope="module")
def exact_kidnap() -> Callable[[str, Sequence[float]], list[np.ndarray]]:
    """The exact posterior's histograms after each update of the kidnap case, given the
    start and the shares the filter drew (ε at an update with a share, 0 without)."""
    odometry, _, scans = kidnap_case()
    pf = build_filter(GRID, SPEC, ros(**SENSOR))
    stencil = transition(pf.motion, odometry[0], odometry[1])  # every step's odometry is STEP
    flat = grid_poses().reshape(-1, 3)

    def posterior(start: str, shares: Sequence[float]) -> list[np.ndarray]:
        prior = "uniform" if start == "global" else "pose"
        epsilons = [EPS if share > 0 else 0.0 for share in shares]
        beliefs = bayes_filter(pf.sensor_model, [stencil] * KIDNAP_AT, scans, epsilons, prior)
        return [histogram(flat, b) for b in beliefs]

    return posterior


@pytest.mark.slow  # 16000 particles x 8 seeds x 1 update, twice
def test_the_initial_weights_give_the_exact_first_posterior(exact_kidnap) -> None:
    """A global start: particles from the proposal weighted u / q, then the first scan, is
    the uniform prior times the first likelihood; weights of 1 (the proposal taken for the
    prior) are not."""
    exact = exact_kidnap("global", [0.0])[0]
    distances = {}
    for mode in ("global", "prior_ignored"):
        runs = [run_kidnap(mode, seed, doubled=False)[0][0] for seed in range(8)]
        distances[mode] = total_variation(np.mean(runs, axis=0), exact)
    print("first update's total variation", {k: round(v, 3) for k, v in distances.items()})
    assert distances["global"] <= TV_BOUND < distances["prior_ignored"]


@pytest.mark.slow  # 16000 particles x 4 seeds x 5 updates, twice per mode: about 20 s a mode
@pytest.mark.parametrize("mode", ["constant", "adaptive", "gated", "resampling"])
def test_the_distribution_matches_the_exact_posterior_through_a_kidnap(
    mode: str, exact_kidnap
) -> None:
    runs = [run_kidnap(mode, seed, doubled=False) for seed in SEEDS]
    shares = runs[0][1]
    assert all(r[1] == pytest.approx(shares) for r in runs) or mode == "adaptive"
    assert shares[-1] > 0  # the kidnap's update draws from the proposal
    if mode == "gated":
        assert shares[: KIDNAP_AT - 2] == [0.0] * (KIDNAP_AT - 2)  # shut before the kidnap
    if mode == "adaptive":
        assert len({round(s, 3) for s in shares}) > 1  # the share follows the likelihood
    exact = exact_kidnap("pose", [0.0, *shares])
    mean = [np.mean([r[0][t] for r in runs], axis=0) for t in range(len(exact))]
    distances = [total_variation(m, e) for m, e in zip(mean, exact, strict=True)]
    print(mode, "total variation per update", np.round(distances, 3))
    assert max(distances) <= TV_BOUND, distances
    doubled = [run_kidnap(mode, seed, doubled=True) for seed in SEEDS]
    wrong = total_variation(np.mean([r[0][-1] for r in doubled], axis=0), exact[-1])
    print(mode, "share doubled: total variation at the kidnap", round(wrong, 3))
    assert wrong > TV_BOUND
