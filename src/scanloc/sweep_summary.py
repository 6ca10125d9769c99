"""A Hydra callback that writes <sweep dir>/summary.csv: one row per job of a multirun.

A row holds the job's number, its status (`ok`, `failed` with the error, or `unfinished` for a
job folder without a record: still running, or killed), the job's wall time as the callback
measured it (`job_wall_s`), one column per overridden key, and the scalar metrics the job
wrote (reports/summary.json and reports/metrics/*.json under its folder, nested keys joined
with `.`).

Why the summary is rebuilt from files after every job and not only in `on_multirun_end`:
Hydra's sweeper re-raises the first failed job's exception after the jobs have run, so
`on_multirun_end` never runs for a sweep with a failure; and parallel launchers (joblib,
submitit) call `on_job_end` in each job's own process, so no single process sees every job.
Each job therefore leaves a small record in its folder (`job_status.json`) and rewrites the
summary from all records, under a file lock and atomically, so the last job to finish always
leaves the complete table.
"""

from __future__ import annotations

import csv
import fcntl
import logging
import math
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml
from hydra.core.utils import JobReturn, JobStatus
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig

from scanloc.hardware import MACHINE_KEYS
from scanloc.io import atomic_path, read_json, write_json

RECORD = "job_status.json"
LOCK = ".summary.lock"
FIXED_COLUMNS = ("job", "status", "job_wall_s")
# Where a job's metrics live, relative to its folder (the pipeline's layout: stages redirect
# their outputs into the job folder, stages/_app.py).
SUMMARY_JSON = Path("reports/summary.json")
METRICS_DIR = Path("reports/metrics")
# The stages' timing files: of them only the machine-dependent training figures (epoch_s, ...).
TIMING_DIR = Path("reports/timing")

Cell = str | int | float
log = logging.getLogger(__name__)


class SweepSummary(Callback):
    """Configured in conf/hydra/callbacks/sweep_summary.yaml; does nothing outside multiruns."""

    def __init__(self, filename: str = "summary.csv") -> None:
        self.filename = filename
        self._started: dict[str, float] = {}

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        if _is_multirun(config):
            self._started[str(config.hydra.runtime.output_dir)] = time.perf_counter()

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        if not _is_multirun(config):
            return
        job_dir = str(config.hydra.runtime.output_dir)
        started = self._started.pop(job_dir, None)
        wall_s = round(time.perf_counter() - started, 3) if started is not None else None
        record = job_record(int(config.hydra.job.num), job_return, wall_s)
        write_json(Path(job_dir) / RECORD, record)
        write_summary(Path(str(config.hydra.sweep.dir)), self.filename)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        path = write_summary(Path(str(config.hydra.sweep.dir)), self.filename)
        log.info(f"Sweep summary: {path}")


def _is_multirun(config: DictConfig) -> bool:
    return config.hydra.mode == RunMode.MULTIRUN


def job_record(num: int, job_return: JobReturn, wall_s: float | None) -> dict[str, Any]:
    """What a job leaves in its folder for the summary: number, overrides, status, error."""
    failed = job_return.status == JobStatus.FAILED
    # JobReturn.return_value re-raises a failed job's exception; the exception itself is kept
    # in _return_value.
    error = job_return._return_value if failed else None
    return {
        "job": num,
        "overrides": list(job_return.overrides or []),
        "status": "failed" if failed else "ok",
        "error": " ".join(f"{type(error).__name__}: {error}".split()) if failed else None,
        "job_wall_s": wall_s,
    }


def flatten_numbers(obj: Mapping[str, Any], prefix: str = "") -> dict[str, float | int]:
    """The numeric leaves of nested JSON, keys joined with `.` (strings, booleans, nulls and
    lists are left out: a summary cell holds one number)."""
    out: dict[str, float | int] = {}
    for key, value in obj.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out |= flatten_numbers(value, name + ".")
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            out[name] = value
    return out


