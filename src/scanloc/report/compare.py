"""An offline page that compares two or more runs: DVC experiments (or git revisions) of the
repository, or the jobs of one Hydra multirun (read by compare_runs.py).

The page has four sections: the parameters that differ, the headline metrics side by side
(report/summary.py) with the better value marked, the learning curves of every Table 1 row
overlaid (paper Fig. 7), and the position error along the map-1 drive of each localizer
overlaid. An artifact a run lacks is said in its section; it is not an error. compare.html is
self-contained, compare.md shows the same figures from figures/ beside it (render/document.py).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from scanloc.io import atomic_path
from scanloc.report.compare_runs import (
    SUMMARY_JSON,
    ComparedRun,
    drive_errors,
    headline,
    history,
)
from scanloc.report.paper import PAPER_DRIVE, ROWS
from scanloc.report.render import figures
from scanloc.report.render.document import (
    Builder,
    Para,
    Section,
    Table,
    render_html,
    render_markdown,
)

BEST_MARK = "★"
# Which way is better, by headline key prefix (summary.py); claims_* counts are not marked.
LOWER_IS_BETTER = ("pos_", "lost_", "conv_", "rec_", "t1_", "real_rmse_", "ece_", "real_ece_")
HIGHER_IS_BETTER = ("top5_", "real_top5_", "vtop1_", "real_vtop1_")
MISSING = "—"


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


def params_section(runs: Sequence[ComparedRun]) -> Section:
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


def metrics_section(runs: Sequence[ComparedRun]) -> Section:
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


def curves_section(b: Builder, runs: Sequence[ComparedRun]) -> Section:
    section = Section("curves", "Learning curves (paper Fig. 7)")
    for row in ROWS:
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
    b: Builder, runs: Sequence[ComparedRun], trajectory: str, localizers: Sequence[str]
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
    runs: Sequence[ComparedRun],
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
