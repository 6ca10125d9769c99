"""A small learnable scan dataset in the data/scans/<name>/ format, for training tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanloc.data.scan_dataset import save_scan_dataset


def write_synthetic_scans(
    path: Path, count: int = 256, beams: int = 64, seed: int = 0, val_fraction: float = 0.25
) -> Path:
    """Ranges that are a smooth function of the pose, so every network can fit them."""
    rng = np.random.default_rng(seed)
    poses = np.column_stack(
        [rng.uniform(0, 10, count), rng.uniform(0, 10, count), rng.uniform(-np.pi, np.pi, count)]
    )
    angles = np.linspace(-2.0944, 2.0944, beams)
    ranges = (
        3.0
        + 1.5 * np.sin(2 * angles[None] + poses[:, 2:3])
        + 0.1 * poses[:, :1] * np.cos(angles[None])
        + 0.1 * poses[:, 1:2] * np.sin(angles[None])
    )
    is_val = np.zeros(count, dtype=bool)
    is_val[rng.permutation(count)[: round(val_fraction * count)]] = True
    meta = {"seed": seed, "sensor": {"num_beams": beams}}
    return save_scan_dataset(path, np.clip(ranges, 0.02, 7.0), poses, is_val, meta)
