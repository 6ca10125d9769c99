"""Benchmark: one full amcl filter update (motion, sensor model, resampling, clusters) per model.

For each laser model (likelihood_field, likelihood_field_prob, beam): fixed particle counts (KLD
off: min_particles = max_particles) of 1k, 5k and 10k, 60 beams asked for (each model's own
beam rule picks 56-61 of 667), an update and a resampling on every scan. The compiled filter
(`scanloc.localize.mcl.filter.ParticleFilter.update`) runs against a plain numpy version of the
same math in the same process: the likelihood fields vectorised, the beam model with an exact
ray cast per particle and beam (what amcl does, through scanloc's exact caster) instead of the
range table.

Threads: the compiled filter uses numba's threads (2 here); it is also timed on 1 thread. The
numpy reference runs numpy's element-wise operations, which use one thread; its ray casts
(beam model) use numba's threads. Figures are medians over repeats, after warm-up (JIT
compilation excluded).

Map: the paper's map 1 (STDR sparse_obstacles, 0.02 m) when ../shared/data/stdr_maps holds it,
else a 15 m x 15 m room drawn here. Run: python benchmarks/amcl.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import fields
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numba
import numpy as np
from scipy import ndimage

from scanloc.localize.beam_model import exit_distance, select_beams_beam_model
from scanloc.localize.clustering import BIN_THETA, BIN_XY
from scanloc.localize.likelihood_field import distance_map, select_beams
from scanloc.localize.likelihood_field_prob import select_beams_prob
from scanloc.localize.mcl.config import MclConfig, build_filter
from scanloc.localize.mcl.motion import OdometryParams, decompose, noise_sigmas
from scanloc.localize.mcl.sensor_models import BeamParams, LikelihoodFieldProbParams
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.trajectory.drive import drive_trajectory
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid

STDR_MAP = Path(__file__).resolve().parents[2] / "shared" / "data" / "stdr_maps"
MAX_BEAMS = 60
MODELS = ("likelihood_field", "likelihood_field_prob", "beam")
SIZES = (1000, 5000, 10000)


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


# ROS 1's defaults of the laser and odometry keys the numpy reference reads
REFERENCE_DEFAULTS = {
    f.name: f.default
    for part in (OdometryParams, LikelihoodFieldProbParams, BeamParams)
    for f in fields(part)
}


def params_for(model: str, n: int) -> dict[str, Any]:
    """ROS-named parameters: `n` particles (KLD off), an update and a resampling per scan."""
    return {
        "min_particles": n,
        "max_particles": n,
        "laser_model_type": model,
        "laser_max_beams": MAX_BEAMS,
        "resample_interval": 1,
        "update_min_d": 0.0,
        "update_min_a": 0.0,
    }


def compiled_filter(grid: OccupancyGrid, spec: LaserSpec, params: dict[str, Any]):
    return build_filter(grid, spec, MclConfig.from_ros(params, where="benchmark"), seed=0)


def median_update_s(
    filter_, odom, ranges, repeats: int, per_repeat: int, n_particles: int | None = None
) -> float:
    """Median seconds per update of an initialised filter (amcl or the hybrid), after a first
    update and 3 of warm-up (compiled code is cached, but let caches settle); every timed
    update must be a filter update, with `n_particles` particles where given."""
    filter_.update(odom[0], ranges[0])
    for k in range(1, 4):
        filter_.update(odom[k], ranges[k])
    times, k = [], 4
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(per_repeat):
            est = filter_.update(odom[k % len(odom)], ranges[k % len(odom)])
            assert est.updated and n_particles in (None, est.n_particles)
            k += 1
        times.append((time.perf_counter() - start) / per_repeat)
    return float(np.median(times))


def time_filter(grid, spec, odom, ranges, model: str, n: int, repeats: int, per_repeat: int):
    """Median seconds per update of the compiled filter with `n` particles (KLD off)."""
    amcl = compiled_filter(grid, spec, params_for(model, n))
    amcl.initialize_pose(odom[0])
    return median_update_s(amcl, odom, ranges, repeats, per_repeat, n_particles=n)


class Reference:
    """The same filter update in plain numpy (and scipy's labelling for the clusters)."""

    def __init__(self, grid: OccupancyGrid, spec: LaserSpec, params: dict[str, Any]) -> None:
        self.grid, self.spec = grid, spec
        self.p = p = SimpleNamespace(**(REFERENCE_DEFAULTS | params))
        self.dist = distance_map(grid, p.laser_likelihood_max_dist)
        self.angles = spec.beam_angles()
        self.rng = np.random.default_rng(0)
        self.cast_map = CastMap.from_grid(grid, unknown_blocks=True)

    def _end_point_distances(self, poses, r, b) -> np.ndarray:
        g = self.grid
        hx = poses[:, :1] + r * np.cos(poses[:, 2:] + b)
        hy = poses[:, 1:2] + r * np.sin(poses[:, 2:] + b)
        col = np.floor((hx - g.origin[0]) / g.resolution).astype(np.int64)
        row = np.floor((hy - g.origin[1]) / g.resolution).astype(np.int64)
        inside = (col >= 0) & (col < g.width) & (row >= 0) & (row < g.height)
        return np.where(
            inside,
            self.dist[np.clip(row, 0, g.height - 1), np.clip(col, 0, g.width - 1)],
            self.p.laser_likelihood_max_dist,
        )

    def weights(self, poses: np.ndarray, ranges: np.ndarray) -> np.ndarray:
        p, spec = self.p, self.spec
        rmin, rmax = spec.range_min, spec.range_max
        hit = p.laser_z_hit
        rand = p.laser_z_rand / rmax
        two_var = 2 * p.laser_sigma_hit**2
        if p.laser_model_type == "likelihood_field":
            r, b = select_beams(ranges, self.angles, rmin, rmax, MAX_BEAMS)
            z = self._end_point_distances(poses, r, b)
            return 1.0 + ((hit * np.exp(-(z * z) / two_var) + rand) ** 3).sum(axis=1)
        if p.laser_model_type == "likelihood_field_prob":
            r, b = select_beams_prob(ranges, self.angles, rmin, rmax, MAX_BEAMS)
            z = self._end_point_distances(poses, r, b)
            return np.exp(np.log(hit * np.exp(-(z * z) / two_var) + rand).sum(axis=1))
        obs, b = select_beams_beam_model(ranges, self.angles, rmin, rmax, MAX_BEAMS)
        expected = self.map_ranges(poses, b)
        z = obs - expected
        pz = hit * np.exp(-(z * z) / two_var)
        pz += np.where(z < 0, p.laser_z_short * p.laser_lambda_short, 0.0) * np.exp(
            -p.laser_lambda_short * obs
        )
        pz += np.where(obs == rmax, p.laser_z_max, 0.0) + np.where(obs < rmax, rand, 0.0)
        return 1.0 + (pz**3).sum(axis=1)

    def map_ranges(self, poses: np.ndarray, bearings: np.ndarray) -> np.ndarray:
        """Exact ranges per particle and beam (0 from a blocked cell, the map's border counts as
        a hit), as amcl's per-ray map_calc_range."""
        g, rmax = self.grid, self.spec.range_max
        col, row = g.world_to_cell(poses[:, 0], poses[:, 1])
        inside = (col >= 0) & (col < g.width) & (row >= 0) & (row < g.height)
        ok = inside.copy()
        ok[inside] = g.free[row[inside], col[inside]]
        out = np.zeros((len(poses), len(bearings)))
        if ok.any():
            hit = cast_exact(self.cast_map, poses[ok], bearings, rmax)
            w, h = g.size_m
            box = (g.origin[0], g.origin[1], g.origin[0] + w, g.origin[1] + h)
            leave = exit_distance(
                poses[ok, :1], poses[ok, 1:2], poses[ok, 2:3] + bearings[None, :], box
            )
            out[ok] = np.where(np.isfinite(hit), hit, np.minimum(leave, rmax))
        return out

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


def time_reference(grid, spec, odom, ranges, model, n: int, repeats: int, per_repeat: int):
    ref = Reference(grid, spec, params_for(model, n))
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


def agreement(grid, spec, odom, ranges, model: str) -> tuple[float, float]:
    """Max and median relative difference of the compiled and the numpy model's weights at 2000
    particles around the start (the beam model's range table quantises; the others are exact)."""
    amcl = compiled_filter(grid, spec, params_for(model, 2000))
    amcl.initialize_pose(odom[0])
    fast = amcl.sensor_model(amcl.poses, ranges[0], False)
    slow = Reference(grid, spec, params_for(model, 2000)).weights(amcl.poses, ranges[0])
    rel = np.abs(fast - slow) / np.abs(slow)
    return float(rel.max()), float(np.median(rel))


def benchmark_drive() -> tuple[OccupancyGrid, str, LaserSpec, np.ndarray, np.ndarray]:
    """The map, its name, the sensor, noise-free scans and odometry of a 200-step drive."""
    grid, map_name = load_benchmark_map()
    spec = LaserSpec()
    traj = drive_trajectory(grid, 200, seed=0)
    exact = cast_exact(CastMap.from_grid(grid), traj.truth, spec.beam_angles(), spec.range_max)
    ranges = np.where(np.isfinite(exact), exact, spec.no_return_value).astype(np.float32)
    return grid, map_name, spec, ranges, traj.odometry


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a fast smoke run")
    args = parser.parse_args()
    repeats, per_repeat = (2, 2) if args.quick else (7, 15)
    grid, map_name, spec, ranges, odom = benchmark_drive()
    threads = numba.get_num_threads()
    print(f"map: {map_name}; numba threads: {threads}; reference: numpy on 1 thread")
    figures: dict[str, object] = {"map": map_name, "threads": threads, "quick": args.quick}
    for model in MODELS:
        for n in SIZES:
            sec = time_filter(grid, spec, odom, ranges, model, n, repeats, per_repeat)
            figures[f"{model}_hz_{n // 1000}k"] = round(1.0 / sec, 1)
            print(
                f"{model:>22} compiled, {n:>5} particles: {sec * 1e3:7.2f} ms = {1 / sec:7.1f} Hz"
            )
        numba.set_num_threads(1)
        one = time_filter(grid, spec, odom, ranges, model, 10000, repeats, per_repeat)
        numba.set_num_threads(threads)
        figures[f"{model}_hz_10k_1thread"] = round(1.0 / one, 1)
        ref = time_reference(
            grid, spec, odom, ranges, model, 10000, max(2, repeats // 2), max(1, per_repeat // 5)
        )
        figures[f"{model}_reference_hz_10k"] = round(1.0 / ref, 1)
        figures[f"{model}_speedup_10k"] = round(ref / (1.0 / figures[f"{model}_hz_10k"]), 1)
        worst, median = agreement(grid, spec, odom, ranges, model)
        figures[f"{model}_weights_max_rel_diff"] = worst
        figures[f"{model}_weights_median_rel_diff"] = median
        print(
            f"{model:>22} 10k on 1 thread {1 / one:7.1f} Hz; numpy reference {1 / ref:7.1f} Hz; "
            f"weights differ by {worst:.2e} at most, {median:.2e} median"
        )
    # The previous figures' names, for the likelihood field (ROS 1's default model).
    figures["hz_10k"] = figures["likelihood_field_hz_10k"]
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
