"""What every stage entry point shares: Hydra wiring, where outputs go, per-stage wall time, and
how a user's mistake is reported.

A user's mistake (a bad file, field, topic or setting: ValueError and its kinds, a missing
file, a missing or unknown config value) prints its message, which names the file, the field
and what was expected, and exits with status 2, without a traceback; SCANLOC_TRACEBACK=1 shows
the traceback too. Anything else is a bug and keeps its traceback, and so does a job of a
multirun, whose failure the sweep records (scanloc.sweep_summary).

Where outputs go: a stage's config lists the keys it writes (`outputs`). Under DVC (which sets
DVC_STAGE for every stage command) they are the pipeline's tracked paths. A run by hand, or a
job of a Hydra multirun, writes them under its own Hydra folder instead (runs/<stage>/<its
overrides>/ or the multirun job's folder), so that it never overwrites what DVC tracks; an
output key given on the command line is used as given.
"""

from __future__ import annotations

import hashlib
import os
import re
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import ConfigAttributeError, ConfigKeyError, MissingMandatoryValue

from scanloc.io import write_json

# Lightning 2.6 on torch 2.13 warns about a torch-internal deprecation on every run; it is
# not actionable here and would bury the stages' own messages.
warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")


# The overrides that name what a run by hand is about, first found first used (run_folder).
ENTRY_KEYS = ("name", "map_name", "log_name", "map.name", "dataset.map", "experiment", "trajectory",
              "init", "dataset", "study", "map", "bag", "log")  # fmt: skip


def run_folder(override_dirname: str) -> str:
    """The folder name of a run by hand (runs/<stage>/<this>/, conf/_common.yaml): its entry's
    name and a short hash of all its overrides (`office-3fa2c1d0`), not the overrides
    themselves, whose paths would nest folders; Hydra keeps them in the folder's
    .hydra/overrides.yaml."""
    if not override_dirname:
        return "default"
    digest = hashlib.sha1(override_dirname.encode()).hexdigest()[:8]
    given = dict(item.partition("=")[::2] for item in override_dirname.split(","))
    entry = next((given[key] for key in ENTRY_KEYS if given.get(key)), "run")
    readable = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(entry.rstrip("/")).name).strip("._") or "run"
    return f"{readable[:40]}-{digest}"


OmegaConf.register_new_resolver("run_folder", run_folder, replace=True)


# A user's mistake, not a bug (module docstring); the library raises these with messages that
# name the file, the field and what was expected.
USER_ERRORS: tuple[type[BaseException], ...] = (
    ValueError,
    FileNotFoundError,
    NotADirectoryError,
    IsADirectoryError,
    PermissionError,
    MissingMandatoryValue,
    ConfigKeyError,
    ConfigAttributeError,
)
USER_ERROR_STATUS = 2


def user_error_exit(program: str, err: BaseException) -> None:
    """Print a user's mistake as `<program>: error: <message>` and exit with USER_ERROR_STATUS,
    unless SCANLOC_TRACEBACK is set (then the caller re-raises for the traceback)."""
    if os.environ.get("SCANLOC_TRACEBACK", "") not in ("", "0"):
        return
    message = str(err) or type(err).__name__
    if isinstance(err, MissingMandatoryValue):
        message = f"config field '{err.full_key}': expected a value (give {err.full_key}=...)"
    elif isinstance(err, ConfigKeyError | ConfigAttributeError):
        message = f"config field '{err.full_key}': {message.splitlines()[0]}"
    print(
        f"{program}: error: {message}\n(SCANLOC_TRACEBACK=1 shows where it was raised)",
        file=sys.stderr,
    )
    raise SystemExit(USER_ERROR_STATUS)


def module_name(module: str) -> str:
    """A module's importable name, also for the one run as `python -m` (named __main__)."""
    if module == "__main__":
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        return spec.name if spec is not None else Path(sys.argv[0]).stem
    return module


def reporting_user_errors(program: str, main: Callable[..., Any]) -> Callable[..., Any]:
    """`main` with a user's mistake reported as user_error_exit does (module docstring)."""

    def checked(*args: Any, **kwargs: Any) -> Any:
        try:
            return main(*args, **kwargs)
        except USER_ERRORS as err:
            user_error_exit(program, err)
            raise

    return checked


def conf_dir() -> str:
    """The Hydra config tree: `conf/` of the working directory (the repository root under DVC).

    SCANLOC_CONF overrides it, e.g. to run a stage from another folder.
    """
    return str(Path(os.environ.get("SCANLOC_CONF", Path.cwd() / "conf")).resolve())


def stage_main(config_name: str) -> Callable[[Callable[[DictConfig], Any]], Callable[[], Any]]:
    """`hydra.main` over the repository's conf/ with `config_name` as the primary config; the
    outputs are redirected first (see the module docstring)."""

    def decorate(task: Callable[[DictConfig], Any]) -> Callable[[], Any]:
        def run(cfg: DictConfig) -> Any:
            redirect_outputs(cfg)
            if HydraConfig.get().mode == RunMode.MULTIRUN:
                return task(cfg)  # a failed job is the sweep's to record (sweep_summary)
            return reporting_user_errors(module_name(task.__module__), task)(cfg)

        run.__name__, run.__module__ = task.__name__, task.__module__
        main = hydra.main(version_base=None, config_path=conf_dir(), config_name=config_name)(run)

        def named_main() -> Any:
            # Hydra names the job after the file that defines the decorated function (this
            # one, for every stage); the stage's config name is what its run folders need.
            if not any(arg.startswith("hydra.job.name=") for arg in sys.argv[1:]):
                sys.argv.append(f"hydra.job.name={config_name}")
            return main()

        return named_main

    return decorate


def redirect_outputs(cfg: DictConfig) -> Path | None:
    """Outside DVC, or in a multirun, prefix every `outputs` key not given on the command line
    with the run's own Hydra folder; returns that folder (None: the pipeline's paths)."""
    hydra_cfg = HydraConfig.get()
    multirun = hydra_cfg.mode == RunMode.MULTIRUN
    if os.environ.get("DVC_STAGE") and not multirun:
        return None
    folder = Path(os.path.relpath(hydra_cfg.runtime.output_dir))
    given = {o.split("=", 1)[0].lstrip("+~") for o in hydra_cfg.overrides.task}
    with open_dict(cfg):
        for key in cfg.get("outputs", []):
            if key not in given:
                cfg[key] = str(folder / str(cfg[key]))
    if not multirun and is_rank_zero():
        print(
            f"scanloc: not run by DVC, so this run writes into {folder}/ (the pipeline's "
            "tracked outputs are left alone; `dvc repro` writes those)",
            file=sys.stderr,
        )
    return folder


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


@contextmanager
def timed_stage(name: str, folder: str | Path) -> Iterator[dict[str, Any]]:
    """Record the stage's wall time in <folder>/<name>.json (the config's timing_dir; under
    DVC reports/timing/, listed in dvc.yaml's top-level metrics: shown, never hashed); rank 0
    only. The stage may add its other machine-dependent figures (epoch_s, device: see
    scanloc.hardware.split_machine_figures) to the yielded dict."""
    start = time.perf_counter()
    machine: dict[str, Any] = {}
    yield machine
    if is_rank_zero():
        write_json(
            Path(folder) / f"{name}.json",
            {"stage": name, "wall_s": round(time.perf_counter() - start, 3), **machine},
        )
