"""Model files (model.pt, last.pt, snapshots): the networks' configs and weights in one
byte-reproducible format, and how to build, load and run a stored network."""

from __future__ import annotations

import copy
import inspect
import io
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, OmegaConf
from torch import nn

from scanloc.data.scan_dataset import ScanDataset
from scanloc.io import atomic_path

PathLike = str | os.PathLike[str]


def build_model(model_cfg: Mapping[str, Any]) -> nn.Module:
    """Instantiate a network from a config dict with `_target_`. A flat config (no nested
    `_target_`, no other `_..._` keys) calls the class directly: hydra.utils.instantiate
    would give it the same arguments, but first turns the config into OmegaConf nodes, which
    takes a second for a ScanLocNet whose pose grid lists thousands of cells."""
    target = _target_of(model_cfg)
    cfg = plain_config(model_cfg)
    if _needs_instantiate(cfg):
        return instantiate(cfg, _convert_="all")
    return get_class(target)(**{key: value for key, value in cfg.items() if key != "_target_"})


def _needs_instantiate(cfg: Any, top: bool = True) -> bool:
    """Whether a config holds what only hydra's instantiate handles: nested `_target_`s or
    special keys (`_partial_`, `_args_`, ...)."""
    if isinstance(cfg, dict):
        special = [key for key in cfg if str(key).startswith("_")]
        if special != (["_target_"] if top else []):
            return True
        return any(_needs_instantiate(value, top=False) for value in cfg.values())
    if isinstance(cfg, list):
        return any(_needs_instantiate(value, top=False) for value in cfg)
    return False


def plain_config(model_cfg: Mapping[str, Any]) -> dict[str, Any]:
    """A plain JSON-able copy (no OmegaConf nodes), as stored in model files."""
    if isinstance(model_cfg, DictConfig):
        model_cfg = OmegaConf.to_container(model_cfg, resolve=True)  # type: ignore[assignment]
    return json.loads(json.dumps(dict(model_cfg)))


def dataset_model_cfg(model_cfg: Mapping[str, Any], data: ScanDataset) -> dict[str, Any]:
    """model_cfg with the sensor geometry the network's constructor takes filled in from the
    dataset (num_beams; angle_min/angle_max for the 2D CNN) unless given; a num_beams that
    contradicts the data is an error."""
    cfg = plain_config(model_cfg)
    accepted = inspect.signature(get_class(_target_of(cfg))).parameters
    beams = int(data.ranges.shape[1])
    if cfg.setdefault("num_beams", beams) != beams:
        raise ValueError(
            f"{data.path}/ranges.npy: scans have {beams} beams, model_cfg says "
            f"num_beams={cfg['num_beams']}"
        )
    sensor = data.meta.get("sensor", {})
    for key in ("angle_min", "angle_max"):
        if key in accepted and key in sensor:
            cfg.setdefault(key, float(sensor[key]))
    return cfg


def _target_of(model_cfg: Mapping[str, Any]) -> str:
    if "_target_" not in model_cfg:
        raise ValueError(f"model_cfg needs a '_target_' (a class path), got keys {list(model_cfg)}")
    return str(model_cfg["_target_"])


def model_file_bytes(model_cfg: Mapping[str, Any], state_dict: Mapping[str, torch.Tensor]) -> bytes:
    """The model.pt format. Saved through memory: torch.save names its zip folder after the
    file, so saving to a temporary name would put that name into the bytes."""
    state = {k: v.detach().cpu().clone().contiguous() for k, v in state_dict.items()}
    buffer = io.BytesIO()
    torch.save({"model_cfg": copy.deepcopy(dict(model_cfg)), "state_dict": state}, buffer)
    return buffer.getvalue()


def save_model(path: PathLike, model_cfg: Mapping[str, Any], state_dict) -> None:
    """Write a model file atomically."""
    data = model_file_bytes(model_cfg, state_dict)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def read_model_file(path: PathLike) -> dict[str, Any]:
    """{"model_cfg", "state_dict"} of a model.pt, with errors that name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: model file not found")
    try:
        content = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for a damaged file
        raise ValueError(f"{path}: not a readable model file ({err})") from None
    if not isinstance(content, dict) or not {"model_cfg", "state_dict"} <= content.keys():
        raise ValueError(f"{path}: expected a dict with 'model_cfg' and 'state_dict'")
    return content


def load_model(path: PathLike) -> nn.Module:
    """The network stored in a model.pt, in eval mode on the CPU."""
    content = read_model_file(path)
    model = build_model(content["model_cfg"])
    model.load_state_dict(content["state_dict"])
    return model.eval()


def load_weights_(model: nn.Module, path: PathLike) -> None:
    """Copy the weights of a compatible model.pt into `model` (transfer learning)."""
    state = read_model_file(path)["state_dict"]
    own = model.state_dict()
    mismatched = [k for k in own if k not in state or state[k].shape != own[k].shape]
    if mismatched or len(state) != len(own):
        raise ValueError(
            f"{path}: 'state_dict' does not fit this model (missing or differently shaped: "
            f"{mismatched[:5]}; {len(state)} vs {len(own)} entries)"
        )
    model.load_state_dict(state)


@torch.no_grad()
def predict(model: nn.Module, ranges: np.ndarray, batch_size: int = 512) -> np.ndarray:
    """Poses (N, 3) float64 = (x, y, θ) predicted for scans `ranges` (N, beams), in eval mode."""
    ranges = np.asarray(ranges, dtype=np.float32)
    if ranges.ndim != 2:
        raise ValueError(f"ranges must have shape (N, beams), got {ranges.shape}")
    model.eval()
    device = next(model.parameters()).device
    out = [
        model(torch.from_numpy(ranges[i : i + batch_size]).to(device)).double().cpu()
        for i in range(0, len(ranges), batch_size)
    ]
    return torch.cat(out).numpy() if out else np.zeros((0, 3))


def count_parameters(model: nn.Module) -> int:
    """Trainable parameters (Keras' 'trainable params')."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


# ---------------------------------------------------------------- outputs
