"""Evaluate every localizer's estimate table and write the metrics JSON and Table 2.

`reports/metrics/localization.json` is `{method: {metric: value}}` with sorted keys and values
rounded to 6 significant digits (NaN written as null), so that identical estimates give
identical bytes; only `time_per_scan_s` varies from run to run.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from scanloc.evaluate.metrics import localization_metrics, read_estimates
from scanloc.io import atomic_path, read_json

METHOD_ORDER = ("amcl", "cnn_single", "cnn_ensemble")
TIMING_SUFFIX = "_timing.json"


def ordered_methods(names: list[str] | Mapping[str, object]) -> list[str]:
    """The paper's three localizers first (amcl, single, ensemble), any others sorted after."""
    known = [m for m in METHOD_ORDER if m in names]
    return known + sorted(m for m in names if m not in METHOD_ORDER)


def evaluate_all(
    truth: np.ndarray,
    tables: Mapping[str, pd.DataFrame],
    timings: Mapping[str, float],
    sources: Mapping[str, str] | None = None,
) -> dict[str, dict[str, float]]:
    """Metrics of each localizer; `sources` (method → file) only improves error messages."""
    sources = sources or {}
    return {
        name: localization_metrics(truth, tables[name], timings.get(name), sources.get(name, name))
        for name in ordered_methods(tables)
    }


def round_sig(value: float | int, digits: int = 6) -> float | int | None:
    """`value` rounded to `digits` significant digits; None for NaN/inf; ints unchanged."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return int(value)
    value = float(value)
    if not math.isfinite(value):
        return None
    return float(f"{value:.{digits}g}")


def metrics_json(metrics: Mapping[str, Mapping[str, float]]) -> str:
    """Stable JSON text of {method: {metric: value}}."""
    rounded = {m: {k: round_sig(v) for k, v in vals.items()} for m, vals in metrics.items()}
    return json.dumps(rounded, sort_keys=True, indent=2, allow_nan=False) + "\n"


def _fixed(digits: int) -> Callable[[float | None], str]:
    return lambda v: "–" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _percent(value: float | None) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{100 * value:.1f} %"


def _millis(value: float | None) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{1000 * value:.3g}"


# (metric key, column header, formatter) of the two tables.
TABLE2_COLUMNS: tuple[tuple[str, str, Callable[[float | None], str]], ...] = (
    ("x_err_mean", "x error mean [m]", _fixed(4)),
    ("x_err_std", "x error std [m]", _fixed(4)),
    ("y_err_mean", "y error mean [m]", _fixed(4)),
    ("y_err_std", "y error std [m]", _fixed(4)),
    ("theta_sin_err_mean", "sin θ error mean", _fixed(4)),
    ("theta_sin_err_std", "sin θ error std", _fixed(4)),
)
MODERN_COLUMNS: tuple[tuple[str, str, Callable[[float | None], str]], ...] = (
    ("pos_err_mean_m", "pos. error mean [m]", _fixed(3)),
    ("pos_err_median_m", "median [m]", _fixed(3)),
    ("pos_err_rmse_m", "RMSE [m]", _fixed(3)),
    ("pos_err_p95_m", "95th pct. [m]", _fixed(3)),
    ("heading_err_mean_deg", "heading error mean [°]", _fixed(2)),
    ("heading_err_median_deg", "median [°]", _fixed(2)),
    ("frac_within_0_1m", "< 0.1 m", _percent),
    ("frac_within_0_25m", "< 0.25 m", _percent),
    ("frac_within_0_5m", "< 0.5 m", _percent),
    ("frac_gross_over_1m", "> 1 m (gross)", _percent),
    ("calib_within_1sigma", "in 1σ ellipse (39.3 %)", _percent),
    ("calib_within_2sigma", "in 2σ ellipse (86.5 %)", _percent),
    ("time_per_scan_s", "time per scan [ms]", _millis),
)


def format_rows(
    metrics: Mapping[str, Mapping[str, float | None]],
    columns: tuple[tuple[str, str, Callable[[float | None], str]], ...],
) -> tuple[list[str], list[list[str]]]:
    """Header and text rows (one per method, in report order) of a metrics table."""
    header = ["method"] + [title for _, title, _ in columns]
    rows = [
        [name] + [fmt(metrics[name].get(key)) for key, _, fmt in columns]
        for name in ordered_methods(metrics)
    ]
    return header, rows


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A GitHub-flavoured Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


TABLE2_NOTE = (
    "Means and standard deviations of the ABSOLUTE errors |x_est − x_true|, |y_est − y_true| "
    "and |sin θ_true − sin θ_est| (the paper's θ error: the difference of the sines) over all "
    "steps with an estimate; standard deviations with divisor n."
)


def table2_markdown(metrics: Mapping[str, Mapping[str, float | None]], steps: int) -> str:
    """Table 2 and the modern metrics as a Markdown document."""
    return (
        f"# Table 2: localization error on the map-1 trajectory ({steps} steps)\n\n"
        f"{TABLE2_NOTE}\n\n"
        + markdown_table(*format_rows(metrics, TABLE2_COLUMNS))
        + "\n## Modern metrics\n\n"
        "Position error = Euclidean distance in x, y; heading error wrapped to ±180°; "
        "calibration = share of steps whose true position lies inside the 1σ / 2σ ellipse "
        "of the estimate's position covariance (a calibrated Gaussian: 39.3 % / 86.5 %).\n\n"
        + markdown_table(*format_rows(metrics, MODERN_COLUMNS))
    )


def read_timings(localize_dir: Path) -> dict[str, float]:
    """`time_per_scan_s` of each `<method>_timing.json` in the folder."""
    timings = {}
    for path in sorted(Path(localize_dir).glob(f"*{TIMING_SUFFIX}")):
        doc = read_json(path)
        value = doc.get("time_per_scan_s") if isinstance(doc, dict) else None
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ValueError(f"{path}: field 'time_per_scan_s': expected a number, got {value!r}")
        timings[path.name.removesuffix(TIMING_SUFFIX)] = float(value)
    return timings


def evaluate_dir(
    truth_path: Path, localize_dir: Path, out_json: Path, out_md: Path
) -> dict[str, dict[str, float]]:
    """Evaluate every `<method>.csv` in `localize_dir` against `truth_path` (truth.npy) and
    write the metrics JSON and the Table 2 Markdown. Returns the (unrounded) metrics."""
    truth = np.load(truth_path)
    if truth.ndim != 2 or truth.shape[1] != 3:
        raise ValueError(f"{truth_path}: expected true poses of shape (T, 3), got {truth.shape}")
    paths = {p.stem: p for p in sorted(Path(localize_dir).glob("*.csv"))}
    if not paths:
        raise FileNotFoundError(f"{localize_dir}: no <method>.csv estimate tables found")
    tables = {name: read_estimates(path) for name, path in paths.items()}
    sources = {name: str(path) for name, path in paths.items()}
    metrics = evaluate_all(truth, tables, read_timings(localize_dir), sources)
    text = metrics_json(metrics)
    with atomic_path(out_json) as tmp:
        tmp.write_text(text, encoding="utf-8")
    with atomic_path(out_md) as tmp:
        tmp.write_text(table2_markdown(json.loads(text), len(truth)), encoding="utf-8")
    return metrics
