"""Benchmark: one full hybrid update (scanloc.localize.hybrid) against plain amcl, same run.

A hybrid update is everything the filter does for one scan: the learned localizer's network
and top-K decoding for the scan, sampling the proposal's share of particles, the motion model,
the balance-heuristic weights, the sensor model (nav2's likelihood_field_prob, the hybrid's),
KLD resampling and the clusters. Plain amcl does the same update with the same sensor model and
no proposal. Both at fixed particle counts (min = max) of 1k and 5k, updating and resampling
on every scan, on map 1 (as benchmarks/amcl.py), 2 numba threads, medians over repeats after
warm-up.

The network is the pipeline's trained model for map 1 (models/scanlocnet/sparse_obstacles/
model.pt, from `dvc repro train_scanlocnet@sparse_obstacles`) when it exists, else an untrained
one of conf/scanlocnet.yaml's architecture. An untrained network decodes more slowly (its
branch and bound prunes little), so its figures are a worst case; the JSON names which ran.

Four hybrids, with the proposal, mixing and weighting conf/localizer ships (hybrid.yaml's
sections, and hybrid_adaptive.yaml's, hybrid_verified.yaml's or hybrid_real.yaml's over them):
the constant share (`mixing: constant`, a share of particles from the proposal, and so the
network, on every update),
the adaptive one (hybrid.py's adaptive mixing: the network runs only on updates whose share
is > 0, so its cost is amortised; on this clean drive from a known pose it should not need the
network at all), the verified one (hybrid_verified.yaml: the constant share with every scan's
hypotheses verified against the map; uncalibrated here, which costs the same), and the gated
one (hybrid_real.yaml's verified gate: the network and the gate's verification of the estimate
and the hypotheses on every update, proposals only when the gate opens). Each reports the share
of updates that ran the network; its Hz include the network's (and verification's) cost where
it ran.

Run: python benchmarks/hybrid.py [--quick] [--model PATH]. Last line: JSON.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numba
import numpy as np
import torch
import yaml

from amcl import (  # benchmarks/amcl.py, beside this script
    benchmark_drive,
    compiled_filter,
    median_update_s,
    params_for,
)
from scanloc.localize.catalog import raw_config
from scanloc.localize.config_params import parse_section
from scanloc.localize.hypothesis_verification import HypothesisVerifier, VerifierParams
from scanloc.localize.kinds import config_file
from scanloc.localize.learned_localizer import LearnedParams, scan_hypotheses, verified
from scanloc.localize.mcl.config import MclConfig, build_filter
from scanloc.localize.mcl.parts import MIXINGS, PROPOSALS, WEIGHTINGS, PartsContext
from scanloc.models.training import build_model
from scanloc.scanlocnet.pose_grid import PoseGrid
from scanloc.sensor.laser import LaserSpec

ROOT = Path(__file__).resolve().parents[1]
PIPELINE_MODEL = ROOT / "models" / "scanlocnet" / "sparse_obstacles" / "model.pt"
SIZES = (1000, 5000)
MODEL = "likelihood_field_prob"


def untrained_model(grid, spec: LaserSpec, path: Path) -> Path:
    """conf/scanlocnet.yaml's network for `grid`, untrained, saved to `path`."""
    from scanloc.models.training import save_model

    conf = yaml.safe_load((ROOT / "conf" / "scanlocnet.yaml").read_text())
    cell = conf["grid"]
    pose_grid = PoseGrid.from_map(
        grid, float(cell["cell_size"]), int(cell["heading_bins"]), float(cell["clearance"])
    )
    cfg = dict(conf["net"]) | {
        "grid": pose_grid.to_dict(),
        "num_beams": spec.num_beams,
        "range_max": spec.range_max,
    }
    torch.manual_seed(0)
    save_model(path, cfg, build_model(cfg).state_dict())
    return path


HYBRIDS = {
    "hybrid": "hybrid",
    "adaptive_hybrid": "hybrid_adaptive",
    "verified_hybrid": "hybrid_verified",
    "gated_hybrid": "hybrid_real",
}


