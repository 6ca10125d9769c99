"""Ensemble members of one architecture trained together, in one process, in one loop.

The members' parameters and BatchNorm statistics are stacked along a leading member axis
(torch.func.stack_module_state) and one Adam updates the stack: Adam works element by element,
so this is M independent Adams with the same learning-rate schedule. Every member keeps what
makes it a separate model: its own seed (initialisation and global RNG stream for dropout),
its own data order (epoch_permutation(seed_k, epoch), as `fit` uses), its own Adam moments and
its own running statistics. Member k therefore ends (within float rounding) where
`training.fit(seed=seeds[k], ...)` ends; tests/test_stacked_ensemble.py checks this.

Two ways to run the members' forward/backward passes over the shared stack:
- "loop" (default): member after member through torch.func.functional_call on views of the
  stack, each member's RNG state swapped in around its forward pass (dropout masks equal to a
  lone run's, results bit-identical to `fit`). On CPU a member at batch 400 already fills the
  cores, so this is about as fast as training the members one after another
  (benchmarks/ensemble_train.py: 1.02x on 2 cores), with one data load and one process.
- "vmap": all members in one vectorised call (torch.func.vmap, randomness="different": dropout
  masks differ from a lone run's). Fewer, larger kernels, meant for GPUs (unmeasured here);
  0.6x on CPU, where vmap also rules out the faster channels-last layout.
Each member's out_dir receives the files `fit` writes (model.pt, last.pt, history.csv,
metrics.json); epoch_s there is the whole stack's epoch time.
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import lightning as L
import torch
from torch import Tensor, nn
from torch.func import functional_call, stack_module_state, vmap

from scanloc.data.datamodule import EpochBatches, ScanDataModule
from scanloc.data.scan_dataset import load_scan_dataset
from scanloc.hardware import training_device
from scanloc.models.lr_schedule import keras_decay
from scanloc.models.model_files import (
    PathLike,
    build_model,
    count_parameters,
    dataset_model_cfg,
    load_weights_,
    save_model,
)
from scanloc.models.pose_regressor import epoch_row, mae_loss, make_adam, pose_error_sums
from scanloc.models.trainer_setup import (
    compile_requested,
    keep_freed_memory,
    trainer_arguments,
    uses_cuda,
)
from scanloc.models.training import training_metrics, write_history, write_run_metrics

Mode = Literal["loop", "vmap"]


def _setup_torch(
    trainer_cfg: Mapping[str, Any] | None, device: str | None
) -> tuple[torch.device, bool]:
    """The training device and whether to train under bf16 autocast, with torch configured as
    fit's Trainer would configure it."""
    if compile_requested(trainer_cfg):
        raise ValueError("trainer compile: true is not supported by fit_stacked")
    args = trainer_arguments(trainer_cfg)  # also applies matmul_precision, resolves "auto"
    precision = args["precision"]
    if precision not in ("32-true", "bf16-mixed"):
        raise ValueError(
            f"trainer precision {precision!r}: fit_stacked trains in 32-true or bf16-mixed"
        )
    if device is None:
        device = "cuda" if uses_cuda(str(args["accelerator"])) else "cpu"
    deterministic = args["deterministic"]
    if deterministic:
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # as Lightning does
        torch.use_deterministic_algorithms(True, warn_only=deterministic == "warn")
    return torch.device(device), precision == "bf16-mixed"


class _RngStreams:
    """Each member's own global-RNG state (CPU, and CUDA when training there)."""

    def __init__(self, device: torch.device) -> None:
        self.cuda = device.type == "cuda"
        self.states: list[tuple[Tensor, Tensor | None]] = []

    def capture(self) -> None:
        self.states.append((torch.get_rng_state(), self._cuda_state()))

    def _cuda_state(self) -> Tensor | None:
        return torch.cuda.get_rng_state() if self.cuda else None

    def swap_in(self, k: int) -> None:
        cpu, cuda = self.states[k]
        torch.set_rng_state(cpu)
        if cuda is not None:
            torch.cuda.set_rng_state(cuda)

    def swap_out(self, k: int) -> None:
        self.states[k] = (torch.get_rng_state(), self._cuda_state())


