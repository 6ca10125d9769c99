"""Real scans in the learned localizer's training stream: a log's mapping part, with its
corrected laser poses, mixed into every epoch of simulated scans (conf/scanlocnet.yaml
`real_scans`). Simulated scans teach every pose of the map; the real ones what this laser and
this building look like (people, furniture, glass, the scanner's own artefacts) where the
simulator and the measured corruptions fall short. Only the dataset's training split is used:
its validation split (the log's tune hold-out) is where the share is chosen, and no scan of the
log's evaluation part is ever in the dataset (the `real` stage writes it)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanloc.data.scan_dataset import load_scan_dataset
from scanloc.scanlocnet.pose_grid import PoseGrid


@dataclass(frozen=True)
class RealScans:
    """Real scans with known laser poses (a log's mapping part) mixed into every epoch: `share`
    of the epoch's scans are replaced by real ones drawn from SeedSequence(seed, spawn_key=
    (epoch, 3)), so an epoch still depends on (seed, epoch) alone. `digest` names their bytes
    (the checkpoint key)."""

    ranges: np.ndarray  # float32 (M, B)
    poses: np.ndarray  # float64 (M, 3), laser poses inside the grid's cells
    share: float
    digest: str = ""

    def __post_init__(self) -> None:
        if not 0.0 < self.share <= 1.0:
            raise ValueError(f"real_scans.share: expected in (0, 1], got {self.share}")
        if not len(self.ranges) or len(self.ranges) != len(self.poses):
            raise ValueError(
                f"real_scans: expected as many poses as scans (> 0), got {len(self.poses)} poses "
                f"for {len(self.ranges)} scans"
            )

    def mix_into(
        self, ranges: np.ndarray, poses: np.ndarray, seed: int, epoch: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """The epoch's (ranges, poses) with round(share · N) rows replaced by real scans."""
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(epoch, 3)))
        count = round(self.share * len(ranges))
        rows = rng.choice(len(ranges), size=count, replace=False)
        picks = rng.choice(len(self.ranges), size=count, replace=count > len(self.ranges))
        ranges, poses = ranges.copy(), poses.copy()
        ranges[rows], poses[rows] = self.ranges[picks], self.poses[picks]
        return ranges, poses


def load_real_scans(dataset: Path, grid: PoseGrid, share: float, num_beams: int) -> RealScans:
    """The training split of a scan dataset of real scans, less the scans whose pose lies in no
    cell of the grid (a pose the free space's clearance leaves out cannot be a target)."""
    data = load_scan_dataset(dataset)
    rows = np.flatnonzero(~np.asarray(data.is_val))
    ranges = np.ascontiguousarray(data.ranges[rows], dtype=np.float32)
    if ranges.shape[1] != num_beams:
        raise ValueError(
            f"{dataset}/ranges.npy: {ranges.shape[1]} beams, the stream's sensor has {num_beams}"
        )
    poses = np.asarray(data.poses[rows], dtype=np.float64)
    inside = grid.encode(poses)["cell"] >= 0
    digest = hashlib.sha256(ranges[inside].tobytes() + poses[inside].tobytes()).hexdigest()
    return RealScans(ranges[inside], poses[inside], share, digest[:16])
