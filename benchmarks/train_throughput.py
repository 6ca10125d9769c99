"""Training throughput of the paper's 1D CNN (batch 400): scanloc's training path vs a plain one.

Compared in the same run, same model, same batch, same Lightning loop:
- ours: ScanDataModule (data resident in device memory, one gather per batch) at the precision
  the pipeline trains in (conf/trainer/cpu.yaml: `auto` = bf16 autocast where the CPU has bf16
  dot-product instructions, float32 elsewhere);
- baseline: torch.utils.data.DataLoader over a per-sample Dataset reading the memory map, in
  Lightning's default float32: the textbook loop;
- ours_fp32: our data path in float32, which splits the speed-up into its two causes
  (data_path_speedup = ours_fp32 / baseline, precision_speedup = ours / ours_fp32);
- ours with the plain (contiguous Conv1D) layout, float32, to show what channels-last gives;
- ours before `keep_freed_memory` (glibc's default allocator thresholds), float32, measured
  first because that setting cannot be undone; the others run with it, as `fit` does.
Also measured: this machine's matmul rate in float32 and bf16 (median GFLOP/s of large square
matmuls) and the model's FLOPs per training sample (forward + backward, counted by
FlopCounterMode on a real training step), giving the fraction of the matmul ceiling (of the
precision trained in) that the training reaches; and the data paths alone (no model).

Synthetic data in the dataset format (data/scans/<name>/) is written to a temporary folder.
Last line: one JSON object of the figures (medians over epochs).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import lightning as L
import numpy as np
import torch
from omegaconf import OmegaConf
from torch.utils.data import DataLoader, Dataset
from torch.utils.flop_counter import FlopCounterMode

from scanloc.data.datamodule import ScanDataModule
from scanloc.data.scan_dataset import save_scan_dataset
from scanloc.models.cnn1d import Cnn1d
from scanloc.models.pose_regressor import PoseRegressor, mae_loss
from scanloc.models.trainer_setup import keep_freed_memory, trainer_arguments

BEAMS = 667
PIPELINE_TRAINER = Path(__file__).resolve().parents[1] / "conf" / "trainer" / "cpu.yaml"


def write_synthetic_dataset(path: Path, count: int, beams: int = BEAMS, seed: int = 0) -> Path:
    """Random poses and ranges in the scan-dataset format (10 % validation)."""
    rng = np.random.default_rng(seed)
    poses = np.column_stack(
        [rng.uniform(0, 15, count), rng.uniform(0, 15, count), rng.uniform(-np.pi, np.pi, count)]
    )
    ranges = rng.uniform(0.02, 7.0, (count, beams))
    is_val = np.zeros(count, dtype=bool)
    is_val[rng.permutation(count)[: count // 10]] = True
    meta = {"seed": seed, "sensor": {"num_beams": beams}}
    return save_scan_dataset(path, ranges, poses, is_val, meta)


class PerSampleScans(Dataset):
    """The textbook Dataset: one sample per __getitem__, from the memory map."""

    def __init__(self, dataset_dir: Path) -> None:
        is_val = np.load(dataset_dir / "is_val.npy")
        self.rows = np.flatnonzero(~is_val)
        self.ranges = np.load(dataset_dir / "ranges.npy", mmap_mode="r")
        self.poses = np.load(dataset_dir / "poses.npy", mmap_mode="r")

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        row = self.rows[i]
        x = torch.from_numpy(np.array(self.ranges[row]))
        y = torch.from_numpy(np.array(self.poses[row], dtype=np.float32))
        return x, y


class EpochTimer(L.Callback):
    def __init__(self) -> None:
        self.seconds: list[float] = []

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self._start = time.perf_counter()

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        self.seconds.append(time.perf_counter() - self._start)


def matmul_gflops(n: int, repeats: int, dtype: torch.dtype = torch.float32) -> float:
    """Median matmul rate of n×n matrices of `dtype` (GFLOP/s)."""
    a, b = torch.randn(n, n, dtype=dtype), torch.randn(n, n, dtype=dtype)
    torch.matmul(a, b)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        torch.matmul(a, b)
        times.append(time.perf_counter() - start)
    return 2 * n**3 / statistics.median(times) / 1e9


def train_flops_per_sample(batch: int) -> float:
    """FLOPs of one training step (forward + backward) of the 1D CNN, per sample."""
    model = Cnn1d(BEAMS)
    x, y = torch.rand(batch, BEAMS) * 7, torch.randn(batch, 3)
    counter = FlopCounterMode(display=False)
    with counter:
        mae_loss(model(x), y).backward()
    return counter.get_total_flops() / batch


def pipeline_trainer_cfg() -> dict:
    """The pipeline's CPU trainer config (conf/trainer/cpu.yaml)."""
    return OmegaConf.to_container(OmegaConf.load(PIPELINE_TRAINER))


def pipeline_precision() -> str:
    """The precision `fit` trains in under the pipeline's CPU trainer config, on this machine."""
    return trainer_arguments(pipeline_trainer_cfg())["precision"]


def train_epochs(
    train_data, channels_last: bool, epochs: int, precision: str, compile_model: bool = False
) -> list[float]:
    """Wall seconds of each training epoch (Lightning loop, no validation, no checkpoints)."""
    L.seed_everything(0, verbose=False)
    module = PoseRegressor(Cnn1d(BEAMS, channels_last=channels_last), lr=0.006)
    if compile_model:
        module.model.compile()  # as fit does for trainer `compile: true`
    timer = EpochTimer()
    trainer = L.Trainer(
        accelerator="cpu",
        devices=1,
        precision=precision,
        max_epochs=epochs,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        callbacks=[timer],
    )
    if isinstance(train_data, DataLoader):
        trainer.fit(module, train_dataloaders=train_data)
    else:
        trainer.fit(module, datamodule=train_data)
    return timer.seconds


