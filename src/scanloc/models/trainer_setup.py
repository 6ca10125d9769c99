"""The Lightning Trainer's arguments for this machine: defaults, precision ("auto": bf16 where
the hardware multiplies it natively), torch.compile, and the process-wide settings a training
run makes (glibc's memory reuse, Lightning's banner lines)."""

from __future__ import annotations

import ctypes
import functools
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from scanloc.progress import interactive

TRAINER_DEFAULTS: dict[str, Any] = {
    "accelerator": "cpu",
    "devices": 1,
    "precision": "32-true",
    "deterministic": True,
}
# Trainer arguments that fit sets itself.
_FIXED_TRAINER_KEYS = {
    "max_epochs",
    "logger",
    "callbacks",
    "default_root_dir",
    "enable_checkpointing",
    "num_sanity_val_steps",
    "check_val_every_n_epoch",
}


def trainer_arguments(trainer_cfg: Mapping[str, Any] | None) -> dict[str, Any]:
    """Trainer kwargs: TRAINER_DEFAULTS updated by trainer_cfg (conf/trainer/*.yaml).

    `matmul_precision` is not a Trainer argument: it sets torch.set_float32_matmul_precision.
    `compile` is not one either: `fit` reads it (see compile_requested).
    `precision: auto` becomes a Lightning precision here (see resolve_precision).
    """
    cfg = dict(trainer_cfg or {})
    clash = sorted(_FIXED_TRAINER_KEYS & cfg.keys())
    if clash:
        raise ValueError(f"trainer_cfg: {clash} are set by scanloc.models.training.fit")
    cfg.pop("compile", None)
    matmul = cfg.pop("matmul_precision", None)
    if matmul is not None:
        torch.set_float32_matmul_precision(matmul)
    args = {**TRAINER_DEFAULTS, **cfg}
    args["precision"] = resolve_precision(args["precision"], str(args["accelerator"]))
    return args


def resolve_precision(precision: Any, accelerator: str) -> str:
    """Lightning's precision string; "auto" is bf16-mixed where the hardware multiplies bf16
    natively, else 32-true.

    Natively means bf16 dot-product instructions (x86 avx512_bf16 or AMX) on the CPU, or a GPU
    with bf16 tensor cores. There bf16 autocast trains the 1D CNN 1.8-2x faster than float32
    on CPU; 4 seeds per precision showed no significant difference of the mean validation MAE
    (a Welch test, benchmarks/precision_noise.py), which is not a proof of equivalence.
    Elsewhere bf16 would be emulated, and slower.
    """
    precision = str(precision)
    if precision != "auto":
        return precision
    if uses_cuda(accelerator):
        native = torch.cuda.is_available() and torch.cuda.is_bf16_supported(
            including_emulation=False
        )
    else:
        native = cpu_has_native_bf16()
    return "bf16-mixed" if native else "32-true"


def uses_cuda(accelerator: str) -> bool:
    """Whether a Trainer with this `accelerator` trains on a CUDA device."""
    return accelerator in ("gpu", "cuda") or (accelerator == "auto" and torch.cuda.is_available())


def compile_requested(trainer_cfg: Mapping[str, Any] | None) -> bool:
    """trainer_cfg `compile: true`: the network's forward goes through torch.compile (in place,
    so state dicts keep their keys). Meant for GPUs; on 2 CPU cores it trained the 1D CNN
    0.83x as fast after a 21 s compilation, so the CPU config leaves it off."""
    value = dict(trainer_cfg or {}).get("compile", False)
    if not isinstance(value, bool):
        raise ValueError(f"trainer_cfg compile: expected true or false, got {value!r}")
    return value


@functools.cache
def cpu_has_native_bf16() -> bool:
    """Whether this CPU has bf16 dot-product instructions (Linux: /proc/cpuinfo flags)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    flags = next(
        (line.split(":", 1)[1].split() for line in text.splitlines() if line.startswith("flags")),
        [],
    )
    return "avx512_bf16" in flags or "amx_bf16" in flags


def keep_freed_memory() -> bool:
    """Let glibc keep freed memory for reuse instead of handing it back to the OS at once.

    A training step frees and re-allocates activation blocks of tens of MB. With glibc's
    defaults each is a fresh mmap whose pages fault in again at every step: the 1D CNN at
    batch 400 on CPU spent ~40 % of its time in the kernel and trained 1.7x slower. Raising the
    mmap and trim thresholds to 1 GiB keeps such blocks in the heap. Process-wide; returns
    False where it does not apply (no glibc).
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # from malloc.h
    return bool(libc.mallopt(m_mmap_threshold, 1 << 30) and libc.mallopt(m_trim_threshold, 1 << 30))


def quiet_lightning() -> None:
    """Keep Lightning's banner lines (GPU available, TPU...) out of non-interactive logs."""
    if not interactive():
        for name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.seed"):
            logging.getLogger(name).setLevel(logging.WARNING)
