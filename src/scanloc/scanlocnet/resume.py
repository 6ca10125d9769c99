"""Stopping and resuming ScanLocNet's training (scanlocnet_training.fit_scanlocnet): the stop
signals, the key of a run's checkpoint folder, the per-epoch checkpoint and the RNG states it
keeps. As the paper's training (scanloc.models.training): a checkpoint resumes only the run
whose configuration, inputs and code it was written by.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import random
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Checkpoint

from scanloc.io import atomic_path
from scanloc.scanlocnet.scan_stream import StreamSpec
from scanloc.world.map_server import read_map_metadata

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# The code whose change must not resume an old checkpoint: the stage's DVC code deps and the
# pose sampling the stream uses (paths relative to the scanloc package).
CODE_DEPS = ("models", "data", "sensor", "world/free_space.py", "world/map_server.py", "pose.py")


class TrainingStopped(BaseException):
    """A stop signal during fit_scanlocnet (a BaseException, so that no `except Exception` on
    the way swallows it); fit_scanlocnet adds how far it got and where it resumes from."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum
        self.epochs = 0
        self.epochs_done: int | None = None
        self.checkpoint: Path | None = None

    def __str__(self) -> str:
        name = signal.Signals(self.signum).name
        if self.checkpoint is None:
            return f"stopped by {name}, nothing written; the same command starts it again"
        done = "" if self.epochs_done is None else f" after epoch {self.epochs_done}"
        return (
            f"stopped by {name}, nothing written; the same command resumes{done} of "
            f"{self.epochs} from {self.checkpoint}"
        )


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """In the main thread, the first SIGINT or SIGTERM raises TrainingStopped (also where the
    process inherited them ignored, as a script's background job does); later ones are
    ignored while the training shuts down. Lightning's SIGTERM handler calls this one too."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def stop(signum: int, frame: object) -> None:
        if not received:
            received.append(signum)
            raise TrainingStopped(signum)

    previous = {signum: signal.signal(signum, stop) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _digest(paths: Sequence[Path], root: Path | None = None) -> str:
    """SHA-256 of the files' bytes (and of their names relative to `root`, if given)."""
    digest = hashlib.sha256()
    for path in paths:
        if root is not None:
            digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def run_key(config: Mapping[str, Any], stream: StreamSpec, val_dataset: Path) -> str:
    """A short hash of everything that determines a training run's result: the config, the
    stream (but for the map's path: its bytes count), the map, the validation scans, the code."""
    package = Path(__file__).resolve().parents[1]
    code = sorted(
        f
        for part in CODE_DEPS
        for f in ([package / part] if part.endswith(".py") else (package / part).glob("*.py"))
    )
    names = ("meta.json", "ranges.npy", "poses.npy", "is_val.npy")
    content = {
        "config": config,
        "stream": dataclasses.asdict(stream) | {"map_yaml": None},
        "map": _digest([Path(stream.map_yaml), read_map_metadata(stream.map_yaml).image]),
        "val_dataset": _digest([val_dataset / name for name in names]),
        "code": _digest(code, package),
    }
    text = json.dumps(content, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@contextmanager
def run_dir(checkpoint_dir: Path | None, key: str) -> Iterator[Path]:
    """checkpoint_dir/<key>, or a temporary folder (removed afterwards): no resume."""
    if checkpoint_dir is not None:
        path = checkpoint_dir / key
        path.mkdir(parents=True, exist_ok=True)
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="scanloc-scanlocnet-") as tmp:
        yield Path(tmp)


class EpochCheckpoint(Checkpoint):
    """last.ckpt at every epoch's end, written atomically (a stop while writing keeps the
    previous one), then `saved()` (the epoch line: once it shows, a stop resumes after that
    epoch). A Checkpoint's hook runs after ScanLocModule's, which adds the history row."""

    def __init__(self, path: Path, saved: Callable[[], None]) -> None:
        self.path, self.saved = path, saved
        self.epochs_saved: int | None = None  # known once training (re)starts

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.epochs_saved = trainer.current_epoch if self.path.is_file() else 0

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        with atomic_path(self.path) as tmp:
            trainer.save_checkpoint(tmp, weights_only=False)
        self.epochs_saved = trainer.current_epoch + 1
        self.saved()


def rng_states() -> dict[str, Any]:
    """The global RNG states of torch (and CUDA's), numpy and Python, loadable by
    torch.load(weights_only=True) (numpy's key as a list)."""
    numpy_rng = np.random.get_state(legacy=False)  # noqa: NPY002 (the global state, saved)
    numpy_rng["state"]["key"] = numpy_rng["state"]["key"].tolist()
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_initialized() else [],
        "numpy": numpy_rng,
        "python": random.getstate(),
    }


def restore_rng_states(states: Mapping[str, Any]) -> None:
    """Set the global RNG states that rng_states() returned."""
    torch.set_rng_state(states["torch"])
    if states["cuda"]:
        torch.cuda.set_rng_state_all(states["cuda"])
    numpy_rng = dict(states["numpy"])
    numpy_rng["state"] = dict(numpy_rng["state"])
    numpy_rng["state"]["key"] = np.asarray(numpy_rng["state"]["key"], dtype=np.uint32)
    np.random.set_state(numpy_rng)  # noqa: NPY002 (the global state, restored)
    version, internal, gauss = states["python"]
    random.setstate((version, tuple(internal), gauss))
