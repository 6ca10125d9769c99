"""Training batches from a scan dataset (data/scans/<name>/), without per-sample Python work.

A dataset that fits in device memory is copied once into tensors on the training device, and
each batch is one gather `x[idx]`, `y[idx]` with an index slice of a per-epoch permutation.
Larger datasets fall back to gathering each batch from the memory-mapped file (same order,
same batches, so same results). The permutation depends only on (seed, epoch): training
that resumes at an epoch boundary sees exactly the batches an uninterrupted run sees.

Keras semantics: every epoch visits all training samples in a fresh random order, in batches
of `batch_size`, the last one smaller. Exception: a last batch of one sample is dropped
(training-mode BatchNorm cannot normalise a single sample). Under data-parallel training
(world_size > 1) each of the world_size processes takes batch_size / world_size samples of
every global batch, and an incomplete last global batch is dropped.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch import Tensor

from scanloc.data.scan_dataset import load_scan_dataset

Batch = tuple[Tensor, Tensor]
Gather = Callable[[Tensor], Batch]
RESIDENT_MAX_BYTES = 8 << 30


def epoch_permutation(n: int, seed: int, epoch: int) -> Tensor:
    """The order of the n training samples in `epoch` (int64, CPU; same on every machine)."""
    state = np.random.SeedSequence([seed, epoch]).generate_state(2, dtype=np.uint32)
    generator = torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))
    return torch.randperm(n, generator=generator)


def batch_slices(n: int, batch_size: int, rank: int = 0, world_size: int = 1) -> list[slice]:
    """Positions in the epoch's permutation that make up each of this process' batches."""
    if batch_size < 1 or world_size < 1 or batch_size % world_size:
        raise ValueError(
            f"batch_size ({batch_size}) must be a positive multiple of world_size ({world_size})"
        )
    if world_size == 1:
        slices = [slice(start, min(start + batch_size, n)) for start in range(0, n, batch_size)]
        if len(slices) > 1 and slices[-1].stop - slices[-1].start == 1:
            slices.pop()
        return slices
    local = batch_size // world_size
    return [
        slice(start + rank * local, start + (rank + 1) * local)
        for start in range(0, n - batch_size + 1, batch_size)
    ]


class EpochBatches:
    """One epoch of batches per iteration; Lightning calls `set_epoch` (via `.sampler`).

    `device` is where the batches live; the epoch's order is built on `index_device` (default:
    `device`), where `gather` indexes: on the device for resident data, on the CPU for the
    memory map (so no batch waits for a device-to-host copy of its indices).
    """

    batch_sampler = None  # Lightning inspects DataLoader-like objects for both attributes

    def __init__(
        self,
        gather: Gather,
        n: int,
        batch_size: int,
        seed: int | None,
        device: torch.device,
        rank: int = 0,
        world_size: int = 1,
        index_device: torch.device | None = None,
    ) -> None:
        self.gather, self.n, self.seed, self.device = gather, n, seed, device
        self.index_device = device if index_device is None else index_device
        self.rank, self.world_size = rank, world_size
        if seed is None:  # evaluation: every world_size-th sample, in order, nothing dropped
            local = len(range(rank, n, world_size))
            self.slices = [
                slice(s, min(s + batch_size, local)) for s in range(0, local, batch_size)
            ]
        else:
            self.slices = batch_slices(n, batch_size, rank, world_size)
        self.epoch = 0

    @property
    def sampler(self) -> EpochBatches:
        return self

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.slices)

    def __iter__(self) -> Iterator[Batch]:
        if self.seed is None:
            order = torch.arange(self.rank, self.n, self.world_size, device=self.index_device)
        else:
            order = epoch_permutation(self.n, self.seed, self.epoch).to(self.index_device)
        for part in self.slices:
            yield self.gather(order[part])


def resident_gather(x: Tensor, y: Tensor) -> Gather:
    return lambda idx: (x[idx], y[idx])


def memmap_gather(ranges: np.ndarray, targets: np.ndarray, rows: np.ndarray, device) -> Gather:
    """Batches read from the memory map; `rows` maps split positions to dataset rows."""

    def gather(idx: Tensor) -> Batch:
        picked = rows[idx.numpy()]
        x = torch.from_numpy(np.ascontiguousarray(ranges[picked]))
        y = torch.from_numpy(targets[picked])
        return x.to(device, non_blocking=True), y.to(device, non_blocking=True)

    return gather


class ScanDataModule(L.LightningDataModule):
    """Train/val batches of (ranges float32 (B, beams), pose float32 (B, 3)).

    Args:
        dataset_dir: a folder written by scanloc.data.scan_dataset.
        batch_size: samples per optimiser update (all processes together).
        seed: the data order's seed (epoch e uses epoch_permutation(n, seed, e)).
        max_samples: use only the first N samples of the dataset (its own split flags).
        eval_batch_size: validation batch size (default: batch_size).
        resident: keep the data in device memory (default: when it takes <= 8 GiB).
        device: where batches live when no Trainer is attached (default: the Trainer's device).
    """

    def __init__(
        self,
        dataset_dir: str | os.PathLike[str],
        batch_size: int,
        seed: int = 0,
        max_samples: int | None = None,
        eval_batch_size: int | None = None,
        resident: bool | None = None,
        device: str | torch.device | None = None,
    ) -> None:
        super().__init__()
        self.dataset_dir = Path(dataset_dir)
        self.batch_size, self.seed, self.max_samples = batch_size, seed, max_samples
        self.eval_batch_size = eval_batch_size or batch_size
        self.resident = resident
        self._device = None if device is None else torch.device(device)
        # Per split: the gather, the sample count and the device its indices live on.
        self._splits: dict[str, tuple[Gather, int, torch.device]] = {}

    @property
    def device(self) -> torch.device:
        if self._device is not None:
            return self._device
        if self.trainer is not None:
            return self.trainer.strategy.root_device
        return torch.device("cpu")

    def _rank_world(self) -> tuple[int, int]:
        if self.trainer is None:
            return 0, 1
        return self.trainer.global_rank, self.trainer.world_size

    def setup(self, stage: str | None = None) -> None:
        if self._splits:
            return
        data = load_scan_dataset(self.dataset_dir)
        if self.max_samples is not None and self.max_samples > len(data):
            raise ValueError(
                f"{self.dataset_dir}: max_samples={self.max_samples} but the dataset holds "
                f"only {len(data)} samples"
            )
        count = self.max_samples or len(data)
        is_val = np.asarray(data.is_val[:count])
        targets = np.asarray(data.poses[:count], dtype=np.float32)
        resident = self.resident
        if resident is None:
            resident = count * (data.ranges.shape[1] + 3) * 4 <= RESIDENT_MAX_BYTES
        for name, rows in (("train", np.flatnonzero(~is_val)), ("val", np.flatnonzero(is_val))):
            if rows.size == 0:
                raise ValueError(
                    f"{self.dataset_dir}/is_val.npy: no {name} samples among the first {count}"
                )
            if resident:
                x = torch.from_numpy(np.ascontiguousarray(data.ranges[rows])).to(self.device)
                y = torch.from_numpy(targets[rows]).to(self.device)
                gather, index_device = resident_gather(x, y), self.device
            else:
                gather = memmap_gather(data.ranges, targets, rows, self.device)
                index_device = torch.device("cpu")
            self._splits[name] = (gather, int(rows.size), index_device)

    @property
    def train_size(self) -> int:
        return self._splits["train"][1]

    @property
    def val_size(self) -> int:
        return self._splits["val"][1]

    def train_batches(self, seed: int | None = None) -> EpochBatches:
        """Shuffled training batches in the order of `seed` (default: the module's seed)."""
        gather, n, index_device = self._splits["train"]
        seed = self.seed if seed is None else seed
        rank, world = self._rank_world()
        return EpochBatches(
            gather, n, self.batch_size, seed, self.device, rank, world, index_device
        )

    def val_batches(self) -> EpochBatches:
        """Validation batches in dataset order."""
        gather, n, index_device = self._splits["val"]
        rank, world = self._rank_world()
        return EpochBatches(
            gather, n, self.eval_batch_size, None, self.device, rank, world, index_device
        )

    def train_dataloader(self) -> EpochBatches:
        return self.train_batches()

    def val_dataloader(self) -> EpochBatches:
        return self.val_batches()
