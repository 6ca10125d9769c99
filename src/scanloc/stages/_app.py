"""What every stage entry point shares: Hydra wiring, quiet logging, and per-stage wall time."""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from scanloc.io import write_json

TIMING_DIR = Path("reports/timing")

# Lightning 2.6 on torch 2.13 warns about a torch-internal deprecation on every run; it is
# not actionable here and would bury the stages' own messages.
warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")


def conf_dir() -> str:
    """The Hydra config tree: `conf/` of the working directory (the repository root under DVC).

    SCANLOC_CONF overrides it, e.g. to run a stage from another folder.
    """
    return str(Path(os.environ.get("SCANLOC_CONF", Path.cwd() / "conf")).resolve())


def stage_main(config_name: str) -> Callable[[Callable[[DictConfig], Any]], Callable[[], Any]]:
    """`hydra.main` over the repository's conf/ with `config_name` as the primary config."""

    def decorate(task: Callable[[DictConfig], Any]) -> Callable[[], Any]:
        return hydra.main(version_base=None, config_path=conf_dir(), config_name=config_name)(task)

    return decorate


def to_dict(node: DictConfig) -> dict[str, Any]:
    """A resolved plain-dict copy of a config node, for library code and JSON outputs."""
    return OmegaConf.to_container(node, resolve=True)  # type: ignore[return-value]


def is_rank_zero() -> bool:
    """False in the extra processes of a multi-process (DDP) run, which re-run the stage's
    command with RANK / LOCAL_RANK set: only rank 0 writes a stage's outputs."""
    for key in ("RANK", "LOCAL_RANK"):
        if key in os.environ:
            return int(os.environ[key]) == 0
    return True


def output_paths(cfg: DictConfig) -> tuple[Path, Path, Path]:
    """(model folder, metrics file, timing folder) of a training stage: the configured ones
    under DVC; in a Hydra multirun the job's own folder, so sweeps never overwrite the
    pipeline's models and metrics."""
    hydra_cfg = HydraConfig.get()
    if hydra_cfg.mode == RunMode.MULTIRUN:
        job_dir = Path(hydra_cfg.runtime.output_dir)
        return job_dir / "model", job_dir / "metrics.json", job_dir
    return Path(cfg.out_dir), Path(cfg.metrics_path), TIMING_DIR


@contextmanager
def timed_stage(name: str, folder: Path = TIMING_DIR) -> Iterator[None]:
    """Record the stage's wall time in <folder>/<name>.json (under DVC: reports/timing/, a
    cache-less metric); rank 0 only."""
    start = time.perf_counter()
    yield
    if is_rank_zero():
        write_json(
            folder / f"{name}.json",
            {"stage": name, "wall_s": round(time.perf_counter() - start, 3)},
        )