class StackedMembers:
    """M copies of one architecture as stacked tensors, run one by one or vectorised.

    `params` holds the stacked parameters (M, ...) the optimiser updates, with their gradients
    in `.grad`. In "loop" mode every member works on its own leaf views of that storage, whose
    `.grad` are views of the stacked gradients: member k's backward writes straight into row k,
    right after its forward pass, so only one member's activations are alive at a time.
    """

    def __init__(
        self, models: Sequence[nn.Module], device: torch.device, mode: Mode, bf16: bool = False
    ) -> None:
        if mode not in ("loop", "vmap"):
            raise ValueError(f"mode must be 'loop' or 'vmap', got {mode!r}")
        self.mode, self.size = mode, len(models)
        self.device, self.bf16 = device, bf16
        params, buffers = stack_module_state(list(models))
        self.params = {k: v.detach().to(device) for k, v in params.items()}
        self.buffers = {k: v.to(device) for k, v in buffers.items()}
        self.template = copy.deepcopy(models[0]).to("meta")
        self.state_keys = list(models[0].state_dict().keys())
        # select, not unbind: BatchNorm updates the buffer views in place.
        self.member_buffers = [{k: v[i] for k, v in self.buffers.items()} for i in range(self.size)]
        if mode == "vmap":
            if hasattr(self.template, "channels_last"):
                self.template.channels_last = False
            for value in self.params.values():
                value.requires_grad_()
            return
        self.member_params = []
        for value in self.params.values():
            value.grad = torch.zeros_like(value)
        for i in range(self.size):
            views = {}
            for name, value in self.params.items():
                views[name] = value[i].detach().requires_grad_()
                views[name].grad = value.grad[i]
            self.member_params.append(views)

    def train(self, flag: bool = True) -> None:
        self.template.train(flag)

    def zero_grad(self) -> None:
        for value in self.params.values():
            if self.mode == "loop":
                value.grad.zero_()  # keeps the members' views of it
            else:
                value.grad = None

    def _call(self, params: dict, buffers: dict, x: Tensor) -> Tensor:
        # Forward passes under autocast as Lightning's bf16-mixed runs them; backward outside.
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.bf16):
            return functional_call(self.template, (params, buffers), (x,))

    def _vmapped(self, xs: Sequence[Tensor]) -> list[Tensor]:
        stacked = vmap(self._call, in_dims=(0, 0, 0), randomness="different")
        return list(stacked(self.params, self.buffers, torch.stack(list(xs))).unbind(0))

    def backward_each(
        self, batches: Sequence[tuple[Tensor, Tensor]], rng: _RngStreams | None = None
    ) -> list[Tensor]:
        """Forward and backward pass of member k on batches[k] (with member k's RNG stream, if
        given); returns the predictions."""
        if self.mode == "vmap":
            preds = self._vmapped([x for x, _ in batches])
            losses = [mae_loss(p, y) for p, (_, y) in zip(preds, batches, strict=True)]
            torch.stack(losses).sum().backward()
            return [p.detach() for p in preds]
        preds = []
        for k, (x, y) in enumerate(batches):
            if rng is not None:
                rng.swap_in(k)
            pred = self._call(self.member_params[k], self.member_buffers[k], x)
            if rng is not None:
                rng.swap_out(k)
            mae_loss(pred, y).backward()
            preds.append(pred.detach())
        return preds

    @torch.no_grad()
    def predict_each(self, x: Tensor) -> list[Tensor]:
        """Every member's output for the same batch x."""
        if self.mode == "vmap":
            return self._vmapped([x] * self.size)
        return [
            self._call(params, buffers, x)
            for params, buffers in zip(self.member_params, self.member_buffers, strict=True)
        ]

    def member_state(self, k: int) -> dict[str, Tensor]:
        """Member k's state dict (keys and order of the network's own state_dict)."""
        values = {**self.params, **self.buffers}
        return {key: values[key][k].detach().cpu().clone() for key in self.state_keys}


def _evaluate(members: StackedMembers, batches: EpochBatches) -> list[Tensor]:
    """Per member: the mean error vector (see pose_error_sums) over the validation set."""
    members.train(False)
    sums = [torch.zeros(3, dtype=torch.float64, device=batches.device) for _ in range(members.size)]
    for x, y in batches:
        for k, pred in enumerate(members.predict_each(x)):
            sums[k] += pose_error_sums(pred, y)
    return [(s / batches.n).cpu() for s in sums]


