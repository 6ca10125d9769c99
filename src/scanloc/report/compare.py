"""An offline page that compares two or more runs: DVC experiments (or git revisions) of the
repository, or the jobs of one Hydra multirun.

Nothing is re-run. A DVC experiment's artifacts are read at its revision through DVC's file
system (git-tracked files from the commit, DVC outputs from the cache); a multirun job's from
its folder, where the stages wrote them (stages/_app.py). The page has four sections: the
parameters that differ, the headline metrics side by side (report/summary.py) with the better
value marked, the learning curves of every Table 1 row overlaid (paper Fig. 7), and the
position error along the map-1 drive of each localizer overlaid. An artifact a run lacks is
said in its section; it is not an error. compare.html is self-contained, compare.md shows the
same figures from figures/ beside it (report/document.py).
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from scanloc.evaluate.metrics import check_table
from scanloc.io import atomic_path
from scanloc.report import figures
from scanloc.report.document import (
    Builder,
    Para,
    Section,
    Table,
    render_html,
    render_markdown,
)
from scanloc.report.summary import PAPER_DRIVE, TABLE1_ROWS
from scanloc.sweep_summary import job_folders, parse_overrides

SUMMARY_JSON = "reports/summary.json"
BEST_MARK = "★"
# Which way is better, by headline key prefix (summary.py); claims_* counts are not marked.
LOWER_IS_BETTER = ("pos_", "lost_", "conv_", "rec_", "t1_", "real_rmse_")
HIGHER_IS_BETTER = ("top5_", "real_top5_")
HISTORY_COLUMNS = ("epoch", "train_mae", "val_mae")
MISSING = "—"


@dataclass(frozen=True)
class Run:
    """One run to compare: its label, its parameters ({name: value}, flat) and a reader of its
    artifacts by repository-relative path (None where the run has no such file); `where` says
    where a path was read from, for error messages."""

    label: str
    params: Mapping[str, Any]
    read: Callable[[str], bytes | None]
    where: Callable[[str], str]


# ---------------------------------------------------------------- loading runs


def flatten(obj: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings as one level, keys joined with `.` (lists stay values)."""
    out: dict[str, Any] = {}
    for key, value in obj.items():
        if isinstance(value, Mapping) and value:
            out |= flatten(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def multirun_runs(folder: Path) -> list[Run]:
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
            Run(label, parse_overrides([str(o) for o in overrides]), _folder_reader(job), _at(job))
        )
    return runs


def _folder_reader(root: Path) -> Callable[[str], bytes | None]:
    def read(path: str) -> bytes | None:
        file = root / path
        return file.read_bytes() if file.is_file() else None

    return read


def _at(root: Path) -> Callable[[str], str]:
    return lambda path: str(root / path)


def experiment_runs(names: Sequence[str], repo: Path) -> list[Run]:
    """DVC experiments (names) or git revisions of the DVC repository `repo`; parameters: the
    params every stage of dvc.yaml declares, as `<file>:<key>` (dvc params show)."""
    import dvc.api
    from dvc.scm import SCM, RevError, resolve_rev

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
        runs.append(Run(name, _params_by_file(params), _rev_reader(repo, rev), _at_rev(name)))
    return runs


def _params_by_file(params: Mapping[str, Any]) -> dict[str, Any]:
    """dvc.api.params_show's answer ({file: params} for several files, the params themselves
    for a single params.yaml), flat."""
    by_file = all(isinstance(k, str) and k.endswith((".yaml", ".yml")) for k in params)
    if not by_file:
        return flatten(params)
    return {f"{file}:{key}": v for file, p in params.items() for key, v in flatten(p).items()}


def _rev_reader(repo: Path, rev: str) -> Callable[[str], bytes | None]:
    from dvc.api import DVCFileSystem

    fs = DVCFileSystem(str(repo), rev=rev)

    def read(path: str) -> bytes | None:
        return fs.read_bytes(path) if fs.isfile(path) else None

    return read


def _at_rev(name: str) -> Callable[[str], str]:
    return lambda path: f"{path} (experiment {name})"


# ---------------------------------------------------------------- artifacts of a run


def read_json_at(run: Run, path: str) -> Any:
    """A JSON file of the run, or None where it has none; malformed → error naming it."""
    data = run.read(path)
    if data is None:
        return None
    try:
        return json.loads(data)
    except json.JSONDecodeError as err:
        raise ValueError(f"{run.where(path)}: not valid JSON ({err})") from None


