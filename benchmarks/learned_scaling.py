"""Benchmark: how ScanLocNet's cost grows with the building, and what verification adds per scan.

Part 1, training cost at 3 map sizes: generated rooms maps (conf/map/generated_rooms.yaml's
generator) of 25 x 12.5, 50 x 25 and 100 x 50 m; for each, the laptop network with its pose
grid, `--steps` training steps of batch 256 on freshly simulated scans (median step time),
the decoding of 64 scans over the whole grid (ms per scan: what validation and localization
pay) and the process's peak RSS after both. From these, the whole laptop training on each map:
its epochs (raised on a large map: scanloc.scanlocnet.schedule) times the measured steps of an
epoch (`train_steps_s`), plus the validation's decoding at the measured worst case
(`validation_worst_s`: an untrained network; a trained one decodes faster), next to the maps
stage's estimate (stages/budget.py, float32, fitted to whole trainings: `budget_estimate_s`).
The figures are fitted by least squares, linear in the number of cells (a + b·cells) and as a
power law (cells^k); the smallest map is the reference the others are compared with
(`step_ratio`).

Part 2, one scan's cost in the learned localizer on map 1 (sparse_obstacles, drive at the
laptop profile): the network's hypotheses (top_k + non-maximum suppression) alone, the
reference, and their verification against the map (hypothesis_verification: refinement,
scores, calibration, re-ranking), medians per scan.

Run: python benchmarks/learned_scaling.py [--steps 5] [--quick]
Last line: JSON {"scaling": {...}, "inference": {...}}.
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from amcl_every_scan import pipeline_run
from scanloc.localize.hypothesis_verification import HypothesisVerifier, VerifierParams
from scanloc.localize.learned_localizer import scan_hypotheses, verified
from scanloc.models.model_files import build_model, save_model
from scanloc.scanlocnet.model import top_k
from scanloc.scanlocnet.pose_grid import PoseGrid
from scanloc.scanlocnet.scan_stream import StreamSpec, simulate_epoch
from scanloc.scanlocnet.schedule import training_epochs
from scanloc.scanlocnet.training import encode_targets, scanlocnet_loss
from scanloc.sensor.noise import noise_from_config
from scanloc.sensor.simulate import ScanSimulator, laser_spec_from_config
from scanloc.stages.budget import PipelineSizes, scanlocnet_training_seconds
from scanloc.world.build import build_map

CONF = Path(__file__).resolve().parents[1] / "conf"
SIZES = ((25.0, 12.5), (50.0, 25.0), (100.0, 50.0))
PIPELINE_MODEL = CONF.parent / "models/scanlocnet/sparse_obstacles/model.pt"


def learned_config() -> dict:
    """conf/scanlocnet.yaml at the laptop profile, with its validation scans per epoch
    (`val_scans`: the map's validation dataset, conf/dataset/map_validation.yaml)."""
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = OmegaConf.to_container(compose("scanlocnet"), resolve=True)
        val = compose("scans", overrides=["dataset=map_validation"]).dataset
    return cfg | {"val_scans": int(val.num_samples)}


def rooms_map(width: float, height: float):
    cfg = OmegaConf.to_container(OmegaConf.load(CONF / "map/generated_rooms.yaml"))
    return build_map(cfg | {"width": width, "height": height})


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def training_cost(cfg: dict, width: float, height: float, steps: int) -> dict:
    """Median training step and decoding time of the laptop network on one map size."""
    grid = rooms_map(width, height)
    g, sensor, noise = cfg["grid"], cfg["sensor"], cfg["noise"]
    pose_grid = PoseGrid.from_map(grid, g["cell_size"], g["heading_bins"], g["clearance"])
    spec = laser_spec_from_config(sensor)
    batch = cfg["training"]["batch_size"]
    simulator = ScanSimulator(grid, spec, noise_from_config(noise), sensor["mode"])
    stream = StreamSpec("", sensor, noise, g["clearance"], batch * (steps + 1), 3)
    ranges, poses = simulate_epoch(stream, 0, grid, simulator)
    torch.manual_seed(0)
    net = cfg["net"] | {"grid": pose_grid.to_dict(), "num_beams": spec.num_beams}
    model = build_model(net | {"range_max": spec.range_max}).train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-3)
    times = []
    for step in range(steps + 1):  # the first step warms up (oneDNN builds its kernels)
        rows = slice(step * batch, (step + 1) * batch)
        x = torch.from_numpy(ranges[rows])
        targets = encode_targets(pose_grid, poses[rows], "benchmark scans")
        tick = time.perf_counter()
        loss = scanlocnet_loss(model, x, targets)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        times.append(time.perf_counter() - tick)
    model.eval()
    tick = time.perf_counter()
    top_k(model, ranges[:64], 50)
    decode_ms = 1000 * (time.perf_counter() - tick) / 64
    return {
        "size_m": [width, height],
        "cells": pose_grid.num_cells,
        "step_s": float(np.median(times[1:])),
        "decode_ms_per_scan": decode_ms,
        "peak_rss_mb": peak_rss_mb(),
    }


