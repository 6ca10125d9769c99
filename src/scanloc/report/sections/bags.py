"""What a ROS bag's site section adds (report/sections/sites.py): where its map came from,
and, for a bag without ground truth, what can be scored instead of accuracy: speed (time per
scan) and consistency (how far each localizer's estimates lie from global amcl's: localizers
that agree are either all right or all wrong the same way). A bag with truth is scored like
any run (the site section's tables)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scanloc.evaluate.table2 import TIME_COLUMN
from scanloc.report.artifacts import LOCALIZE_DIRS, TRAJECTORIES, localize_timings
from scanloc.report.context import ReportContext
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.render.tables import MISSING, fixed

REFERENCE = "amcl_global"  # the estimates the others are compared with, without truth


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


def without_truth(section: Section, root: Path, name: str, run: str) -> None:
    """Speed and agreement with the reference, where there is no truth to score against."""
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


BAG_NOTE = (
    "A ROS bag (params.yaml `bags`, docs/bags.md), read into the run <name>_real and "
    "localized by the same stages as every site."
)


def bag_blocks(ctx: ReportContext, section: Section, name: str) -> bool:
    """Where the bag's map came from, and without truth its localizers' agreement and speed;
    True when the bag has truth (then the site section's tables score it)."""
    section.blocks.append(Para(BAG_NOTE))
    run = f"{name}_real"
    meta_path = ctx.builder.root / TRAJECTORIES / run / "meta.json"
    if not meta_path.is_file():
        section.blocks.append(Para(f"{name}: not read yet (no {TRAJECTORIES / run})."))
        return False
    meta = json.loads(meta_path.read_text())
    section.blocks.append(Para(split_sentence(meta)))
    if not meta.get("has_truth"):
        without_truth(section, ctx.builder.root, name, run)
        return False
    return True