def job_metrics(job_dir: Path) -> dict[str, float | int]:
    """The job's scalar metrics from reports/summary.json and reports/metrics/*.json, and the
    machine-dependent training figures (epoch_s, train_s) of reports/timing/*.json. Keys are
    the metric names; a name that two files share is prefixed with its file's stem."""
    files = [job_dir / SUMMARY_JSON, *sorted((job_dir / METRICS_DIR).glob("*.json"))]
    timings = sorted((job_dir / TIMING_DIR).glob("*.json"))
    per_file: dict[Path, dict[str, float | int]] = {}
    for path in [*files, *timings]:
        if path.is_file():
            content = read_json(path)
            if not isinstance(content, Mapping):
                raise ValueError(f"{path}: expected a JSON object of metrics")
            if path in timings:
                content = {k: v for k, v in content.items() if k in MACHINE_KEYS}
            per_file[path] = flatten_numbers(content)
    seen: dict[str, int] = {}
    for values in per_file.values():
        for key in values:
            seen[key] = seen.get(key, 0) + 1
    return {
        (key if seen[key] == 1 else f"{path.stem}.{key}"): value
        for path, values in per_file.items()
        for key, value in values.items()
    }


def parse_overrides(items: list[str]) -> dict[str, str]:
    """Override strings `key=value` (with Hydra's +, ++ or ~ prefixes) as {key: value}."""
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        out[key.lstrip("+~")] = value
    return out


def job_folders(sweep_dir: Path) -> list[Path]:
    """Every job folder under the sweep: those with a record or Hydra's saved overrides."""
    found = {p.parent for p in sweep_dir.rglob(RECORD)}
    saved = sweep_dir.rglob("overrides.yaml")
    found |= {p.parent.parent for p in saved if p.parent.name == ".hydra"}
    return sorted(found)


def job_row(job_dir: Path) -> dict[str, Cell]:
    """One summary row: the job's record (or Hydra's overrides when it left none) and metrics."""
    record_path = job_dir / RECORD
    if record_path.is_file():
        record = read_json(record_path)
        missing = [k for k in ("job", "overrides", "status") if k not in record]
        if missing:
            raise ValueError(f"{record_path}: missing field(s) {missing}")
    else:
        hydra_dir = job_dir / ".hydra"
        hydra_cfg = yaml.safe_load((hydra_dir / "hydra.yaml").read_text())
        record = {
            "job": hydra_cfg["hydra"]["job"]["num"],
            "overrides": yaml.safe_load((hydra_dir / "overrides.yaml").read_text()) or [],
            "status": "unfinished",
            "error": f"no {RECORD}: the job was still running or was killed",
        }
    row: dict[str, Cell] = {"job": int(record["job"]), "status": str(record["status"])}
    if record.get("job_wall_s") is not None:
        row["job_wall_s"] = float(record["job_wall_s"])
    row |= parse_overrides([str(o) for o in record["overrides"]])
    row |= job_metrics(job_dir)
    if record.get("error"):
        row["error"] = str(record["error"])
    return row


def summary_rows(sweep_dir: Path) -> list[dict[str, Cell]]:
    """One row per job folder of the sweep, by job number."""
    return sorted((job_row(d) for d in job_folders(sweep_dir)), key=lambda r: int(r["job"]))


def columns(rows: list[dict[str, Cell]]) -> list[str]:
    """The fixed columns, then every other key in first-seen order, the error last."""
    names = dict.fromkeys(FIXED_COLUMNS)
    for row in rows:
        names |= dict.fromkeys(k for k in row if k != "error")
    return [*names, "error"]


def _cell(value: Cell | None) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return str(value)


@contextmanager
def _locked(sweep_dir: Path) -> Iterator[None]:
    with open(sweep_dir / LOCK, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def write_summary(sweep_dir: Path, filename: str = "summary.csv") -> Path:
    """Rebuild <sweep_dir>/<filename> from the job folders, atomically, under a lock."""
    sweep_dir.mkdir(parents=True, exist_ok=True)
    path = sweep_dir / filename
    with _locked(sweep_dir):
        rows = summary_rows(sweep_dir)
        header = columns(rows)
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(header)
            writer.writerows([_cell(row.get(name)) for name in header] for row in rows)
    return path