def whole_training(cfg: dict, row: dict) -> dict:
    """The whole training on one map size (module docstring), in seconds."""
    train = cfg["training"]
    epochs = training_epochs(
        train["epochs"], train["scans_per_epoch"], row["cells"], train["min_samples_per_cell"]
    )
    steps = train["scans_per_epoch"] // train["batch_size"]
    sizes = PipelineSizes(
        datasets={},
        num_beams=cfg["sensor"]["num_beams"],
        scans_per_epoch=train["scans_per_epoch"],
        epochs=train["epochs"],
        val_scans=cfg["val_scans"],
        min_samples_per_cell=train["min_samples_per_cell"],
    )
    return {
        "epochs": epochs,
        "train_steps_s": epochs * steps * row["step_s"],
        "validation_worst_s": epochs * cfg["val_scans"] * row["decode_ms_per_scan"] / 1000,
        "budget_estimate_s": scanlocnet_training_seconds(sizes, row["cells"], bf16=False),
    }


def fit_growth(rows: list[dict], key: str) -> dict:
    """Least squares of `key` against the cells: linear (a + b·cells) and power law."""
    cells = np.array([r["cells"] for r in rows], dtype=float)
    values = np.array([r[key] for r in rows], dtype=float)
    b, a = np.polyfit(cells, values, 1)
    k, _ = np.polyfit(np.log(cells), np.log(values), 1)
    return {"intercept": float(a), "per_cell": float(b), "power_law_exponent": float(k)}


def inference_cost(quick: bool) -> dict:
    """Per-scan milliseconds of the network's hypotheses and of their verification on the map-1
    drive, with the pipeline's trained model (PIPELINE_MODEL) when `dvc repro` has made it,
    else an untrained one (its flat scores make the exact top-K visit every cell: the worst
    case of decoding; verification costs the same either way)."""
    cfg = learned_config()
    grid, spec, _, ranges = pipeline_run("smoke" if quick else "laptop", "sparse_obstacles")
    with tempfile.TemporaryDirectory() as tmp:
        path = PIPELINE_MODEL
        if not path.is_file():
            g = cfg["grid"]
            pose_grid = PoseGrid.from_map(grid, g["cell_size"], g["heading_bins"], g["clearance"])
            net = cfg["net"] | {"grid": pose_grid.to_dict(), "num_beams": spec.num_beams}
            net |= {"range_max": spec.range_max}
            torch.manual_seed(0)
            path = Path(tmp) / "model.pt"
            save_model(path, net, build_model(net).state_dict())
        _, hypotheses_of, _ = scan_hypotheses(path, ranges)
    # no calibration: a 3-feature logistic per hypothesis costs nothing next to the refinement
    verifier = HypothesisVerifier(grid, spec, VerifierParams())
    n = min(len(ranges), 50 if quick else 300)
    network, both = [], []
    for scan in ranges[:n]:
        tick = time.perf_counter()
        hyp = hypotheses_of(scan)
        mid = time.perf_counter()
        verifier.verify(scan, hyp)
        network.append(mid - tick)
        both.append(time.perf_counter() - tick)
    verified(hypotheses_of, verifier)(ranges[0])  # the composed function the localizer runs
    return {
        "model": "pipeline" if PIPELINE_MODEL.is_file() else "untrained",
        "scans": n,
        "hypotheses_ms": 1000 * float(np.median(network)),
        "verification_ms": 1000 * float(np.median(np.subtract(both, network))),
        "total_ms": 1000 * float(np.median(both)),
    }


def scaling_cost(steps: int, quick: bool) -> dict:
    """Part 1 (module docstring) at the 3 sizes (2 when `quick`), with the fitted growth."""
    cfg = learned_config()
    rows = []
    for width, height in SIZES[:2] if quick else SIZES:
        row = training_cost(cfg, width, height, steps)
        rows.append(row | whole_training(cfg, row))
        print(json.dumps(rows[-1]))
    for row in rows:
        row["step_ratio"] = row["step_s"] / rows[0]["step_s"]
    return {
        "maps": rows,
        "step_s_growth": fit_growth(rows, "step_s"),
        "decode_ms_growth": fit_growth(rows, "decode_ms_per_scan"),
        "train_steps_s_growth": fit_growth(rows, "train_steps_s"),
        "budget_estimate_s_growth": fit_growth(rows, "budget_estimate_s"),
        "peak_rss_mb_growth": fit_growth(rows, "peak_rss_mb"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5, help="timed training steps per size")
    parser.add_argument("--quick", action="store_true", help="a fast smoke run")
    args = parser.parse_args()
    torch.set_num_threads(2)
    scaling = scaling_cost(1 if args.quick else args.steps, args.quick)
    inference = inference_cost(args.quick)
    print(json.dumps({"scaling": scaling, "inference": inference}))


if __name__ == "__main__":
    main()
