"""Benchmark: one full amcl filter update (motion, likelihood field, resampling, clusters).

Fixed particle counts (KLD off: min_particles = max_particles) of 1k, 5k and 10k, 60 beams asked
for (amcl's integer step makes that 61 of 667), an update and a resampling on every scan. The
compiled filter (`scanloc.localize.amcl.Amcl.update`) runs against a plain vectorised numpy
version of the same math in the same process. Figures are medians over repeats, after warm-up
(JIT compilation excluded).

Map: the paper's map 1 (STDR sparse_obstacles, 0.02 m) when ../shared/data/stdr_maps holds it,
else a 15 m x 15 m room drawn here. Run: python benchmarks/amcl.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numba
import numpy as np
from scipy import ndimage

from scanloc.localize.amcl import BIN_THETA, BIN_XY, Amcl, AmclParams
from scanloc.localize.likelihood_field import beam_weights, distance_map, select_beams
from scanloc.localize.motion_model import decompose, noise_sigmas
from scanloc.localize.trajectory import drive_trajectory
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid

STDR_MAP = Path(__file__).resolve().parents[2] / "shared" / "data" / "stdr_maps"
MAX_BEAMS = 60


def load_benchmark_map() -> tuple[OccupancyGrid, str]:
    yaml_path = STDR_MAP / "sparse_obstacles.yaml"
    if yaml_path.is_file():
        from scanloc.world.map_server import load_map

        return load_map(yaml_path), "stdr sparse_obstacles (0.02 m)"
    res = 0.02
    cells = np.zeros((750, 750), dtype=np.int8)
    cells[:6], cells[-6:], cells[:, :6], cells[:, -6:] = OCCUPIED, OCCUPIED, OCCUPIED, OCCUPIED
    cells[200:205, 100:400] = OCCUPIED
    cells[350:600, 500:505] = OCCUPIED
    cells[500:550, 150:250] = OCCUPIED
    return OccupancyGrid(cells, res), "synthetic room (0.02 m)"


def params_for(n: int) -> AmclParams:
    return AmclParams(
        min_particles=n,
        max_particles=n,
        laser_max_beams=MAX_BEAMS,
        resample_interval=1,
        update_min_d=0.0,
        update_min_a=0.0,
    )


def time_filter(grid, spec, odom, ranges, n: int, repeats: int, per_repeat: int) -> float:
    """Median seconds per update of the compiled filter."""
    amcl = Amcl(grid, spec, params_for(n), seed=0)
    amcl.initialize_pose(odom[0])
    amcl.update(odom[0], ranges[0])
    for k in range(1, 4):  # warm-up (compiled code is cached, but let caches settle)
        amcl.update(odom[k], ranges[k])
    times, k = [], 4
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(per_repeat):
            est = amcl.update(odom[k % len(odom)], ranges[k % len(odom)])
            assert est.updated and est.n_particles == n
            k += 1
        times.append((time.perf_counter() - start) / per_repeat)
    return float(np.median(times))


class Reference:
    """The same filter update in plain numpy (and scipy's labelling for the clusters)."""

    def __init__(self, grid: OccupancyGrid, spec: LaserSpec, params: AmclParams) -> None:
        self.grid, self.spec, self.p = grid, spec, params
        self.dist = distance_map(grid, params.laser_likelihood_max_dist)
        self.angles = spec.beam_angles()
        self.rng = np.random.default_rng(0)

    def weights(self, poses: np.ndarray, ranges: np.ndarray) -> np.ndarray:
        p, g = self.p, self.grid
        r, b = select_beams(
            ranges, self.angles, self.spec.range_min, self.spec.range_max, MAX_BEAMS
        )
        hx = poses[:, :1] + r * np.cos(poses[:, 2:] + b)
        hy = poses[:, 1:2] + r * np.sin(poses[:, 2:] + b)
        col = np.floor((hx - g.origin[0]) / g.resolution).astype(np.int64)
        row = np.floor((hy - g.origin[1]) / g.resolution).astype(np.int64)
        inside = (col >= 0) & (col < g.width) & (row >= 0) & (row < g.height)
        z = np.where(
            inside,
            self.dist[np.clip(row, 0, g.height - 1), np.clip(col, 0, g.width - 1)],
            p.laser_likelihood_max_dist,
        )
        pz = p.laser_z_hit * np.exp(-(z * z) / (2 * p.laser_sigma_hit**2)) + (
            p.laser_z_rand / self.spec.range_max
        )
        return 1.0 + (pz**3).sum(axis=1)

    def update(self, poses, weights, old_odom, new_odom, ranges):
        p, n = self.p, len(poses)
        rot1, trans, rot2 = decompose(old_odom, new_odom)
        sd = noise_sigmas(
            p.odom_model_type,
            (p.odom_alpha1, p.odom_alpha2, p.odom_alpha3, p.odom_alpha4),
            old_odom,
            new_odom,
        )
        z = self.rng.standard_normal((n, 3))
        r1 = np.angle(np.exp(1j * (rot1 - sd[0] * z[:, 0])))
        tr = trans - sd[1] * z[:, 1]
        r2 = np.angle(np.exp(1j * (rot2 - sd[2] * z[:, 2])))
        poses = poses.copy()
        poses[:, 0] += tr * np.cos(poses[:, 2] + r1)
        poses[:, 1] += tr * np.sin(poses[:, 2] + r1)
        poses[:, 2] = np.angle(np.exp(1j * (poses[:, 2] + r1 + r2)))
        weights = weights * self.weights(poses, ranges)
        weights /= weights.sum()
        cum = np.concatenate([[0.0], np.cumsum(weights)])
        pick = np.clip(np.searchsorted(cum, self.rng.random(n), side="right") - 1, 0, n - 1)
        poses = poses[pick]
        weights = np.full(n, 1.0 / n)
        return poses, weights, self.cluster_mean(poses, weights)

    @staticmethod
    def cluster_mean(poses: np.ndarray, weights: np.ndarray) -> np.ndarray:
        kx = np.floor(poses[:, 0] / BIN_XY).astype(np.int64)
        ky = np.floor(poses[:, 1] / BIN_XY).astype(np.int64)
        nt = round(2 * math.pi / BIN_THETA)
        kt = np.floor((poses[:, 2] + math.pi) / BIN_THETA).astype(np.int64) % nt
        kx, ky = kx - kx.min() + 1, ky - ky.min() + 1
        hist = np.zeros((kx.max() + 2, ky.max() + 2, nt + 2), dtype=bool)
        hist[kx, ky, kt + 1] = True
        hist[..., 0], hist[..., -1] = hist[..., -2], hist[..., 1]  # wrap the heading
        labels, count = ndimage.label(hist, structure=np.ones((3, 3, 3)))
        parent = np.arange(count + 1)

        def root(a: int) -> int:
            while parent[a] != a:
                a = parent[a]
            return a

        for ends in ((0, -2), (-1, 1)):
            for a, b in {
                (int(a), int(b))
                for a, b in zip(
                    labels[..., ends[0]].ravel(), labels[..., ends[1]].ravel(), strict=True
                )
                if a and b
            }:
                parent[root(a)] = root(b)
        lab = np.array([root(int(a)) for a in labels[kx, ky, kt + 1]])
        best = np.argmax(np.bincount(lab, weights=weights))
        w = weights[lab == best]
        sel = poses[lab == best]
        return np.array(
            [
                np.average(sel[:, 0], weights=w),
                np.average(sel[:, 1], weights=w),
                math.atan2((w * np.sin(sel[:, 2])).sum(), (w * np.cos(sel[:, 2])).sum()),
            ]
        )


def time_reference(grid, spec, odom, ranges, n: int, repeats: int, per_repeat: int) -> float:
    ref = Reference(grid, spec, params_for(n))
    poses = odom[0] + np.random.default_rng(1).normal(0, [0.3, 0.3, 0.2], (n, 3))
    weights = np.full(n, 1.0 / n)
    poses, weights, _ = ref.update(poses, weights, odom[0], odom[1], ranges[1])  # warm-up
    times, k = [], 2
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(per_repeat):
            j = k % (len(odom) - 1) + 1
            poses, weights, _ = ref.update(poses, weights, odom[j - 1], odom[j], ranges[j])
            k += 1
        times.append((time.perf_counter() - start) / per_repeat)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a fast smoke run")
    args = parser.parse_args()
    repeats, per_repeat = (2, 3) if args.quick else (7, 20)
    grid, map_name = load_benchmark_map()
    spec = LaserSpec()
    traj = drive_trajectory(grid, 200, seed=0)
    exact = cast_exact(CastMap.from_grid(grid), traj.truth, spec.beam_angles(), spec.range_max)
    ranges = np.where(np.isfinite(exact), exact, spec.no_return_value).astype(np.float32)
    odom = traj.odometry
    beams = len(
        select_beams(
            ranges[0].astype(float), spec.beam_angles(), spec.range_min, spec.range_max, MAX_BEAMS
        )[0]
    )
    print(
        f"map: {map_name}; numba threads: {numba.get_num_threads()}; beams used at step 0: {beams}"
    )

    hz = {}
    for n in (1000, 5000, 10000):
        sec = time_filter(grid, spec, odom, ranges, n, repeats, per_repeat)
        hz[n] = 1.0 / sec
        print(f"compiled filter, {n:>5} particles: {sec * 1e3:7.3f} ms/update = {hz[n]:8.1f} Hz")
    ref_sec = time_reference(
        grid, spec, odom, ranges, 10000, max(2, repeats // 2), max(2, per_repeat // 4)
    )
    print(
        f"numpy reference, 10000 particles: {ref_sec * 1e3:7.3f} ms/update = {1 / ref_sec:8.1f} Hz"
    )

    # The sensor model alone, and agreement of the two implementations on it.
    amcl = Amcl(grid, spec, params_for(10000), seed=0)
    amcl.initialize_pose(odom[0])
    r, b = select_beams(
        ranges[0].astype(float), spec.beam_angles(), spec.range_min, spec.range_max, MAX_BEAMS
    )
    beam_weights(amcl.field, amcl.poses, r, b)
    t = []
    for _ in range(repeats * 3):
        start = time.perf_counter()
        fast = beam_weights(amcl.field, amcl.poses, r, b)
        t.append(time.perf_counter() - start)
    slow = Reference(grid, spec, params_for(10000)).weights(amcl.poses, ranges[0].astype(float))
    rel = float(np.max(np.abs(fast - slow) / slow))
    beam_rate = len(amcl.poses) * len(r) / float(np.median(t))
    print(
        f"likelihood field alone: {beam_rate / 1e6:.1f} M beam evaluations/s; "
        f"max relative difference to numpy: {rel:.2e}"
    )
    print(
        json.dumps(
            {
                "hz_1k": round(hz[1000], 1),
                "hz_5k": round(hz[5000], 1),
                "hz_10k": round(hz[10000], 1),
                "reference_hz_10k": round(1 / ref_sec, 1),
                "speedup_10k": round(hz[10000] * ref_sec, 1),
                "beam_evals_per_s": round(beam_rate),
                "beams": beams,
                "threads": numba.get_num_threads(),
                "weights_max_rel_diff": rel,
                "map": map_name,
                "quick": args.quick,
            }
        )
    )


if __name__ == "__main__":
    main()
