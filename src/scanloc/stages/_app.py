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


@contextmanager
def timed_stage(name: str, folder: Path = TIMING_DIR) -> Iterator[None]:
    """Record the stage's wall time in <folder>/<name>.json (under DVC: reports/timing/, a
    cache-less metric)."""
    start = time.perf_counter()
    yield
    write_json(
        folder / f"{name}.json",
        {"stage": name, "wall_s": round(time.perf_counter() - start, 3)},
    )