def hybrid_parts(name: str, grid, spec: LaserSpec, hypotheses_of, verified_of):
    """(proposal, mixing, weighting) of conf/localizer/<name>.yaml as shipped, on the
    benchmark's hypotheses (verified ones where its `learned` section says `verified`)."""
    cfg = raw_config(name, ROOT / "conf" / "localizer")
    where = config_file(cfg)
    learned = parse_section(LearnedParams, cfg, "learned", where)
    chosen = verified_of if learned.verified else hypotheses_of
    context = PartsContext(grid, spec, sections=cfg, where=where, hypotheses=lambda: chosen)
    context.proposal = PROPOSALS.build(context)
    return context.proposal, MIXINGS.build(context), WEIGHTINGS.build(context)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a fast smoke run")
    parser.add_argument("--model", type=Path, default=PIPELINE_MODEL)
    args = parser.parse_args()
    repeats, per_repeat = (2, 2) if args.quick else (7, 15)
    grid, map_name, spec, ranges, odom = benchmark_drive()
    trained = args.model.is_file()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.model if trained else untrained_model(grid, spec, Path(tmp) / "model.pt")
        _, hypotheses_of, _ = scan_hypotheses(path, ranges)
    cfg = raw_config("hybrid_verified", ROOT / "conf" / "localizer")
    verifier = HypothesisVerifier(
        grid, spec, parse_section(VerifierParams, cfg, "verifier", config_file(cfg))
    )
    verified_of = verified(hypotheses_of, verifier)
    net, checked = [], []
    for scan in ranges[:: max(1, len(ranges) // (10 if args.quick else 60))]:
        tick = time.perf_counter()
        hyp = hypotheses_of(scan)
        net.append(time.perf_counter() - tick)
        tick = time.perf_counter()
        verifier.verify(scan, hyp)
        checked.append(time.perf_counter() - tick)
    threads = numba.get_num_threads()
    figures: dict[str, object] = {
        "map": map_name,
        "threads": threads,
        "torch_threads": torch.get_num_threads(),
        "model": str(args.model) if trained else "untrained",
        "sensor_model": MODEL,
        "network_ms_median": round(1e3 * float(np.median(net)), 2),
        "verification_ms_median": round(1e3 * float(np.median(checked)), 2),
        "quick": args.quick,
    }
    print(
        f"map: {map_name}; model: {figures['model']}; network {figures['network_ms_median']} ms, "
        f"verification {figures['verification_ms_median']} ms"
    )
    for n in SIZES:
        params = params_for(MODEL, n)
        plain = compiled_filter(grid, spec, params)
        plain.initialize_pose(odom[0])
        plain_s = median_update_s(plain, odom, ranges, repeats, per_repeat)
        key = f"{n // 1000}k"
        figures[f"amcl_hz_{key}"] = round(1.0 / plain_s, 1)
        config = MclConfig.from_ros(params | {"publish_every_update": True}, where="benchmark")
        for label, name in HYBRIDS.items():
            proposal, mixing, weighting = hybrid_parts(name, grid, spec, hypotheses_of, verified_of)
            filter_ = build_filter(
                grid, spec, config, 0, proposal=proposal, weighting=weighting, mixing=mixing
            )
            filter_.initialize_pose(odom[0])
            hybrid_s = median_update_s(filter_, odom, ranges, repeats, per_repeat)
            network_share = proposal.inferences / max(1, mixing.updates)
            figures[f"{label}_hz_{key}"] = round(1.0 / hybrid_s, 1)
            figures[f"{label}_cost_ratio_{key}"] = round(hybrid_s / plain_s, 2)
            figures[f"{label}_network_share_{key}"] = round(network_share, 3)
            print(
                f"{n:>5} particles: amcl {plain_s * 1e3:6.2f} ms ({1 / plain_s:6.1f} Hz), {label} "
                f"{hybrid_s * 1e3:6.2f} ms ({1 / hybrid_s:6.1f} Hz), {hybrid_s / plain_s:.2f}x; "
                f"network on {100 * network_share:.0f} % of updates"
            )
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
