"""Benchmark: localization accuracy against training wall time, scanloc's learned localizer
(ScanLocNet) and the paper's 1D CNN, on the same data path and the same budget, in one run.

Both train on the same fresh scans (scanloc.scanlocnet.scan_stream: a new epoch simulated in the
background each time, the pipeline's sensor and noise model) for `--budget` seconds of wall
time each, one after the other on this machine's threads:
- ScanLocNet (conf/scanlocnet.yaml's network): its loss, AdamW with a one-cycle schedule over
  the wall-time budget (one_cycle_lr);
- the paper's 1D CNN (conf/model/cnn1d.yaml, Table 1's cnn1d_200k: no dropout, batch 400,
  Adam lr 0.006): mean absolute error on raw (x, y, θ), as the paper trains it.
Then both localize 2000 fresh validation scans and the pipeline's drive trajectory of the map
(conf/trajectory.yaml at `--profile`): median position error of the best hypothesis (the 1D
CNN has only one), the share of gross failures (> 1 m) and the top-5 recall (truth within
0.5 m and 10° of one of the 5 best hypotheses; for the 1D CNN, of its one estimate).

Then ScanLocNet's cost with the building and per scan (benchmarks/learned_scaling.py, whose
parts this runs): its training at 3 map sizes (25 x 12.5, 50 x 25 and 100 x 50 m generated
rooms maps: a training step, a scan's decoding, peak memory, the whole training composed from
them and the maps stage's estimate of it, each with its fitted growth in the pose cells), and
on the map-1 drive the network's hypotheses against their verification, ms per scan.

Run: python benchmarks/learned_localizer.py [--budget 240] [--map sparse_obstacles]
     [--parts compare scaling inference] [--quick]
Last line: JSON: per model (`scanlocnet`, `cnn1d`) median_pos_err_m, gross_frac, top5_recall,
budget_s, samples; `scaling` (per map size and the fits); `inference` (hypotheses_ms,
verification_ms, total_ms).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from amcl_every_scan import pipeline_run
from learned_scaling import inference_cost, scaling_cost
from scanloc.models.model_files import build_model, predict
from scanloc.pose import recall_within
from scanloc.scanlocnet.model import suppress_duplicates, top_k
from scanloc.scanlocnet.pose_grid import PoseGrid
from scanloc.scanlocnet.scan_stream import ScanStream, StreamSpec, simulate_epoch
from scanloc.scanlocnet.training import encode_targets, scanlocnet_loss
from scanloc.sensor.noise import noise_from_config
from scanloc.sensor.simulate import ScanSimulator, laser_spec_from_config
from scanloc.world.map_server import save_map

CONF = Path(__file__).resolve().parents[1] / "conf"
PARTS = ("compare", "scaling", "inference")


def configs() -> tuple[dict, dict]:
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        learned = compose("scanlocnet")
        paper = compose("train", overrides=["experiment=cnn1d_200k", "profile=paper"])
    return OmegaConf.to_container(learned, resolve=True), OmegaConf.to_container(
        paper, resolve=True
    )


def train_for(budget: float, stream: ScanStream, step, batch_size: int) -> int:
    """Run `step(ranges, poses)` on shuffled batches of the stream's epochs until `budget`
    seconds have passed; returns the number of samples seen."""
    start, seen, epoch = time.perf_counter(), 0, 0
    while True:
        ranges, poses = stream.epoch(epoch)
        order = np.random.default_rng(epoch).permutation(len(ranges))
        for b in range(len(ranges) // batch_size):
            idx = order[b * batch_size : (b + 1) * batch_size]
            step(ranges[idx], poses[idx])
            seen += batch_size
            if time.perf_counter() - start >= budget:
                return seen
        epoch += 1


def one_cycle_lr(spent: float, max_lr: float, pct_start: float) -> float:
    """torch's OneCycleLR (cosine, div_factor 25, final_div_factor 1e4) over the share of the
    wall-time budget spent: a budget in seconds has no step count known in advance (estimating
    one from the first steps undershot 6x: they include the JIT's and the stream's warm-up)."""
    low, end = max_lr / 25.0, max_lr / 25.0 / 1e4
    if spent < pct_start:
        return low + (max_lr - low) * (1 - math.cos(math.pi * spent / pct_start)) / 2
    t = min(1.0, (spent - pct_start) / (1 - pct_start))
    return end + (max_lr - end) * (1 + math.cos(math.pi * t)) / 2


def figures(hyp_poses: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    pos = np.hypot(*(hyp_poses[:, 0, :2] - truth[:, :2]).T)
    return {
        "median_pos_err_m": round(float(np.median(pos)), 4),
        "gross_frac": round(float(np.mean(pos > 1.0)), 4),
        "top5_recall": round(float(recall_within(hyp_poses[:, :5], truth).mean()), 4),
    }


def compare(args: argparse.Namespace) -> dict[str, dict]:
    """ScanLocNet against the paper's 1D CNN at the same budget (module docstring)."""
    budget = 8.0 if args.quick else args.budget
    profile = "smoke" if args.quick else args.profile
    learned_cfg, paper_cfg = configs()
    grid, spec, traj, traj_ranges = pipeline_run(profile, args.map)
    sensor, noise = learned_cfg["sensor"], learned_cfg["noise"]
    g = learned_cfg["grid"]
    pose_grid = PoseGrid.from_map(grid, g["cell_size"], g["heading_bins"], g["clearance"])
    simulator = ScanSimulator(
        grid, laser_spec_from_config(sensor), noise_from_config(noise), sensor["mode"]
    )
    n_val = 200 if args.quick else 2000
    val_spec = StreamSpec("", sensor, noise, g["clearance"], n_val, 999)
    val_ranges, val_poses = simulate_epoch(val_spec, 0, grid, simulator)
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        save_map(grid, Path(tmp) / "map.yaml")
        stream_spec = StreamSpec(
            str(Path(tmp) / "map.yaml"),
            sensor,
            noise,
            g["clearance"],
            2048 if args.quick else 20000,
            11,
        )
        torch.manual_seed(0)
        # --- ScanLocNet
        net_cfg = learned_cfg["net"] | {
            "grid": pose_grid.to_dict(),
            "num_beams": spec.num_beams,
            "range_max": spec.range_max,
        }
        model = build_model(net_cfg).train()
        train = learned_cfg["training"]
        optimizer = torch.optim.AdamW(
            model.parameters(), lr=train["lr"], weight_decay=train["weight_decay"]
        )
        batch = train["batch_size"]

        started = time.perf_counter()

        def learned_step(ranges: np.ndarray, poses: np.ndarray) -> None:
            spent = (time.perf_counter() - started) / budget
            for group in optimizer.param_groups:
                group["lr"] = one_cycle_lr(spent, train["lr"], train["pct_start"])
            target = encode_targets(pose_grid, poses, "benchmark batch")
            loss = scanlocnet_loss(model, torch.from_numpy(ranges), target)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()

        with ScanStream(stream_spec) as stream:
            started = time.perf_counter()
            seen = train_for(budget, stream, learned_step, batch)
        model.eval()
        scored = {}
        for label, ranges, truth in (
            ("val", val_ranges, val_poses),
            ("trajectory", traj_ranges, traj.truth),
        ):
            hyp = suppress_duplicates(top_k(model, ranges, 50), 0.5, math.radians(10.0), 20)
            scored[label] = figures(hyp.poses, truth)
        results["scanlocnet"] = {
            **scored["trajectory"],
            "val": scored["val"],
            "budget_s": budget,
            "samples": seen,
        }
        # --- the paper's 1D CNN
        exp, net = (
            paper_cfg["experiment"],
            paper_cfg["model"]["net"] | {"num_beams": spec.num_beams},
        )
        cnn = build_model(net).train()
        adam = torch.optim.Adam(
            cnn.parameters(), lr=paper_cfg["model"]["lr"], betas=(0.9, 0.999), eps=1e-8
        )

        def cnn_step(ranges: np.ndarray, poses: np.ndarray) -> None:
            loss = (cnn(torch.from_numpy(ranges)) - torch.from_numpy(poses).float()).abs().mean()
            adam.zero_grad()
            loss.backward()
            adam.step()

        with ScanStream(stream_spec) as stream:
            seen_cnn = train_for(budget, stream, cnn_step, exp["batch_size"])
        cnn.eval()
        scored = {}
        for label, ranges, truth in (
            ("val", val_ranges, val_poses),
            ("trajectory", traj_ranges, traj.truth),
        ):
            scored[label] = figures(predict(cnn, ranges)[:, None, :], truth)
        results["cnn1d"] = {
            **scored["trajectory"],
            "val": scored["val"],
            "budget_s": budget,
            "samples": seen_cnn,
        }
    for name, r in results.items():
        print(
            f"{name:>11}: {r['samples']:>8} samples in {budget:.0f} s; trajectory median "
            f"{r['median_pos_err_m']:.3f} m, > 1 m {100 * r['gross_frac']:.1f} %, top-5 recall "
            f"{100 * r['top5_recall']:.1f} %; validation {r['val']}"
        )
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=float, default=240.0, help="training seconds per model")
    parser.add_argument("--map", default="sparse_obstacles")
    parser.add_argument("--profile", default="laptop", help="the trajectory's profile")
    parser.add_argument("--steps", type=int, default=5, help="timed training steps per size")
    parser.add_argument(
        "--parts", nargs="+", choices=PARTS, default=list(PARTS), help="which parts to run"
    )
    parser.add_argument("--quick", action="store_true", help="a fast smoke run")
    args = parser.parse_args()
    figures: dict = {"map": args.map, "threads": torch.get_num_threads(), "quick": args.quick}
    # Scaling first: its peak RSS is the process's high-water mark, which the comparison's
    # training would otherwise have set for every size.
    if "scaling" in args.parts:
        figures["scaling"] = scaling_cost(1 if args.quick else args.steps, args.quick)
    if "compare" in args.parts:
        figures |= compare(args)
    if "inference" in args.parts:
        figures["inference"] = inference_cost(args.quick)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
