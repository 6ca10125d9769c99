"""Benchmark: single-scan global localization by branch and bound, against the exhaustive
search it must equal and the learned model it can be guided by, in one run.

Per site, on `--scans` scans spread evenly over a run (each scan alone, no odometry):
- `bnb`: the branch-and-bound search over the whole map (localize/branch_and_bound.py), its
  best pose;
- `scanlocnet_bnb`: the same search ordered by ScanLocNet's hypotheses (same answer, fewer
  blocks scored: checked here on every scan);
- `scanlocnet`: the network alone, its best hypothesis (where the site has a trained model).
Each: success (within 0.5 m and 10 deg of the truth), median position error, ms per scan
(median) and blocks scored per scan (the search's). Sites: the pipeline's map-1 drive, intel's
and fr079's held-out real runs (their data, models and maps from `dvc repro`; a site whose
outputs are absent is skipped), and a generated 50 x 25 m rooms map with noise-free scans
simulated at random free poses (the search only: it has no trained model).
The plain reference, in the same run: the exhaustive correlative search (every heading at every
free cell, numba) on the 6 x 5 m test room, against the branch and bound on the same scans:
the same best score on every scan, and the time of each.

Run: python benchmarks/global_search.py [--scans 20] [--quick]
Last line: JSON: per site and method success, median_err_m, ms_per_scan, nodes_per_scan; and
`reference` (exhaustive_ms, bnb_ms, speedup, equal).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from conftest import small_map  # noqa: E402  (the test room, the reference's map)
from scanloc.localize.branch_and_bound import (  # noqa: E402
    GlobalSearch,
    SearchParams,
    brute_force,
    end_points,
    heading_step,
    point_offsets,
)
from scanloc.localize.learned_localizer import scan_hypotheses  # noqa: E402
from scanloc.pose import compose, inverse  # noqa: E402
from scanloc.sensor.laser import LaserSpec  # noqa: E402
from scanloc.sensor.simulate import laser_spec_from_config, simulate_scans  # noqa: E402
from scanloc.stages.localize import laser_mount  # noqa: E402
from scanloc.trajectory.format import load_trajectory  # noqa: E402
from scanloc.world.build import build_map  # noqa: E402
from scanloc.world.free_space import sample_free_poses  # noqa: E402
from scanloc.world.map_server import load_map  # noqa: E402

SITES = {"sparse_obstacles": "drive", "intel": "real", "fr079": "real"}
PARAMS = SearchParams()  # conf/localizer/bnb.yaml's `search` section: the defaults


def right(poses: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    err = np.hypot(*(poses[:, :2] - truth[:, :2]).T)
    turned = np.abs((poses[:, 2] - truth[:, 2] + math.pi) % (2 * math.pi) - math.pi)
    return (err < 0.5) & (turned < math.radians(10)), err


def figures(poses: np.ndarray, truth: np.ndarray, ms: list[float], nodes: list[int]) -> dict:
    ok, err = right(poses, truth)
    out = {
        "success": round(float(ok.mean()), 4),
        "median_err_m": round(float(np.median(err)), 4),
        "ms_per_scan": round(float(np.median(ms)), 2),
    }
    if nodes:
        out["nodes_per_scan"] = int(np.median(nodes))
    return out


def site_rows(grid, spec: LaserSpec, mount, ranges, truth, model: Path | None) -> dict:
    """The three methods on the scans (laser poses turned into base poses with the mount)."""
    search, angles = GlobalSearch(grid, PARAMS), spec.beam_angles()
    unmount = inverse(np.asarray(mount, dtype=np.float64))
    guide_of = scan_hypotheses(model, ranges)[1] if model is not None else None
    rows: dict[str, tuple[list, list, list]] = {m: ([], [], []) for m in ("bnb", "guided", "net")}
    for scan in ranges:
        valid = (scan >= spec.range_min) & (scan < spec.range_max)
        points = end_points(np.asarray(scan, dtype=np.float64), angles, valid, PARAMS)
        tick = time.perf_counter()
        plain = search.search(points)
        rows["bnb"][0].append(compose(plain.pose, unmount))
        rows["bnb"][1].append(1e3 * (time.perf_counter() - tick))
        rows["bnb"][2].append(plain.nodes)
        if guide_of is None:
            continue
        tick = time.perf_counter()
        hypotheses = guide_of(scan).poses[0]
        net_ms = 1e3 * (time.perf_counter() - tick)
        guided = search.search(points, guide=hypotheses)
        if guided.score != plain.score:
            raise AssertionError(f"guided search {guided.score} != full search {plain.score}")
        rows["guided"][0].append(compose(guided.pose, unmount))
        rows["guided"][1].append(1e3 * (time.perf_counter() - tick))
        rows["guided"][2].append(guided.nodes)
        rows["net"][0].append(compose(hypotheses[0], unmount))
        rows["net"][1].append(net_ms)
    names = {"bnb": "bnb", "guided": "scanlocnet_bnb", "net": "scanlocnet"}
    return {
        names[m]: figures(np.array(p), truth, ms, nodes) for m, (p, ms, nodes) in rows.items() if p
    }


def pipeline_site(site: str, run: str, scans: int) -> dict | None:
    run_dir = ROOT / "data/trajectories" / f"{site}_{run}"
    map_yaml = ROOT / "data/maps" / site / "map.yaml"
    if not (run_dir / "meta.json").is_file() or not map_yaml.is_file():
        return None
    traj, ranges = load_trajectory(run_dir)
    spec = laser_spec_from_config(json.loads((run_dir / "meta.json").read_text())["sensor"])
    pick = np.linspace(0, len(traj.times) - 1, scans).round().astype(int)
    model = ROOT / "models/scanlocnet" / site / "model.pt"
    rows = site_rows(
        load_map(map_yaml),
        spec,
        laser_mount(run_dir),
        np.asarray(ranges)[pick],
        traj.truth[pick],
        model if model.is_file() else None,
    )
    return {"run": f"{site}_{run}", "scans": scans, **rows}


def generated_site(scans: int) -> dict:
    cfg = yaml.safe_load((ROOT / "conf/map/generated_rooms.yaml").read_text())
    grid = build_map(cfg | {"width": 50.0, "height": 25.0, "seed": 2})
    spec = LaserSpec()
    poses = sample_free_poses(grid, scans, 0.3, np.random.default_rng(0))
    ranges = simulate_scans(grid, spec, poses, None, rng_seed=1)
    return {"run": "generated 50 x 25 m rooms", "scans": scans,
            **site_rows(grid, spec, (0.0, 0.0, 0.0), ranges, poses, None)}  # fmt: skip


def reference(scans: int) -> dict:
    """The exhaustive search against branch and bound on the test room's scans."""
    grid, spec = small_map(), LaserSpec()
    params = SearchParams(depth=4, max_points=PARAMS.max_points, sigma=PARAMS.sigma)
    search = GlobalSearch(grid, params)
    poses = sample_free_poses(grid, scans, 0.3, np.random.default_rng(1))
    ranges = simulate_scans(grid, spec, poses, None, rng_seed=2)
    exhaustive_ms, bnb_ms, equal = [], [], True
    for scan in ranges:
        points = end_points(scan, spec.beam_angles(), scan < spec.range_max, params)
        n = math.ceil(2 * math.pi / heading_step(points, grid.resolution))
        offsets = point_offsets(points, np.arange(n) * (2 * math.pi / n), grid.resolution)
        tick = time.perf_counter()
        best = brute_force(search.grids, offsets)[0]
        exhaustive_ms.append(1e3 * (time.perf_counter() - tick))
        tick = time.perf_counter()
        found = search.search(points)
        bnb_ms.append(1e3 * (time.perf_counter() - tick))
        equal &= found is not None and abs(found.score - best) < 1e-12
    return {
        "map": "test room 6 x 5 m at 0.05 m",
        "scans": scans,
        "exhaustive_ms": round(float(np.median(exhaustive_ms)), 1),
        "bnb_ms": round(float(np.median(bnb_ms)), 2),
        "speedup": round(float(np.median(exhaustive_ms) / np.median(bnb_ms)), 1),
        "equal": bool(equal),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=20)
    parser.add_argument("--quick", action="store_true", help="3 scans, the reference only + map 1")
    args = parser.parse_args()
    scans = 3 if args.quick else args.scans
    reference(1)  # compile the kernels before anything is timed
    out: dict = {"reference": reference(scans)}
    print(json.dumps(out["reference"]))
    for site, run in SITES.items():
        if args.quick and site != "sparse_obstacles":
            continue
        found = pipeline_site(site, run, scans)
        if found is None:
            print(f"{site}: no pipeline outputs (run `dvc repro`): skipped")
            continue
        out[site] = found
        print(json.dumps(found))
    if not args.quick:
        out["generated"] = generated_site(scans)
        print(json.dumps(out["generated"]))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
