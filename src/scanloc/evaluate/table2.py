"""Evaluate every localizer's estimate table on one trajectory; write the metrics JSON and Table 2.

`reports/metrics/localization_<trajectory>.json` is `{method: {metric: value}}` with sorted keys
and values rounded to 6 significant digits (NaN written as null), so that identical estimates
give identical bytes. Each method gets Table 2's and the modern metrics, the global-localization,
kidnap and staying-right metrics, and, for a localizer that writes ranked hypotheses
(`<method>_hypotheses.npz`), the top-1/5/20 recall, and for verified hypotheses (with
`scores`) the expected calibration error of the top-1's calibrated score (`calibration_ece`).
Wall-clock figures (time per scan, setup) measure the machine, not the estimates: they stay in
the localize stages' unhashed reports/localize_timing/ files, which the report reads beside
these metrics.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scanloc.evaluate.metrics import (
    convergence_metrics,
    expected_calibration_error,
    localization_metrics,
    read_estimates,
    staying_right_metrics,
)
from scanloc.io import atomic_path, read_json
from scanloc.pose import recall_within

METHOD_ORDER = ("amcl", "cnn_single", "cnn_ensemble")
HYPOTHESES_SUFFIX = "_hypotheses.npz"
RECALL_K = (1, 5, 20)


def ordered_methods(names: list[str] | Mapping[str, object]) -> list[str]:
    """The paper's three localizers first (amcl, single, ensemble), any others sorted after."""
    known = [m for m in METHOD_ORDER if m in names]
    return known + sorted(m for m in names if m not in METHOD_ORDER)


def evaluate_all(
    truth: np.ndarray,
    tables: Mapping[str, pd.DataFrame],
    sources: Mapping[str, str] | None = None,
    kidnap_steps: tuple[int, ...] = (),
    hypotheses: Mapping[str, np.ndarray] | None = None,
    scores: Mapping[str, np.ndarray] | None = None,
) -> dict[str, dict[str, float]]:
    """Metrics of each localizer; `sources` (method → file) only improves error messages;
    `hypotheses` (method → (T, K, 3) ranked poses) adds the top-K recall, `scores` (method →
    (T, K) calibrated probabilities of those hypotheses) the top-1's calibration error."""
    sources, hypotheses, scores = sources or {}, hypotheses or {}, scores or {}
    out = {}
    for name in ordered_methods(tables):
        metrics = localization_metrics(truth, tables[name], source=sources.get(name, name))
        metrics |= convergence_metrics(truth, tables[name], kidnap_steps)
        metrics |= staying_right_metrics(truth, tables[name], kidnap_steps)
        if name in hypotheses:
            hits = {k: recall_within(hypotheses[name][:, :k], truth) for k in RECALL_K}
            metrics |= {f"top{k}_recall": float(hit.mean()) for k, hit in hits.items()}
            if name in scores:  # verified hypotheses: their top-1 score against its hit
                top1 = scores[name][:, 0]
                metrics["calibration_ece"] = expected_calibration_error(top1, hits[1])
                metrics["top1_score_mean"] = float(np.mean(top1))
        out[name] = metrics
    return out


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


def _rounded(doc: Any) -> Any:
    if isinstance(doc, Mapping):
        return {str(k): _rounded(v) for k, v in doc.items()}
    return round_sig(doc)


def nested_json(doc: Mapping[str, Any]) -> str:
    """Stable JSON text of nested mappings of numbers (rounded as `metrics_json`)."""
    return json.dumps(_rounded(doc), sort_keys=True, indent=2, allow_nan=False) + "\n"


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
    ("heading_err_rmse_deg", "RMSE [°]", _fixed(2)),
    ("frac_within_0_1m", "< 0.1 m", _percent),
    ("frac_within_0_25m", "< 0.25 m", _percent),
    ("frac_within_0_5m", "< 0.5 m", _percent),
    ("frac_gross_over_1m", "> 1 m (gross)", _percent),
    ("calib_within_1sigma", "in 1σ ellipse (39.3 %)", _percent),
    ("calib_within_2sigma", "in 2σ ellipse (86.5 %)", _percent),
)
# Measured on the machine that ran the localize stage (reports/localize_timing/, unhashed):
# the report adds it to the modern metrics; the hashed Markdown tables leave it out.
TIME_COLUMN: tuple[str, str, Callable[[float | None], str]] = (
    "time_per_scan_s",
    "time per scan [ms]",
    _millis,
)