def headline(run: Run) -> tuple[dict[str, Any], str | None]:
    """The run's headline metrics and where they came from: reports/summary.json, else (a run
    of the train stage only, e.g. a training sweep) Table 1's val_mae per row from
    reports/metrics/train_<row>.json; ({}, None) when it has neither."""
    summary = read_json_at(run, SUMMARY_JSON)
    if summary is not None:
        if not isinstance(summary, Mapping):
            raise ValueError(f"{run.where(SUMMARY_JSON)}: expected a JSON object of metrics")
        return dict(summary), SUMMARY_JSON
    table1 = {}
    for row in TABLE1_ROWS:
        path = f"reports/metrics/train_{row}.json"
        metrics = read_json_at(run, path)
        if metrics is not None:
            if not isinstance(metrics, Mapping) or "val_mae" not in metrics:
                raise ValueError(f"{run.where(path)}: expected a JSON object with 'val_mae'")
            table1[f"t1_{row}"] = metrics["val_mae"]
    return (table1, "reports/metrics/train_<row>.json") if table1 else ({}, None)


def history(run: Run, row: str) -> pd.DataFrame | None:
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
    run: Run, trajectory: str, localizers: Iterable[str]
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
        pos, _ = figures.step_errors(truth, table)
        t = table["t"].to_numpy(dtype=np.float64) if "t" in table else np.arange(len(table))
        out[name] = (t, pos)
    return out, None


# ---------------------------------------------------------------- sections


def direction(key: str) -> int:
    """-1 where lower is better, +1 where higher is, 0 where neither (claim counts, unknown)."""
    if key == "wall_s" or key.startswith(LOWER_IS_BETTER):
        return -1
    return 1 if key.startswith(HIGHER_IS_BETTER) else 0


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        return None
    return float(value)


def marked_row(key: str, values: Sequence[Any]) -> list[str]:
    """The cells of one metric across the runs; the best value(s) get BEST_MARK when the key
    has a direction and the runs differ."""
    numbers = [_number(v) for v in values]
    known = [n for n in numbers if n is not None]
    sign = direction(key)
    best = None
    if sign and len(set(known)) > 1:
        best = min(known) if sign < 0 else max(known)
    cells = []
    for value, number in zip(values, numbers, strict=True):
        if number is None:
            cells.append(MISSING if value is None else str(value))
        else:
            cells.append(f"{number:.4g}" + (f" {BEST_MARK}" if number == best else ""))
    return cells


def _cell(value: Any) -> str:
    if value is None:
        return MISSING
    return json.dumps(value) if isinstance(value, (list, dict)) else str(value)


def params_section(runs: Sequence[Run]) -> Section:
    keys = list(dict.fromkeys(k for run in runs for k in run.params))
    differ = [k for k in keys if len({_cell(run.params.get(k)) for run in runs}) > 1]
    section = Section("params", "Parameter differences")
    if not differ:
        section.blocks.append(Para("The runs' parameters are identical."))
        return section
    section.blocks.append(
        Para(f"Only the {len(differ)} of {len(keys)} parameters that differ; {MISSING}: not set.")
    )
    rows = [[k, *(_cell(run.params.get(k)) for run in runs)] for k in differ]
    section.blocks.append(Table(["parameter", *(run.label for run in runs)], rows))
    return section


def metrics_section(runs: Sequence[Run]) -> Section:
    section = Section("metrics", "Headline metrics")
    loaded = [headline(run) for run in runs]
    keys = list(dict.fromkeys(k for metrics, _ in loaded for k in metrics))
    if not keys:
        section.blocks.append(Para(f"No run has headline metrics ({SUMMARY_JSON})."))
        return section
    sources = sorted({source for _, source in loaded if source})
    lacking = [run.label for run, (_, source) in zip(runs, loaded, strict=True) if not source]
    section.blocks.append(
        Para(
            f"From {' and '.join(sources)}. {BEST_MARK} marks the better value: lower is better "
            f"for {', '.join(p + '*' for p in LOWER_IS_BETTER)} and wall_s, higher for "
            f"{', '.join(p + '*' for p in HIGHER_IS_BETTER)}; claim counts are not marked."
        )
    )
    if lacking:
        section.blocks.append(Para(f"No headline metrics for {', '.join(lacking)}."))
    rows = [[k, *marked_row(k, [metrics.get(k) for metrics, _ in loaded])] for k in keys]
    section.blocks.append(Table(["metric", *(run.label for run in runs)], rows))
    return section


