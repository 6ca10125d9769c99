"""Ensemble members trained together (stacked) vs one after another, same code, same data.

Together: one `fit_stacked` call with all seeds. Sequential: `fit_stacked` once per seed (the
same loop with one member). The same members must come out either way: max_param_diff is the
largest difference between a member's final weights trained together and trained alone.
Also timed once each: the vectorised mode (mode="vmap") and the sequential Lightning `fit`
that the pipeline would otherwise run per member.

Synthetic 667-beam scans in the dataset format, the paper's ensemble network (1D CNN, pool 8,
no dropout) and batch size (400), the pipeline's CPU trainer config
(its precision). Last line: one JSON object of the figures (medians).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import torch

from scanloc.models.model_files import read_model_file
from scanloc.models.stacked_ensemble import fit_stacked
from scanloc.models.training import fit
from train_throughput import (
    logging_off,
    pipeline_precision,
    pipeline_trainer_cfg,
    write_synthetic_dataset,
)

MODEL_CFG = {"_target_": "scanloc.models.cnn1d.Cnn1d", "pool_size": 8, "dropout": 0.0}


def timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def max_param_diff(dirs_a: list[Path], dirs_b: list[Path]) -> float:
    worst = 0.0
    for a, b in zip(dirs_a, dirs_b, strict=True):
        sa = read_model_file(a / "last.pt")["state_dict"]
        sb = read_model_file(b / "last.pt")["state_dict"]
        worst = max(worst, *((sa[k].double() - sb[k].double()).abs().max().item() for k in sa))
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny smoke run")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    parser.add_argument("--members", type=int, default=7)
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--batch", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if args.quick:
        args.members, args.samples, args.epochs, args.batch, args.repeats = 2, 200, 1, 100, 1
    torch.set_num_threads(args.threads)
    logging_off()
    seeds = list(range(11, 11 + args.members))
    with tempfile.TemporaryDirectory(prefix="scanloc-bench-") as tmp:
        root = Path(tmp)
        dataset = write_synthetic_dataset(root / "scans", args.samples)
        common = {
            "model_cfg": MODEL_CFG,
            "dataset_dir": dataset,
            "epochs": args.epochs,
            "batch_size": args.batch,
            "lr": 0.006,
            "lr_decay": 0.0,
            "trainer_cfg": pipeline_trainer_cfg(),
        }
        together = [root / "together" / f"member_{k}" for k in range(args.members)]
        alone = [root / "alone" / f"member_{k}" for k in range(args.members)]
        together_s, sequential_s = [], []
        for repeat in range(args.repeats):
            together_s.append(timed(lambda: fit_stacked(out_dirs=together, seeds=seeds, **common)))
            sequential_s.append(
                timed(
                    lambda: [
                        fit_stacked(out_dirs=[d], seeds=[s], **common)
                        for d, s in zip(alone, seeds, strict=True)
                    ]
                )
            )
            print(
                f"repeat {repeat}: together {together_s[-1]:.2f} s, "
                f"one after another {sequential_s[-1]:.2f} s",
                flush=True,
            )
        diff = max_param_diff(together, alone)
        together_med = statistics.median(together_s)
        sequential_med = statistics.median(sequential_s)
        extras = {"vmap_speedup_vs_sequential": None, "speedup_vs_lightning_fit": None}
        if not args.quick:
            vmap_dirs = [root / "vmap" / f"member_{k}" for k in range(args.members)]
            vmap_s = timed(
                lambda: fit_stacked(out_dirs=vmap_dirs, seeds=seeds, mode="vmap", **common)
            )
            lightning_s = timed(
                lambda: [
                    fit(out_dir=root / "fit" / f"member_{k}", seed=s, **common)
                    for k, s in enumerate(seeds)
                ]
            )
            print(f"vmap mode {vmap_s:.2f} s; Lightning fit one after another {lightning_s:.2f} s")
            extras["vmap_speedup_vs_sequential"] = round(sequential_med / vmap_s, 3)
            extras["speedup_vs_lightning_fit"] = round(lightning_s / together_med, 3)
    result = {
        "precision": pipeline_precision(),
        "speedup_vs_sequential": round(sequential_med / together_med, 3),
        "max_param_diff": diff,
        "together_s": round(together_med, 3),
        "sequential_s": round(sequential_med, 3),
        **extras,
        "members": args.members,
        "samples": args.samples,
        "epochs": args.epochs,
        "batch_size": args.batch,
        "repeats": args.repeats,
        "threads": args.threads,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
