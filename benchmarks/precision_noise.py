"""Does bf16 autocast change what a Table 1 row learns? Compared with float32's seed-to-seed spread.

Trains one Table 1 row (default: cnn1d_20k at the laptop profile, the pipeline's own config and
dataset) with several seeds in float32 (32-true) and under bf16 autocast (bf16-mixed), same
seeds, same data. bf16 leaves the results "unchanged within seed-to-seed noise" when the
difference of the two precisions' mean validation MAE is within two standard errors of that
difference (Welch's t statistic |t| < 2, the seeds' spread estimated separately for each
precision); also printed: the difference in float32 seed standard deviations.
Also the median epoch time of each, for the speed-up it buys. Needs the row's dataset
(`dvc repro scans`); --quick trains a tiny synthetic dataset instead (a smoke run).

Last line: one JSON object of the figures.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import tempfile
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from scanloc.models.training import fit
from train_throughput import logging_off, write_synthetic_dataset

CONF = Path(__file__).resolve().parents[1] / "conf"
PRECISIONS = ("32-true", "bf16-mixed")


def row_config(experiment: str, profile: str) -> dict:
    """The train stage's configuration of one Table 1 row (conf/train.yaml)."""
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose("train", overrides=[f"experiment={experiment}", f"profile={profile}"])
    return OmegaConf.to_container(cfg, resolve=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny smoke run")
    parser.add_argument("--experiment", default="cnn1d_20k")
    parser.add_argument("--profile", default="laptop")
    parser.add_argument("--seeds", type=int, default=4, help="seeds 1..N")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    logging_off()
    cfg = row_config(args.experiment, args.profile)
    exp = cfg["experiment"]
    common = {
        "model_cfg": cfg["model"]["net"],
        "epochs": int(exp["epochs"]),
        "batch_size": int(exp["batch_size"]),
        "lr": float(cfg["model"]["lr"]),
        "lr_decay": float(cfg["model"]["lr_decay"]),
        "max_samples": int(exp["samples"]),
    }
    seeds = list(range(1, args.seeds + 1))
    with tempfile.TemporaryDirectory(prefix="scanloc-bench-") as tmp:
        dataset = Path(cfg["dataset_dir"])
        if args.quick:
            seeds = [1, 2]
            common.update(epochs=1, batch_size=50, max_samples=300)
            dataset = write_synthetic_dataset(Path(tmp) / "scans", 300)
        elif not (dataset / "meta.json").is_file():
            raise SystemExit(f"{dataset}: no scan dataset; run `dvc repro scans` first")
        runs: dict[str, list[dict]] = {p: [] for p in PRECISIONS}
        for seed in seeds:
            for precision in PRECISIONS:
                metrics = fit(
                    dataset_dir=dataset,
                    out_dir=Path(tmp) / f"{precision}_{seed}",
                    seed=seed,
                    trainer_cfg={**cfg["trainer"], "precision": precision},
                    **common,
                )
                runs[precision].append(metrics)
                print(
                    f"seed {seed} {precision:10s} val_mae {metrics['val_mae']:.4f} "
                    f"pos {metrics['val_pos_err_m']:.3f} m  epoch {metrics['epoch_s']:.2f} s",
                    flush=True,
                )
    val = {p: [m["val_mae"] for m in runs[p]] for p in PRECISIONS}
    epoch_s = {p: statistics.median(m["epoch_s"] for m in runs[p]) for p in PRECISIONS}
    fp32_std = statistics.stdev(val["32-true"])
    bf16_std = statistics.stdev(val["bf16-mixed"])
    diff = statistics.mean(val["bf16-mixed"]) - statistics.mean(val["32-true"])
    welch_t = diff / math.sqrt((fp32_std**2 + bf16_std**2) / len(seeds))
    paired = [b - f for b, f in zip(val["bf16-mixed"], val["32-true"], strict=True)]
    result = {
        "experiment": args.experiment,
        "profile": "quick" if args.quick else args.profile,
        "seeds": len(seeds),
        "fp32_val_mae": [round(v, 4) for v in val["32-true"]],
        "bf16_val_mae": [round(v, 4) for v in val["bf16-mixed"]],
        "fp32_mean": round(statistics.mean(val["32-true"]), 4),
        "bf16_mean": round(statistics.mean(val["bf16-mixed"]), 4),
        "fp32_seed_std": round(fp32_std, 4),
        "bf16_seed_std": round(bf16_std, 4),
        "mean_diff": round(diff, 4),
        "diff_in_fp32_std": round(diff / fp32_std, 3),
        "welch_t": round(welch_t, 3),
        "within_seed_noise": abs(welch_t) < 2.0,
        "mean_abs_paired_diff": round(statistics.mean(abs(d) for d in paired), 4),
        "epoch_speedup": round(epoch_s["32-true"] / epoch_s["bf16-mixed"], 3),
        "threads": args.threads,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
