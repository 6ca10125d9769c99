"""How the report writes numbers in its tables: one place for the dash of a missing value, the
digits, percentages, scale factors and the censored counts of convergence and recovery."""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from typing import Any

MISSING = "–"


def num(value: Any, digits: int = 4) -> str:
    """A number with `digits` significant digits (integers with thousands separators)."""
    if value is None:
        return MISSING
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    if isinstance(value, int):
        return f"{value:,}"
    return MISSING if not math.isfinite(value) else f"{value:.{digits}g}"


def seed_summary(values: Sequence[float], digits: int = 3) -> str:
    """One row's figure over its seeds: "2.312" for one seed, "2.312 ± 0.016 (3 seeds)" (mean
    and standard deviation) for several."""
    if len(values) < 2:
        return num(values[0], digits) if values else "–"
    mean, sd = statistics.fmean(values), statistics.stdev(values)
    return f"{mean:.{digits}f} ± {sd:.{digits}f} ({len(values)} seeds)"


def fixed(value: Any, digits: int = 3, percent: bool = False) -> str:
    """A number with `digits` decimals, or a share as a percentage with one decimal."""
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return MISSING
    if not math.isfinite(value):
        return MISSING
    return f"{100 * value:.1f} %" if percent else f"{value:.{digits}f}"


def scale(ours: Any, paper: Any) -> str:
    """Our value as a multiple of the paper's, e.g. ×0.1."""
    if not isinstance(ours, (int, float)) or not isinstance(paper, (int, float)) or not paper:
        return MISSING
    return f"×{ours / paper:.3g}"


def converge_text(metrics: Mapping[str, Any]) -> str:
    """Steps to converge, or 'never (N steps)' for a censored count."""
    steps = metrics.get("steps_to_converge")
    if steps is None:
        return MISSING
    return f"{steps:.0f}" if metrics.get("converged", 1) else f"never ({steps:.0f} steps)"


def recovery_text(metrics: Mapping[str, Any], key: str, digits: int = 0) -> str:
    """A recovery figure, marked '≥' when some kidnap never recovered (censored counts)."""
    value = metrics.get(key)
    if value is None:
        return MISSING
    censored = metrics.get("recovered", 0) < metrics.get("kidnaps", 0)
    return ("≥ " if censored else "") + f"{value:.{digits}f}"