def fit_stacked(
    *,
    model_cfg: Mapping[str, Any],
    dataset_dir: PathLike,
    out_dirs: Sequence[PathLike],
    seeds: Sequence[int],
    epochs: int,
    batch_size: int,
    lr: float,
    lr_decay: float,
    max_samples: int | None = None,
    trainer_cfg: Mapping[str, Any] | None = None,
    device: str | None = None,
    mode: Mode = "loop",
    init_from: PathLike | None = None,
) -> list[dict[str, Any]]:
    """Train len(seeds) members of `model_cfg` together; member k writes into out_dirs[k].

    init_from: a compatible model.pt every member starts from (transfer learning, as `fit`'s);
    the members then differ only in their data order and dropout masks.

    trainer_cfg: conf/trainer/*.yaml; its accelerator picks the device (unless `device` is
    given), deterministic, matmul_precision and precision (32-true or bf16-mixed) apply.
    Returns each member's metrics (as written to its metrics.json).
    """
    if len(out_dirs) != len(seeds) or not seeds:
        raise ValueError(f"need one out_dir per seed, got {len(out_dirs)} and {len(seeds)}")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must differ (else members are identical): {list(seeds)}")
    if epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {epochs}")
    target, bf16 = _setup_torch(trainer_cfg, device)
    keep_freed_memory()
    data = ScanDataModule(dataset_dir, batch_size, max_samples=max_samples, device=target)
    model_cfg = dataset_model_cfg(model_cfg, load_scan_dataset(dataset_dir))
    rng = _RngStreams(target)
    models = []
    for seed in seeds:  # exactly fit's order: seed, then build (the init draws)
        L.seed_everything(seed, workers=True, verbose=False)
        model = build_model(model_cfg)
        if init_from is not None:
            load_weights_(model, init_from)
        models.append(model)
        rng.capture()
    members = StackedMembers(models, target, mode, bf16)
    optimizer = make_adam(list(members.params.values()), lr)
    schedule = keras_decay(optimizer, lr_decay)
    data.setup("fit")
    loaders = [data.train_batches(seed) for seed in seeds]
    val_batches = data.val_batches()
    histories: list[list[dict[str, float]]] = [[] for _ in seeds]
    best: list[tuple[float, dict[str, Tensor]]] = [(float("inf"), {}) for _ in seeds]
    seconds: list[float] = []
    for epoch in range(epochs):
        start = time.perf_counter()
        members.train(True)
        train_sums = [torch.zeros(3, dtype=torch.float64, device=target) for _ in seeds]
        seen = 0
        for loader in loaders:
            loader.set_epoch(epoch)
        for batches in zip(*loaders, strict=True):
            preds = members.backward_each(batches, rng)
            seen += batches[0][1].shape[0]
            for k, (pred, (_, y)) in enumerate(zip(preds, batches, strict=True)):
                train_sums[k] += pose_error_sums(pred, y)
            optimizer.step()
            schedule.step()
            members.zero_grad()
        val = _evaluate(members, val_batches)
        seconds.append(time.perf_counter() - start)
        rate = schedule.get_last_lr()[0]
        for k in range(len(seeds)):
            row = epoch_row(epoch + 1, (train_sums[k] / seen).cpu(), val[k], rate)
            histories[k].append(row)
            if row["val_mae"] < best[k][0]:
                best[k] = (row["val_mae"], members.member_state(k))
    counts = (data.train_size, data.val_size)
    results = []
    for k, out_dir in enumerate(map(Path, out_dirs)):
        metrics = training_metrics(histories[k], seconds, counts, count_parameters(models[k]))
        metrics["precision"] = "bf16-mixed" if bf16 else "32-true"
        metrics["stacked_members"] = len(seeds)
        metrics["device"] = training_device(target.type == "cuda")
        out_dir.mkdir(parents=True, exist_ok=True)
        save_model(out_dir / "model.pt", model_cfg, best[k][1])
        save_model(out_dir / "last.pt", model_cfg, members.member_state(k))
        write_history(out_dir / "history.csv", histories[k])
        write_run_metrics(out_dir, metrics)
        results.append(metrics)
    return results
