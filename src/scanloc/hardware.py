"""What machine a stage ran on: CPU model and cores, NVIDIA GPUs. Recorded beside every timing
figure (training metrics, the report's provenance), because seconds mean nothing without it."""

from __future__ import annotations

import os
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

# Figures of a training run that depend on the machine, not on the parameters: wall seconds
# per epoch and in all, and the device. Stages write them to their timing file (shown by `dvc
# metrics show`, never hashed into dvc.lock), so that every hashed metrics file is the same
# bytes on every machine of the same arithmetic.
MACHINE_KEYS = ("epoch_s", "train_s", "device")


def split_machine_figures(metrics: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the metrics without MACHINE_KEYS, the MACHINE_KEYS found), nested mappings (e.g. an
    ensemble's per-member metrics) split alike."""
    kept: dict[str, Any] = {}
    machine: dict[str, Any] = {}
    for key, value in metrics.items():
        if key in MACHINE_KEYS:  # whole, also when it is a mapping (the device)
            machine[key] = value
        elif isinstance(value, Mapping):
            kept[key], inner = split_machine_figures(value)
            if inner:
                machine[key] = inner
        else:
            kept[key] = value
    return kept, machine


def cpu_model() -> str:
    """The CPU's model name (Linux /proc/cpuinfo), else what `platform` knows."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def nvidia_gpus() -> list[str]:
    """Model names of the NVIDIA GPUs the driver lists (/proc/driver/nvidia), without CUDA."""
    names = []
    for info in sorted(Path("/proc/driver/nvidia/gpus").glob("*/information")):
        names += [
            line.split(":", 1)[1].strip()
            for line in info.read_text().splitlines()
            if line.startswith("Model")
        ]
    return names


def describe_machine() -> str:
    """One line: CPU model, logical cores and GPUs (or "no GPU")."""
    gpus = nvidia_gpus()
    gpu = ", GPU " + "; ".join(gpus) if gpus else ", no GPU"
    return f"{cpu_model()}, {os.cpu_count()} logical cores{gpu}"


def training_device(on_cuda: bool) -> dict[str, Any]:
    """The device a training run used: {"type": "cuda", "name", "count"} or
    {"type": "cpu", "name", "cores", "threads"} (torch's intra-op threads)."""
    import torch

    if on_cuda and torch.cuda.is_available():
        return {
            "type": "cuda",
            "name": torch.cuda.get_device_name(0),
            "count": torch.cuda.device_count(),
        }
    return {
        "type": "cpu",
        "name": cpu_model(),
        "cores": os.cpu_count(),
        "threads": torch.get_num_threads(),
    }


def device_sentence(device: Any) -> str:
    """A training metrics file's `device` entry in words, e.g. "CPU AMD EPYC 7B13 (2 cores)"."""
    if not isinstance(device, dict) or "type" not in device:
        return "an unrecorded device"
    if device["type"] == "cuda":
        count = int(device.get("count", 1))
        return f"GPU {device.get('name', '?')}" + (f" (×{count})" if count > 1 else "")
    return f"CPU {device.get('name', '?')} ({device.get('cores', '?')} cores)"