GLOBAL_COLUMNS: tuple[tuple[str, str, Callable[[float | None], str]], ...] = (
    ("steps_to_converge", "steps to converge", _fixed(0)),
    ("converged", "converged", _fixed(0)),
    ("recovery_steps_max", "recovery steps (max)", _fixed(0)),
    ("recovery_steps_mean", "recovery steps (mean)", _fixed(1)),
    ("recovered", "kidnaps recovered", _fixed(0)),
    ("kidnaps_recovered_frac", "recovered ≤ 20 steps", _percent),
    ("relosses", "re-losses", _fixed(0)),
    ("false_convergences", "false convergences", _fixed(0)),
    ("tracking_pos_err_mean_m", "tracking pos. error mean [m]", _fixed(3)),
    ("tracking_pos_err_median_m", "median [m]", _fixed(3)),
    ("tracking_heading_err_mean_deg", "heading mean [°]", _fixed(2)),
    ("frac_lost", "lost (> 1 m)", _percent),
    ("top5_recall", "top-5 recall", _percent),
)
GLOBAL_NOTE = (
    "Converged: the error stays below 0.5 m and 10° for 20 consecutive steps. Steps to "
    "converge count from the start, recovery steps from each kidnap; a localizer that does not "
    "converge within a stretch (the run, or up to the next kidnap) gets the stretch's length, "
    "with converged = 0 or fewer kidnaps recovered; tracking errors are over the converged "
    "stretches only; recovered ≤ 20 steps: share of kidnaps recovered within 20 steps; "
    "re-losses: a converged filter off (≥ 0.5 m or ≥ 10°) for 5 or more steps in a row; "
    "false convergences: 20 or more steps in a row confident by the filter's own covariance "
    "(larger std ≤ 0.5 m) on a pose ≥ 0.5 m or ≥ 10° from the truth (– without a covariance); "
    "top-5 recall: the truth within 0.5 m and 10° of one of a learned localizer's 5 best "
    "hypotheses."
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


def table2_markdown(
    metrics: Mapping[str, Mapping[str, float | None]], steps: int, trajectory: str
) -> str:
    """Table 2, the modern metrics and the global-localization table as a Markdown document."""
    return (
        f"# Table 2: localization error on trajectory {trajectory} ({steps} steps)\n\n"
        f"{TABLE2_NOTE}\n\n"
        + markdown_table(*format_rows(metrics, TABLE2_COLUMNS))
        + "\n## Modern metrics\n\n"
        "Position error = Euclidean distance in x, y; heading error wrapped to ±180°; "
        "calibration = share of steps whose true position lies inside the 1σ / 2σ ellipse "
        "of the estimate's position covariance (a calibrated Gaussian: 39.3 % / 86.5 %).\n\n"
        + markdown_table(*format_rows(metrics, MODERN_COLUMNS))
        + "\n## Global localization and kidnapping\n\n"
        f"{GLOBAL_NOTE}\n\n" + markdown_table(*format_rows(metrics, GLOBAL_COLUMNS))
    )


def read_timings(path: Path) -> dict[str, dict[str, float]]:
    """{localizer: timing figures} of a localize stage's timing file (absent: none)."""
    path = Path(path)
    if not path.is_file():
        return {}
    doc = read_json(path)
    timings = {}
    for name, figures in doc.items() if isinstance(doc, dict) else ():
        value = figures.get("time_per_scan_s") if isinstance(figures, dict) else None
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ValueError(
                f"{path}: field '{name}.time_per_scan_s': expected a number, got {value!r}"
            )
        timings[name] = {k: float(v) for k, v in figures.items() if isinstance(v, (int, float))}
    return timings


def read_hypotheses(
    localize_dir: Path, steps: int
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The ranked hypotheses (T, K, 3) of each `<method>_hypotheses.npz` in the folder, and the
    calibrated scores (T, K) of those that were verified."""
    found, scores = {}, {}
    for path in sorted(Path(localize_dir).glob(f"*{HYPOTHESES_SUFFIX}")):
        name = path.name.removesuffix(HYPOTHESES_SUFFIX)
        with np.load(path) as data:
            poses = data["poses"]
            if "scores" in data:
                scores[name] = data["scores"]
        if poses.ndim != 3 or poses.shape[0] != steps or poses.shape[2] != 3:
            raise ValueError(f"{path}: 'poses' must have shape ({steps}, K, 3), got {poses.shape}")
        if name in scores and scores[name].shape != poses.shape[:2]:
            raise ValueError(
                f"{path}: 'scores' must have shape {poses.shape[:2]}, got {scores[name].shape}"
            )
        found[name] = poses
    return found, scores


def load_truth(trajectory_dir: Path) -> tuple[np.ndarray, tuple[int, ...]]:
    """A trajectory's true poses (T, 3) and kidnap steps (from meta.json)."""
    truth_path = Path(trajectory_dir) / "truth.npy"
    if not truth_path.is_file():
        raise FileNotFoundError(f"{truth_path}: file not found (expected a saved trajectory)")
    truth = np.load(truth_path)
    if truth.ndim != 2 or truth.shape[1] != 3:
        raise ValueError(f"{truth_path}: expected true poses of shape (T, 3), got {truth.shape}")
    meta_path = Path(trajectory_dir) / "meta.json"
    meta = read_json(meta_path) if meta_path.is_file() else {}
    return truth, tuple(int(k) for k in meta.get("kidnap_steps", ()))


def evaluate_trajectory(
    trajectory_dir: Path, localize_dirs: list[Path]
) -> dict[str, dict[str, float]]:
    """The metrics of every `<method>.csv` in the localize folders against the trajectory."""
    truth, kidnaps = load_truth(trajectory_dir)
    paths = {
        p.stem: p
        for folder in localize_dirs
        if folder.is_dir()
        for p in sorted(folder.glob("*.csv"))
    }
    if not paths:
        raise FileNotFoundError(
            f"{', '.join(map(str, localize_dirs))}: no <method>.csv estimate tables found"
        )
    tables = {name: read_estimates(path) for name, path in paths.items()}
    hypotheses: dict[str, np.ndarray] = {}
    scores: dict[str, np.ndarray] = {}
    for folder in localize_dirs:
        if folder.is_dir():
            poses, verified = read_hypotheses(folder, len(truth))
            hypotheses |= poses
            scores |= verified
    sources = {name: str(path) for name, path in paths.items()}
    return evaluate_all(truth, tables, sources, kidnaps, hypotheses, scores)


def evaluate_runs(
    trajectories: list[str],
    trajectory_root: Path,
    localize_roots: list[Path],
    out_json: Path,
    table2_dir: Path,
) -> dict[str, dict[str, dict[str, float]]]:
    """Evaluate each named trajectory; write {trajectory: {method: metrics}} as one JSON and
    one Table 2 Markdown per trajectory. Returns the (unrounded) metrics."""
    metrics = {}
    for name in trajectories:
        metrics[name] = evaluate_trajectory(
            trajectory_root / name, [root / name for root in localize_roots]
        )
    text = nested_json(metrics)
    with atomic_path(out_json) as tmp:
        tmp.write_text(text, encoding="utf-8")
    rounded = json.loads(text)
    for name, doc in rounded.items():
        steps = len(load_truth(trajectory_root / name)[0])
        with atomic_path(Path(table2_dir) / f"{name}.md") as tmp:
            tmp.write_text(table2_markdown(doc, steps, name), encoding="utf-8")
    return metrics