def curves_section(b: Builder, runs: Sequence[Run]) -> Section:
    section = Section("curves", "Learning curves (paper Fig. 7)")
    for row in TABLE1_ROWS:
        histories = {run.label: h for run in runs if (h := history(run, row)) is not None}
        if not histories:
            section.blocks.append(Para(f"{row}: no run has models/{row}/history.csv."))
            continue
        caption = f"{row}: training and validation MAE per epoch of every run, log scale."
        if len(histories) < len(runs):
            lacking = [run.label for run in runs if run.label not in histories]
            caption += f" Without a history: {', '.join(lacking)}."
        section.blocks.append(
            b.figure(
                f"curves_{row}.png",
                caption,
                lambda p, h=histories, r=row: figures.plot_learning_curves(h, p, r),
            )
        )
    return section


def plot_position_errors(
    errors: Mapping[str, Mapping[str, tuple[np.ndarray, np.ndarray]]],
    localizers: Sequence[str],
    path: Path,
) -> Path:
    """One panel per localizer, one line per run: position error [m] over time, log scale."""
    colours = figures.colors_for(list(errors))
    fig = figures.new_figure(10.0, 2.4 * len(localizers) + 0.6)
    axes = np.atleast_1d(fig.subplots(len(localizers), 1, sharex=True, squeeze=False).ravel())
    for ax, name in zip(axes, localizers, strict=True):
        for label, per_localizer in errors.items():
            if name in per_localizer:
                t, pos = per_localizer[name]
                ax.plot(t, np.maximum(pos, 1e-3), color=colours[label], lw=0.9, label=label)
        ax.set_yscale("log")
        ax.set_ylabel("position error [m]")
        ax.set_title(name, fontsize=10)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=8, ncols=min(len(errors), 4))
    axes[-1].set_xlabel("time [s]")
    return figures.save_png(fig, path)


def errors_section(
    b: Builder, runs: Sequence[Run], trajectory: str, localizers: Sequence[str]
) -> Section:
    section = Section("errors", f"Position error over time ({trajectory})")
    errors, notes = {}, []
    for run in runs:
        per_localizer, why = drive_errors(run, trajectory, localizers)
        if why:
            notes.append(f"{run.label}: {why}")
        elif per_localizer:
            errors[run.label] = per_localizer
        else:
            notes.append(f"{run.label}: no estimates of {', '.join(localizers)}")
    shown = [name for name in localizers if any(name in e for e in errors.values())]
    if notes:
        section.blocks.append(Para("Not shown: " + "; ".join(notes) + "."))
    if not shown:
        section.blocks.append(
            Para(f"No run has estimates of {', '.join(localizers)} on {trajectory}.")
        )
        return section
    caption = (
        f"Position error of {', '.join(shown)} at each step of {trajectory}, one line per run, "
        "log scale (reports/localize/)."
    )
    section.blocks.append(
        b.figure("position_error.png", caption, lambda p: plot_position_errors(errors, shown, p))
    )
    return section


# ---------------------------------------------------------------- the page


def write_compare(
    runs: Sequence[Run],
    out_dir: Path,
    source: str,
    trajectory: str = PAPER_DRIVE,
    localizers: Sequence[str] = ("amcl", "scanlocnet", "hybrid"),
) -> list[Section]:
    """Write <out_dir>/compare.html, compare.md and figures/*.png for `runs` (described by
    `source` in the page's summary line); return the sections."""
    labels = [run.label for run in runs]
    if len(runs) < 2 or len(set(labels)) != len(labels):
        raise ValueError(f"expected two or more runs with distinct labels, got {labels}")
    b = Builder(Path("."), out_dir, {})
    sections = [
        params_section(runs),
        metrics_section(runs),
        curves_section(b, runs),
        errors_section(b, runs, trajectory, list(localizers)),
    ]
    for stale in b.figure_dir.glob("*.png"):
        if stale.name not in b.written:
            stale.unlink()
    title = "scanloc: " + " vs ".join(labels)
    summary = f"{len(runs)} runs compared ({source}); nothing was re-run."
    with atomic_path(out_dir / "compare.md") as tmp:
        tmp.write_text(render_markdown(sections, title, summary), encoding="utf-8")
    with atomic_path(out_dir / "compare.html") as tmp:
        tmp.write_text(render_html(sections, title, summary, b.figure_dir), encoding="utf-8")
    return sections
