"""The training objective shared by the MLP, 1D CNN and 2D CNN (paper-spec §5).

Loss: mean absolute error on the raw targets (x [m], y [m], θ [rad]), unscaled, as Keras'
`mean_absolute_error`; optimiser Adam (Keras defaults β = 0.9, 0.999, ε = 1e-8) with Keras'
per-update decay lr_t = lr_0 / (1 + decay·t). Per epoch it records the training and validation
MAE plus the mean position error (m) and mean wrapped heading error (degrees).

The error sums are accumulated in device tensors and read once per epoch, so training never
waits for the device between batches. `history` and the epoch times travel inside Lightning
checkpoints, as does the global RNG state (dropout masks continue exactly after a resume).
"""

from __future__ import annotations

import time
from typing import Any

import lightning as L
import torch
from torch import Tensor, nn

from scanloc.models.lr_schedule import keras_decay

ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8
HISTORY_COLUMNS = (
    "epoch",
    "train_mae",
    "train_pos_err_m",
    "train_heading_err_deg",
    "val_mae",
    "val_pos_err_m",
    "val_heading_err_deg",
    "lr",
)


def pose_error_sums(pred: Tensor, target: Tensor) -> Tensor:
    """float64 [Σ|error| over x, y, θ; Σ position error (m); Σ wrapped heading error (deg)]."""
    pred, target = pred.float(), target.float()
    diff = pred - target
    heading = torch.atan2(torch.sin(diff[:, 2]), torch.cos(diff[:, 2])).abs()
    return torch.stack(
        [
            diff.abs().sum(dtype=torch.float64),
            torch.linalg.vector_norm(diff[:, :2], dim=1).sum(dtype=torch.float64),
            torch.rad2deg(heading).sum(dtype=torch.float64),
        ]
    )


def mae_loss(pred: Tensor, target: Tensor) -> Tensor:
    """Keras' mean_absolute_error over the batch and the three outputs (computed in the wider
    of the two dtypes: float32 targets lift bf16/fp16 predictions)."""
    return (pred - target).abs().mean()


def make_adam(params, lr: float) -> torch.optim.Adam:
    return torch.optim.Adam(params, lr=lr, betas=ADAM_BETAS, eps=ADAM_EPS)


def epoch_row(epoch: int, train: Tensor, val: Tensor, lr: float) -> dict[str, float]:
    """A history row from per-sample mean error vectors (see pose_error_sums)."""
    t, v = train.tolist(), val.tolist()
    return {
        "epoch": epoch,
        "train_mae": t[0] / 3.0,
        "train_pos_err_m": t[1],
        "train_heading_err_deg": t[2],
        "val_mae": v[0] / 3.0,
        "val_pos_err_m": v[1],
        "val_heading_err_deg": v[2],
        "lr": lr,
    }


class PoseRegressor(L.LightningModule):
    """Wraps one of the networks (ranges (B, beams) → pose (B, 3)) for Lightning."""

    def __init__(self, model: nn.Module, lr: float, lr_decay: float = 0.0) -> None:
        super().__init__()
        if lr <= 0:
            raise ValueError(f"lr must be > 0, got {lr}")
        self.model = model
        self.lr, self.lr_decay = lr, lr_decay
        self.history: list[dict[str, float]] = []
        self.epoch_seconds: list[float] = []
        self._sums: dict[str, Tensor] = {}
        self._counts: dict[str, int] = {}
        self._epoch_start = 0.0

    def forward(self, ranges: Tensor) -> Tensor:
        return self.model(ranges)

    def configure_optimizers(self) -> dict[str, Any]:
        optimizer = make_adam(self.model.parameters(), self.lr)
        schedule = keras_decay(optimizer, self.lr_decay)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}

    def _reset(self, split: str) -> None:
        self._sums[split] = torch.zeros(3, dtype=torch.float64, device=self.device)
        self._counts[split] = 0

    def _accumulate(self, split: str, pred: Tensor, target: Tensor) -> None:
        self._sums[split] += pose_error_sums(pred.detach(), target)
        self._counts[split] += target.shape[0]

    def on_train_epoch_start(self) -> None:
        self._epoch_start = time.perf_counter()
        self._reset("train")

    def training_step(self, batch: tuple[Tensor, Tensor], batch_idx: int) -> Tensor:
        ranges, target = batch
        pred = self.model(ranges)
        self._accumulate("train", pred, target)
        return mae_loss(pred, target)

    def on_validation_epoch_start(self) -> None:
        self._reset("val")

    def validation_step(self, batch: tuple[Tensor, Tensor], batch_idx: int) -> None:
        ranges, target = batch
        self._accumulate("val", self.model(ranges), target)

    def _mean_errors(self, split: str) -> Tensor:
        """Per-sample mean error vector over all processes (one device sync)."""
        reduce = self.trainer.strategy.reduce
        sums = reduce(self._sums[split], reduce_op="sum")
        count = torch.tensor(float(self._counts[split]), device=self.device)
        count = reduce(count, reduce_op="sum")
        return (sums / count).cpu()

    def on_validation_epoch_end(self) -> None:
        if self.trainer.sanity_checking or "train" not in self._sums:
            return
        val = self._mean_errors("val")
        train = self._mean_errors("train")
        lr = self.lr_schedulers().get_last_lr()[0]
        row = epoch_row(self.current_epoch + 1, train, val, lr)
        self.history.append(row)
        self.epoch_seconds.append(time.perf_counter() - self._epoch_start)
        for key in ("train_mae", "val_mae", "val_pos_err_m", "val_heading_err_deg"):
            # Already reduced: sync_dist only averages equal values (and silences a warning).
            self.log(key, row[key], on_epoch=True, sync_dist=True, batch_size=1)
        del self._sums["train"]

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["scanloc"] = {
            "history": list(self.history),
            "epoch_seconds": list(self.epoch_seconds),
            "torch_rng": torch.get_rng_state(),
            "cuda_rng": torch.cuda.get_rng_state_all() if torch.cuda.is_initialized() else [],
        }

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        state = checkpoint.get("scanloc")
        if state is None:
            return
        self.history = list(state["history"])
        self.epoch_seconds = list(state["epoch_seconds"])
        torch.set_rng_state(state["torch_rng"])
        if state["cuda_rng"]:
            torch.cuda.set_rng_state_all(state["cuda_rng"])
