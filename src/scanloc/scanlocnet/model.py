"""scanloc's own learned localizer (beyond the paper): ranked pose hypotheses from one scan.

A single regressed pose cannot be right where several poses explain the same scan (a symmetric
map), and plain regression trains slowly. ScanLocNet instead classifies: the pose space is the
map's `PoseGrid` (cells over the free space × heading bins), and

    p(cell, bin | scan) = p(cell | scan) · p(bin | cell, scan),

each hypothesis refined by offsets inside its cell and bin, with a predicted standard deviation
for each of x, y and θ. The network:
- input: the ranges scaled by range_max (no-return readings, above range_max, set to 1) and a
  no-return flag, as two channels;
- trunk: 1D convolutions with stride 2 (BatchNorm, ReLU), flattened, two dense layers;
- cell head: one logit per cell of the grid (so the output size follows the map);
- conditional head: from the trunk's features and a learnt embedding of a cell, the heading
  bins' logits, a heading offset per bin, the position offset in that cell and log standard
  deviations of x, y, θ.
Training needs the conditional head at the true cell only; decoding evaluates it for the most
likely cells, and `top_k` finds the K best (cell, bin) pairs exactly (branch and bound: a cell's
joint probability never exceeds its own, so cells are visited best first until the next cell
cannot beat the K-th hypothesis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import torch
from torch import Tensor, nn

from scanloc.pose import wrap_pi
from scanloc.scanlocnet.pose_grid import DECODE_BATCH, PoseGrid

LOG_STD_RANGE = (-6.0, 2.0)  # clamp of the predicted log standard deviations (in offset units)


class ScanLocNet(nn.Module):
    """The network (see the module docstring); `grid` is the map's PoseGrid as a dict."""

    def __init__(
        self,
        num_beams: int,
        range_max: float,
        grid: dict,
        channels: tuple[int, ...] = (32, 64, 128, 128, 256),
        kernels: tuple[int, ...] = (5, 5, 3, 3, 3),
        features: int = 512,
        cell_embedding: int = 64,
        hidden: int = 256,
    ) -> None:
        super().__init__()
        if len(channels) != len(kernels):
            raise ValueError(f"channels {channels} and kernels {kernels} differ in length")
        self.num_beams = int(num_beams)
        self.range_max = float(range_max)
        self.grid = PoseGrid.from_dict(grid)
        layers: list[nn.Module] = []
        width, length = 2, self.num_beams
        for out, k in zip(channels, kernels, strict=True):
            # A (1 x k) Conv2D on channels-last (B, C, 1, L): the layout oneDNN trains fastest
            # on CPU (as the paper's 1D CNN here, cnn1d.py); the same function as a Conv1D.
            layers += [
                nn.Conv2d(width, out, (1, k), stride=(1, 2), padding=(0, k // 2), bias=False),
                nn.BatchNorm2d(out),
                nn.ReLU(inplace=True),
            ]
            width, length = out, (length + 2 * (k // 2) - k) // 2 + 1
        self.trunk = nn.Sequential(*layers)
        self.dense = nn.Sequential(
            nn.Flatten(),
            nn.Linear(width * length, features, bias=False),
            nn.BatchNorm1d(features),
            nn.ReLU(inplace=True),
            nn.Linear(features, features),
            nn.ReLU(inplace=True),
        )
        bins = self.grid.heading_bins
        self.cell_head = nn.Linear(features, self.grid.num_cells)
        self.cell_embedding = nn.Embedding(self.grid.num_cells, cell_embedding)
        self.conditional = nn.Sequential(
            nn.Linear(features + cell_embedding, hidden),
            nn.ReLU(inplace=True),
            nn.Linear(hidden, hidden),
            nn.ReLU(inplace=True),
            nn.Linear(hidden, 2 * bins + 5),
        )

    def features(self, ranges: Tensor) -> Tensor:
        """Trunk features (B, F) of raw ranges (B, beams) in metres."""
        if ranges.ndim != 2 or ranges.shape[1] != self.num_beams:
            raise ValueError(
                f"scans must have shape (B, {self.num_beams}), got {tuple(ranges.shape)}"
            )
        no_return = ranges > self.range_max
        scaled = torch.where(no_return, 1.0, ranges / self.range_max)
        x = torch.stack([scaled, no_return.to(scaled.dtype)], dim=1).unsqueeze(2)
        x = x.contiguous(memory_format=torch.channels_last)
        return self.dense(self.trunk(x))

    def cell_logits(self, feats: Tensor) -> Tensor:
        return self.cell_head(feats)

    def conditional_outputs(self, feats: Tensor, cells: Tensor) -> dict[str, Tensor]:
        """Heading logits (..., H), heading offsets (..., H), position offset (..., 2) and log
        standard deviations (..., 3: x, y in cells; θ in bins) for feats (B, F) and cells (B,)
        or (B, M)."""
        if cells.ndim == 2:
            f = feats[:, None, :].expand(-1, cells.shape[1], -1)
        else:
            f = feats
        out = self.conditional(torch.cat([f, self.cell_embedding(cells)], dim=-1)).float()
        bins = self.grid.heading_bins
        return {
            "bin_logits": out[..., :bins],
            "bin_offsets": torch.tanh(out[..., bins : 2 * bins]) * 0.5,
            "offset": torch.tanh(out[..., 2 * bins : 2 * bins + 2]) * 0.5,
            "log_std": out[..., 2 * bins + 2 :].clamp(*LOG_STD_RANGE),
        }

    def forward(self, ranges: Tensor) -> Tensor:
        """Cell logits (B, C): what a traced or exported model returns."""
        return self.cell_logits(self.features(ranges))


@dataclass(frozen=True)
class Hypotheses:
    """The K best pose hypotheses of each of N scans.

    Attributes:
        poses: (N, K, 3) x, y, θ.
        weights: (N, K) joint probabilities p(cell, bin | scan), best first.
        stds: (N, K, 3) predicted standard deviations of x [m], y [m], θ [rad].
        scores: (N, K) after verification against the map (localize.hypothesis_verification),
            the calibrated probability that each hypothesis is right, best first; else None.
    """

    poses: np.ndarray
    weights: np.ndarray
    stds: np.ndarray
    scores: np.ndarray | None = None

    def covariances(self) -> np.ndarray:
        """(N, K, 3, 3) diagonal covariances."""
        cov = np.zeros((*self.stds.shape, 3))
        idx = np.arange(3)
        cov[..., idx, idx] = self.stds**2
        return cov


@torch.inference_mode()
def top_k(
    model: ScanLocNet,
    ranges: np.ndarray | Tensor,
    k: int,
    batch_size: int = DECODE_BATCH,
    chunk: int = 16,
) -> Hypotheses:
    """The exact K best (cell, bin) hypotheses of each scan, by branch and bound over cells.

    Cells are visited in decreasing p(cell) in chunks; a scan is done once the K-th best joint
    probability found is at least the next cell's p(cell), which bounds every joint probability
    left. The K best found so far are kept as they come (merging each chunk into them), so a
    scan whose scores are flat, an untrained network's, visits every cell in linear time.
    Scans must be finite (the network cannot read NaN).
    """
    if model.training:  # eval() walks every module: 0.5 ms, a tenth of one scan's decoding
        model.eval()
    ranges = torch.as_tensor(np.asarray(ranges, dtype=np.float32))
    if ranges.ndim != 2 or ranges.shape[1] != model.num_beams:
        raise ValueError(f"scans must have shape (N, {model.num_beams}), got {tuple(ranges.shape)}")
    if not torch.isfinite(ranges).all():
        raise ValueError(
            "scans contain NaN or infinite ranges; the learned localizer needs finite readings "
            "(no return as the sensor's fill value)"
        )
    grid = model.grid
    k = min(k, grid.num_cells * grid.heading_bins)
    parts = [
        _top_k_batch(model, ranges[s : s + batch_size], k, chunk)
        for s in range(0, len(ranges), batch_size)
    ]
    if not parts:
        return Hypotheses(np.zeros((0, k, 3)), np.zeros((0, k)), np.zeros((0, k, 3)))
    return Hypotheses(
        *(np.concatenate([getattr(p, f) for p in parts]) for f in ("poses", "weights", "stds"))
    )


def _top_k_batch(model: ScanLocNet, batch: Tensor, k: int, chunk: int) -> Hypotheses:
    grid = model.grid
    n, bins = len(batch), grid.heading_bins
    feats = model.features(batch)
    p_cell = torch.softmax(model.cell_logits(feats).float(), dim=-1)
    order = torch.argsort(p_cell, dim=-1, descending=True, stable=True)
    active = torch.ones(n, dtype=torch.bool)
    best = torch.zeros((n, 0))  # the K best joint probabilities found so far, per scan
    fields: dict[str, list[Tensor]] = {
        "joint": [],
        "cell": [],
        "offset": [],
        "bin_offsets": [],
        "log_std": [],
    }
    for first in range(0, grid.num_cells, chunk):
        cells = order[:, first : first + chunk]
        m = cells.shape[1]
        rows = torch.nonzero(active).squeeze(1)
        joint = torch.full((n, m, bins), -1.0)  # rows already done take no new candidates
        offset, bin_offsets = torch.zeros((n, m, 2)), torch.zeros((n, m, bins))
        log_std = torch.zeros((n, m, 3))
        cond = model.conditional_outputs(feats[rows], cells[rows])
        joint[rows] = p_cell[rows[:, None], cells[rows]][..., None] * torch.softmax(
            cond["bin_logits"], dim=-1
        )
        offset[rows], bin_offsets[rows] = cond["offset"], cond["bin_offsets"]
        log_std[rows] = cond["log_std"]
        for name, value in zip(fields, (joint, cells, offset, bin_offsets, log_std), strict=True):
            fields[name].append(value)
        last = first + m
        if last >= grid.num_cells:
            break
        best = torch.cat([best, joint.reshape(n, -1)], dim=1)
        if best.shape[1] > k:
            best = torch.topk(best, k, dim=1).values
        if best.shape[1] < k:
            continue
        kth = best.min(dim=1).values
        active = kth < p_cell[torch.arange(n), order[:, last]]
        if not active.any():
            break
    cat = {name: torch.cat(values, dim=1) for name, values in fields.items()}
    flat = cat["joint"].reshape(n, -1)
    best = torch.topk(flat, k, dim=1)
    m_idx, b_idx = best.indices // bins, best.indices % bins
    rows = torch.arange(n)[:, None]
    poses = grid.decode(
        cat["cell"][rows, m_idx].numpy(),
        cat["offset"][rows, m_idx].numpy(),
        b_idx.numpy(),
        cat["bin_offsets"][rows, m_idx, b_idx].numpy(),
    )
    scale = np.array([grid.cell_size, grid.cell_size, grid.bin_width])
    stds = np.exp(cat["log_std"][rows, m_idx].numpy().astype(np.float64)) * scale
    return Hypotheses(poses, best.values.numpy().astype(np.float64), stds)


def suppress_duplicates(hyp: Hypotheses, distance: float, angle: float, k: int) -> Hypotheses:
    """Non-maximum suppression: drop a hypothesis within `distance` m and `angle` rad of a better
    one of the same scan (its weight goes to that one), then keep the k best."""
    kept, weights = _suppress(hyp.poses, hyp.weights, distance, angle, k)
    n = len(kept)
    rows = np.arange(n)[:, None]
    index = np.maximum(kept, 0)
    valid = (kept >= 0)[..., None]
    poses = np.where(valid, hyp.poses[rows, index], 0.0)
    stds = np.where(valid, hyp.stds[rows, index], 0.0)
    return Hypotheses(poses, weights, stds)


@numba.njit(cache=True)
def _suppress(
    poses: np.ndarray, weights: np.ndarray, distance: float, angle: float, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """suppress_duplicates' indices (N, k) of the kept hypotheses (-1: none) and their weights."""
    n, total = weights.shape
    kept = np.full((n, k), -1, dtype=np.int64)
    out = np.zeros((n, k))
    for i in range(n):
        order = np.empty(total, dtype=np.int64)
        gained = np.zeros(total)
        count = 0
        for j in range(total):
            duplicate = False
            for c in range(count):
                q = order[c]
                d = math.hypot(poses[i, j, 0] - poses[i, q, 0], poses[i, j, 1] - poses[i, q, 1])
                a = abs(wrap_pi(poses[i, j, 2] - poses[i, q, 2]))
                if d <= distance and a <= angle:
                    gained[q] += weights[i, j]
                    duplicate = True
                    break
            if not duplicate:
                order[count] = j
                count += 1
        found = min(count, k)
        for c in range(found):
            kept[i, c] = order[c]
            out[i, c] = weights[i, order[c]] + gained[order[c]]
    return kept, out