def loader_seconds(batches) -> float:
    start = time.perf_counter()
    for _x, _y in batches:
        pass
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny smoke run")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--batch", type=int, default=400)
    parser.add_argument(
        "--compile",
        action="store_true",
        help="also time ours under torch.compile (epochs after the first, which compiles)",
    )
    args = parser.parse_args()
    if args.quick:
        args.samples, args.epochs, args.batch = 300, 1, 100
    samples, epochs = args.samples, args.epochs
    threads = args.threads
    torch.set_num_threads(threads)
    logging_off()
    precision = pipeline_precision()
    size, repeats = (512, 3) if args.quick else (3072, 15)
    gflops = {"32-true": matmul_gflops(size, repeats)}
    if precision == "bf16-mixed":
        gflops[precision] = matmul_gflops(size, repeats, torch.bfloat16)
    flops = train_flops_per_sample(args.batch)
    print(
        f"threads {threads}; matmul GFLOP/s {gflops}; 1D CNN training {flops / 1e6:.1f} "
        f"MFLOP/sample; the pipeline trains in {precision}",
        flush=True,
    )
    with tempfile.TemporaryDirectory(prefix="scanloc-bench-") as tmp:
        dataset = write_synthetic_dataset(Path(tmp) / "scans", samples)
        ours = ScanDataModule(dataset, args.batch, seed=0)
        per_sample = PerSampleScans(dataset)
        baseline = DataLoader(per_sample, batch_size=args.batch, shuffle=True, num_workers=0)
        train_n = len(per_sample)
        rates: dict[str, float] = {}
        for name, data, layout, run_precision in (
            ("ours_default_malloc", ours, True, "32-true"),
            ("ours", ours, True, precision),
            ("dataloader", baseline, True, "32-true"),
            ("ours_fp32", ours, True, "32-true"),
            ("ours_contiguous", ours, False, "32-true"),
        ):
            if name == "ours":
                keep_freed_memory()
            seconds = train_epochs(data, layout, epochs, run_precision)
            rates[name] = train_n / statistics.median(seconds)
            print(
                f"{name:20s} {rates[name]:8.1f} samples/s  ({run_precision}; epochs: "
                f"{', '.join(f'{s:.2f}' for s in seconds)} s)",
                flush=True,
            )
        if args.compile:
            seconds = train_epochs(ours, True, epochs + 1, precision, compile_model=True)
            rates["ours_compiled"] = train_n / statistics.median(seconds[1:])
            compile_extra_s = seconds[0] - statistics.median(seconds[1:])
            print(
                f"{'ours_compiled':20s} {rates['ours_compiled']:8.1f} samples/s  ({precision}, "
                f"torch.compile; epochs: {', '.join(f'{s:.2f}' for s in seconds)} s)",
                flush=True,
            )
        ours.setup("fit")
        loader_ours = statistics.median(loader_seconds(ours.train_batches()) for _ in range(3))
        loader_base = statistics.median(loader_seconds(baseline) for _ in range(3))
        print(
            f"data path alone: ours {train_n / loader_ours:.0f} samples/s, DataLoader "
            f"{train_n / loader_base:.0f} samples/s",
            flush=True,
        )
    achieved = rates["ours"] * flops / 1e9
    achieved_fp32 = rates["ours_fp32"] * flops / 1e9
    result = {
        "samples_per_s": round(rates["ours"], 2),
        "baseline_samples_per_s": round(rates["dataloader"], 2),
        "speedup_vs_dataloader": round(rates["ours"] / rates["dataloader"], 3),
        "precision": precision,
        "data_path_speedup": round(rates["ours_fp32"] / rates["dataloader"], 3),
        "precision_speedup": round(rates["ours"] / rates["ours_fp32"], 3),
        "fp32_samples_per_s": round(rates["ours_fp32"], 2),
        "contiguous_layout_samples_per_s": round(rates["ours_contiguous"], 2),
        "default_malloc_samples_per_s": round(rates["ours_default_malloc"], 2),
        "layout_speedup": round(rates["ours_fp32"] / rates["ours_contiguous"], 3),
        "matmul_gflops": round(gflops[precision], 2),
        "fp32_matmul_gflops": round(gflops["32-true"], 2),
        "train_mflop_per_sample": round(flops / 1e6, 2),
        "achieved_gflops": round(achieved, 2),
        "ceiling_fraction": round(achieved / gflops[precision], 3),
        "fp32_ceiling_fraction": round(achieved_fp32 / gflops["32-true"], 3),
        "loader_only_speedup": round(loader_base / loader_ours, 1),
        "threads": threads,
        "train_samples": train_n,
        "batch_size": args.batch,
        "epochs": epochs,
    }
    if args.compile:
        result["compiled_samples_per_s"] = round(rates["ours_compiled"], 2)
        result["compile_speedup"] = round(rates["ours_compiled"] / rates["ours"], 3)
        result["compile_first_epoch_extra_s"] = round(compile_extra_s, 1)
    print(json.dumps(result))


def logging_off() -> None:
    """No Lightning banners or warnings between the figures."""
    import logging
    import warnings

    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    warnings.filterwarnings("ignore")
    sys.stderr.flush()


if __name__ == "__main__":
    main()
