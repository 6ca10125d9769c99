"""The runs a comparison page reads (report/compare.py): DVC experiments (or git revisions) of
the repository, or the jobs of one Hydra multirun, and the artifacts of each.

Nothing is re-run. A DVC experiment's artifacts are read at its revision through DVC's file
system (git-tracked files from the commit, DVC outputs from the cache); a multirun job's from
its folder, where the stages wrote them (stages/_app.py). An artifact a run lacks reads as
None; a malformed one is an error naming where it was read from.
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import dvc.api
import numpy as np
import pandas as pd
import yaml
from dvc.api import DVCFileSystem
from dvc.scm import SCM, RevError, resolve_rev

from scanloc.evaluate.metrics import check_table
from scanloc.report.paper import ROWS
from scanloc.report.render.localization_figures import step_errors
from scanloc.sweep_summary import job_folders, parse_overrides

SUMMARY_JSON = "reports/summary.json"
HISTORY_COLUMNS = ("epoch", "train_mae", "val_mae")


@dataclass(frozen=True)
class ComparedRun:
    """One whole run of the pipeline to compare (not a training run: artifacts.TrainingRun):
    its label, its parameters ({name: value}, flat) and a reader of its artifacts by
    repository-relative path (None where the run has no such file); `where` says where a path
    was read from, for error messages."""

    label: str
    params: Mapping[str, Any]
    read: Callable[[str], bytes | None]
    where: Callable[[str], str]


def flatten(obj: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings as one level, keys joined with `.` (lists stay values)."""
    out: dict[str, Any] = {}
    for key, value in obj.items():
        if isinstance(value, Mapping) and value:
            out |= flatten(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def multirun_runs(folder: Path) -> list[ComparedRun]:
    """The jobs of a Hydra multirun folder, by job number; parameters: each job's overrides
    (.hydra/overrides.yaml)."""
    if not folder.is_dir():
        raise FileNotFoundError(f"multirun: {folder}: no such folder")
    jobs = [job for job in job_folders(folder) if (job / ".hydra" / "overrides.yaml").is_file()]
    if len(jobs) < 2:
        raise ValueError(
            f"multirun: {folder}: expected a Hydra multirun folder with two or more job folders "
            f"(each with .hydra/overrides.yaml), found {len(jobs)}"
        )
    runs = []
    for job in jobs:
        saved = job / ".hydra" / "overrides.yaml"
        overrides = yaml.safe_load(saved.read_text()) or []
        if not isinstance(overrides, list):
            raise ValueError(f"{saved}: expected a list of overrides, got {type(overrides)}")
        label = f"job {job.relative_to(folder)}"
        runs.append(
            ComparedRun(
                label, parse_overrides([str(o) for o in overrides]), _folder_reader(job), _at(job)
            )
        )
    return runs


def _folder_reader(root: Path) -> Callable[[str], bytes | None]:
    def read(path: str) -> bytes | None:
        file = root / path
        return file.read_bytes() if file.is_file() else None

    return read


def _at(root: Path) -> Callable[[str], str]:
    return lambda path: str(root / path)


def experiment_runs(names: Sequence[str], repo: Path) -> list[ComparedRun]:
    """DVC experiments (names) or git revisions of the DVC repository `repo`; parameters: the
    params every stage of dvc.yaml declares, as `<file>:<key>` (dvc params show)."""
    if len(names) < 2:
        raise ValueError(f"experiments: expected two or more names or revisions, got {names}")
    scm = SCM(str(repo))
    runs = []
    for name in names:
        try:
            rev = resolve_rev(scm, name)
        except RevError as err:
            raise ValueError(
                f"experiments: {name!r} is neither a DVC experiment nor a git revision of "
                f"{repo} ({err})"
            ) from None
        params = dvc.api.params_show(repo=str(repo), rev=rev)
        runs.append(
            ComparedRun(name, _params_by_file(params), _rev_reader(repo, rev), _at_rev(name))
        )
    return runs


def _params_by_file(params: Mapping[str, Any]) -> dict[str, Any]:
    """dvc.api.params_show's answer ({file: params} for several files, the params themselves
    for a single params.yaml), flat."""
    by_file = all(isinstance(k, str) and k.endswith((".yaml", ".yml")) for k in params)
    if not by_file:
        return flatten(params)
    return {f"{file}:{key}": v for file, p in params.items() for key, v in flatten(p).items()}


def _rev_reader(repo: Path, rev: str) -> Callable[[str], bytes | None]:
    fs = DVCFileSystem(str(repo), rev=rev)

    def read(path: str) -> bytes | None:
        return fs.read_bytes(path) if fs.isfile(path) else None

    return read


def _at_rev(name: str) -> Callable[[str], str]:
    return lambda path: f"{path} (experiment {name})"


def read_json_at(run: ComparedRun, path: str) -> Any:
    """A JSON file of the run, or None where it has none; malformed → error naming it."""
    data = run.read(path)
    if data is None:
        return None
    try:
        return json.loads(data)
    except json.JSONDecodeError as err:
        raise ValueError(f"{run.where(path)}: not valid JSON ({err})") from None


def headline(run: ComparedRun) -> tuple[dict[str, Any], str | None]:
    """The run's headline metrics and where they came from: reports/summary.json, else (a run
    of the train stage only, e.g. a training sweep) Table 1's val_mae per row from
    reports/metrics/train_<row>.json; ({}, None) when it has neither."""
    summary = read_json_at(run, SUMMARY_JSON)
    if summary is not None:
        if not isinstance(summary, Mapping):
            raise ValueError(f"{run.where(SUMMARY_JSON)}: expected a JSON object of metrics")
        return dict(summary), SUMMARY_JSON
    table1 = {}
    for row in ROWS:
        path = f"reports/metrics/train_{row}.json"
        metrics = read_json_at(run, path)
        if metrics is not None:
            if not isinstance(metrics, Mapping) or "val_mae" not in metrics:
                raise ValueError(f"{run.where(path)}: expected a JSON object with 'val_mae'")
            table1[f"t1_{row}"] = metrics["val_mae"]
    return (table1, "reports/metrics/train_<row>.json") if table1 else ({}, None)


def history(run: ComparedRun, row: str) -> pd.DataFrame | None:
    """models/<row>/history.csv of the run (None if absent), checked for the curve columns."""
    path = f"models/{row}/history.csv"
    data = run.read(path)
    if data is None:
        return None
    table = pd.read_csv(io.BytesIO(data))
    missing = [c for c in HISTORY_COLUMNS if c not in table.columns]
    if missing:
        raise ValueError(f"{run.where(path)}: missing column(s) {missing}")
    return table


def drive_errors(
    run: ComparedRun, trajectory: str, localizers: Iterable[str]
) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], str | None]:
    """Per localizer of `trajectory` the run estimated: (time [s], position error [m]) per
    step, or ({}, why) when the run has no true trajectory."""
    truth_path = f"data/trajectories/{trajectory}/truth.npy"
    data = run.read(truth_path)
    if data is None:
        return {}, f"no {truth_path}"
    truth = np.load(io.BytesIO(data))
    if truth.ndim != 2 or truth.shape[1] != 3:
        raise ValueError(
            f"{run.where(truth_path)}: expected poses of shape (T, 3), got {truth.shape}"
        )
    out = {}
    for name in localizers:
        path = f"reports/localize/{trajectory}/{name}.csv"
        table_bytes = run.read(path)
        if table_bytes is None:
            continue
        table = pd.read_csv(io.BytesIO(table_bytes))
        check_table(table, run.where(path), len(truth))
        pos, _ = step_errors(truth, table)
        t = table["t"].to_numpy(dtype=np.float64) if "t" in table else np.arange(len(table))
        out[name] = (t, pos)
    return out, None
