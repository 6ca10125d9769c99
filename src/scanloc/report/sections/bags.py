"""Section "Your bags": every `bags:` entry of params.yaml (your robot's ROS bags, docs/bags.md)
and how scanloc's localizers did on its run <name>_real. With ground truth: the Table 2 figures
and the modern metrics, as for any run. Without: accuracy cannot be scored, so the section
shows what can be, speed (time per scan) and consistency (how far each localizer's estimates
lie from global amcl's: localizers that agree are either all right or all wrong the same way).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scanloc.evaluate.table2 import MODERN_COLUMNS, TABLE2_COLUMNS, TIME_COLUMN, format_rows
from scanloc.report.artifacts import LOCALIZE_DIRS, TRAJECTORIES, localize_timings
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.render.tables import MISSING, fixed

REFERENCE = "amcl_global"  # the estimates the others are compared with, without truth
NO_BAGS = "No bags: see docs/sites.md, 'Your own bag'."


def bag_names(ctx: ReportContext) -> list[str]:
    """The bag sites of the run (the report stage's `sites`)."""
    return list(ctx.run.get("bags") or [])


def estimates(root: Path, run: str) -> dict[str, pd.DataFrame]:
    """Every estimate table of `run` (the localize stages' and scored external ones), by name."""
    found: dict[str, pd.DataFrame] = {}
    for folder in LOCALIZE_DIRS:
        for path in sorted((root / folder / run).glob("*.csv")):
            found.setdefault(path.stem, pd.read_csv(path))
    return found


def agreement(tables: Mapping[str, pd.DataFrame], reference: str = REFERENCE) -> dict[str, Any]:
    """{localizer: (median distance [m] to the reference's estimate, steps both estimated)}
    over the steps where both have a finite position."""
    ref = tables[reference][["step", "x", "y"]]
    out = {}
    for name, table in tables.items():
        if name == reference:
            continue
        both = table[["step", "x", "y"]].merge(ref, on="step", suffixes=("", "_ref")).dropna()
        gap = np.hypot(both["x"] - both["x_ref"], both["y"] - both["y_ref"])
        out[name] = (float(np.median(gap)) if len(gap) else None, len(gap))
    return out


def split_sentence(meta: Mapping[str, Any]) -> str:
    """How the run's map came about: given, or built from the bag's mapping part."""
    split, covered = meta.get("split"), meta.get("coverage") or {}
    if not split:
        return "The map is the one the entry gives."
    return (
        f"The map is built from {split['map_scans']} scans of the bag ({split['mode']} split), "
        f"the run is the other {split['evaluation_scans']}; the map covers "
        f"{covered.get('covered', MISSING)} of {covered.get('steps', MISSING)} evaluated poses."
    )


def _with_truth(
    section: Section, name: str, meta: Mapping[str, Any], metrics: Mapping[str, Mapping[str, Any]]
) -> None:
    section.blocks.append(
        Para(
            f"{name}: with ground truth, so scored like any run (paper Table 2, then modern). "
            + split_sentence(meta)
        )
    )
    section.blocks.append(Table(*format_rows(metrics, TABLE2_COLUMNS)))
    section.blocks.append(Table(*format_rows(metrics, (*MODERN_COLUMNS, TIME_COLUMN))))


def _without_truth(section: Section, root: Path, name: str, run: str) -> None:
    section.blocks.append(
        Para(
            f"{name}: no ground truth, so only consistency and speed can be scored, not "
            f"accuracy: each localizer's time per scan, and the median distance between its "
            f"position estimate and {REFERENCE}'s at the same step."
        )
    )
    timings = localize_timings(root, run)
    tables = estimates(root, run)
    agree = agreement(tables) if REFERENCE in tables else {}
    rows = []
    for method in sorted(set(timings) | set(tables)):
        time = timings.get(method, {}).get("time_per_scan_s")
        median, steps = agree.get(method, (None, 0))
        gap = "reference" if method == REFERENCE else fixed(median, 3)
        rows.append(
            [
                method,
                TIME_COLUMN[2](time),
                gap,
                str(steps) if method in agree else MISSING,
            ]
        )
    if not rows:
        section.blocks.append(Para(f"{name}: no estimates or timings yet."))
        return
    header = ["localizer", "time per scan [ms]", f"median distance to {REFERENCE} [m]", "steps"]
    section.blocks.append(Table(header, rows))


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    section = spec.section()
    names = bag_names(ctx)
    if not names:
        section.blocks.append(Para(NO_BAGS))
        return [section]
    section.blocks.append(
        Para(
            "Beyond the paper: your robot's ROS bags (params.yaml `bags`, docs/bags.md), each "
            "read into the run <name>_real and localized by the same stages as a real log."
        )
    )
    root = ctx.builder.root
    for name in names:
        run = f"{name}_real"
        meta_path = root / TRAJECTORIES / run / "meta.json"
        if not meta_path.is_file():
            section.blocks.append(Para(f"{name}: not read yet (no {TRAJECTORIES / run})."))
            continue
        meta = json.loads(meta_path.read_text())
        metrics = ctx.artifacts.localization.get(run) or {}
        if meta.get("has_truth") and metrics:
            _with_truth(section, name, meta, metrics)
        elif meta.get("has_truth"):
            section.blocks.append(Para(f"{name}: not evaluated yet (no metrics for {run})."))
        else:
            _without_truth(section, root, name, run)
    return [section]


SECTION = SectionSpec("bags", "Your bags", build)
