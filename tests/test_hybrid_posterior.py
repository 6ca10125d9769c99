"""The hybrid's importance weights against the exact posterior: a brute-force Bayes filter on a
fine grid of poses of a small room, with the same motion model (its transition histogrammed
from many draws), the same sensor model (evaluated at every grid pose) and the same prediction
bel⁻ = (1 - ε) b + ε u. The filter's weighted particles, carried over several updates without
resampling while a proposal adds particles near the truth and its mirror twin, must have the
posterior's moments and twin mass within a Monte-Carlo tolerance (over 4 seeds the filter's
figures spread by sd <= 0.011). Measured: exact mean x 1.766 m, twin mass 0.054; this
weighting 1.754 m, 0.050; the previous one (weights overwritten, shares (1 - φ, φ), motion
density histogrammed in 0.5 m x 0.5 m x 10° bins) 1.657 m, 0.274, which fails."""

from __future__ import annotations

import numpy as np
import pytest

from scanloc.localize.hybrid import (
    ConstantMixing,
    ConstantMixingParams,
    ImportanceWeightParams,
    ImportanceWeights,
    LearnedProposal,
    LearnedProposalParams,
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


def drive() -> tuple[np.ndarray, np.ndarray]:
    """Truth = odometry (a clean drive from INITIAL) and its scans."""
    poses = [INITIAL]
    for _ in range(UPDATES):
        x, y, th = poses[-1]
        c, s = np.cos(th), np.sin(th)
        poses.append(np.array([x + c * STEP[0], y + s * STEP[0], wrap_angle(th + STEP[2])]))
    truth = np.array(poses)
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


def exact_posterior(sensor, motion, truth: np.ndarray, scans: np.ndarray) -> np.ndarray:
    """The Bayes filter on the grid: the normalised posterior (H, R, C) after every scan."""
    states = grid_poses()
    flat = states.reshape(-1, 3)
    d = flat - INITIAL
    d[:, 2] = wrap_angle(d[:, 2])
    bel = np.exp(-0.5 * np.einsum("ni,ij,nj->n", d, np.linalg.inv(INITIAL_COV), d))
    free = GRID.free[None].repeat(HEADINGS, 0).reshape(-1)
    uniform = free / free.sum()
    bel = bel * sensor(flat, scans[0], False)
    bel /= bel.sum()
    for t in range(1, len(truth)):
        cube = bel.reshape(states.shape[:3])
        pred = np.zeros_like(cube)
        for h, stencil in enumerate(transition(motion, truth[t - 1], truth[t])):
            for dc, dr, target, p in stencil:
                pred[target] += p * shifted(cube[h], dr, dc)
        pred = (1 - EPS) * pred.reshape(-1) / pred.sum() + EPS * uniform
        bel = pred * sensor(flat, scans[t], False)
        bel /= bel.sum()
    return bel


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
