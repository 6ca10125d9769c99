"""Benchmark: the exact ray caster against the plain cell-by-cell traversal, same rays, same run.

Map: the paper's map 1 (STDR sparse_obstacles, 775 x 746 cells at 0.02 m) when
../shared/data/stdr_maps holds it, else a seeded sparse map of the same size from
scanloc.world.generator. Laser: 667 beams over ±120°, range 5.6 m. Poses: uniform over free
space with 0.2 m clearance. Both casters run compiled and parallel over poses on the same number
of threads (default 2); figures are medians over repeats after a warm-up (JIT compilation
excluded), the two casters timed alternately so that load from other processes hits both alike.
Also timed: casting the paper's whole 200k-scan dataset (in the chunks the dataset writer
uses; median of 3), the distance-transform fallback ("march") and STDR's caster. The JSON
records the machine's 1-minute load average: figures taken while other processes compete for
the cores are proportionally lower.

Run: python benchmarks/raycast.py [--quick] [--threads N]. The last line is a JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable
from pathlib import Path

import numba
import numpy as np

from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.sensor.raycast_reference import cast_reference
from scanloc.sensor.raycast_stdr import cast_stdr
from scanloc.world.free_space import sample_free_poses
from scanloc.world.occupancy_grid import OccupancyGrid

STDR_MAP = Path(__file__).resolve().parents[2] / "shared" / "data" / "stdr_maps"
DATASET_POSES = 200_000
CHUNK = 8192
CLEARANCE_M = 0.2


def load_benchmark_map() -> tuple[OccupancyGrid, str]:
    yaml_path = STDR_MAP / "sparse_obstacles.yaml"
    if yaml_path.is_file():
        from scanloc.world.map_server import load_map

        return load_map(yaml_path), "stdr sparse_obstacles"
    from scanloc.world.generator import generate_sparse
    from scanloc.world.geometry import rasterize

    return rasterize(generate_sparse(15.5, 14.92, 0.02, seed=0)), "generated sparse (775 x 746)"


def seconds(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def median_time(fn: Callable[[], object], repeats: int) -> float:
    return float(np.median([seconds(fn) for _ in range(repeats)]))


def compare(exact: np.ndarray, reference: np.ndarray) -> tuple[float, int]:
    """Largest |difference| where both hit something, and how many beams disagree on hitting."""
    hit = np.isfinite(reference)
    mismatches = int((np.isfinite(exact) != hit).sum())
    both = hit & np.isfinite(exact)
    diff = float(np.abs(exact[both] - reference[both]).max()) if both.any() else 0.0
    return diff, mismatches


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small smoke run")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--poses", type=int, default=None, help="poses per timed cast")
    parser.add_argument("--repeats", type=int, default=None)
    args = parser.parse_args()
    n_poses = args.poses or (200 if args.quick else 3000)
    repeats = args.repeats or (3 if args.quick else 7)
    threads = min(args.threads, numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(threads)

    grid, map_name = load_benchmark_map()
    spec = LaserSpec()
    angles = spec.beam_angles()
    print(f"map: {map_name}, {grid.width} x {grid.height} cells at {grid.resolution} m")
    start = time.perf_counter()
    cast_map = CastMap.from_grid(grid)
    prepare_s = time.perf_counter() - start
    print(f"prepared in {prepare_s:.3f} s: method {cast_map.method}, {len(cast_map.boxes)} boxes")
    poses = sample_free_poses(grid, n_poses, CLEARANCE_M, np.random.default_rng(0), map_name)
    rays = n_poses * spec.num_beams

    def run_exact() -> np.ndarray:
        return cast_exact(cast_map, poses, angles, spec.range_max)

    def run_reference() -> np.ndarray:
        return cast_reference(grid, poses, angles, spec.range_max)

    max_diff, mismatches = compare(run_exact(), run_reference())  # also the warm-up
    print(
        f"{rays} rays on {threads} thread(s): max |exact - reference| = {max_diff:.3g} m, "
        f"{mismatches} hit/no-hit mismatches"
    )
    exact_times, reference_times = [], []
    for _ in range(repeats):
        exact_times.append(seconds(run_exact))
        reference_times.append(seconds(run_reference))
    rays_per_s = rays / float(np.median(exact_times))
    reference_rays_per_s = rays / float(np.median(reference_times))
    print(
        f"exact ({cast_map.method}): {rays_per_s / 1e6:.2f} M rays/s, "
        f"reference: {reference_rays_per_s / 1e6:.2f} M rays/s"
    )

    march = CastMap.from_grid(grid, method="march")
    cast_exact(march, poses[:10], angles, spec.range_max)
    march_rays_per_s = rays / median_time(
        lambda: cast_exact(march, poses, angles, spec.range_max), repeats
    )
    cast_stdr(grid, poses[:10], spec)
    stdr_rays_per_s = rays / median_time(lambda: cast_stdr(grid, poses, spec), repeats)
    print(
        f"march fallback: {march_rays_per_s / 1e6:.2f} M rays/s, "
        f"stdr: {stdr_rays_per_s / 1e6:.2f} M rays/s"
    )

    dataset_poses = 4 * CHUNK if args.quick else DATASET_POSES
    big = sample_free_poses(grid, dataset_poses, CLEARANCE_M, np.random.default_rng(1), map_name)
    chunks = range(0, dataset_poses, CHUNK)
    dataset_cast_s = median_time(
        lambda: [
            cast_exact(cast_map, big[lo : lo + CHUNK], angles, spec.range_max) for lo in chunks
        ],
        1 if args.quick else 3,
    )
    dataset_cast_s *= DATASET_POSES / dataset_poses
    extrapolated = dataset_poses != DATASET_POSES
    print(
        f"casting {DATASET_POSES} x {spec.num_beams} rays: {dataset_cast_s:.2f} s"
        + (f" (extrapolated from {dataset_poses} poses)" if extrapolated else "")
    )

    print(
        json.dumps(
            {
                "rays_per_s": round(rays_per_s),
                "reference_rays_per_s": round(reference_rays_per_s),
                "speedup": round(rays_per_s / reference_rays_per_s, 2),
                "max_abs_diff_m": max_diff,
                "no_hit_mismatches": mismatches,
                "dataset_200k_cast_s": round(dataset_cast_s, 3),
                "dataset_200k_extrapolated": extrapolated,
                "march_rays_per_s": round(march_rays_per_s),
                "stdr_rays_per_s": round(stdr_rays_per_s),
                "method": cast_map.method,
                "boxes": len(cast_map.boxes),
                "prepare_s": round(prepare_s, 4),
                "threads": threads,
                "poses": n_poses,
                "beams": spec.num_beams,
                "repeats": repeats,
                "map": map_name,
                "quick": args.quick,
                "load_avg_1m": os.getloadavg()[0],  # competing processes lower the figures
            }
        )
    )


if __name__ == "__main__":
    main()
