"""The report's "Your bags" section, built from fabricated artifacts: one line without bags;
a bag with truth shows the evaluated Table 2 figures; a bag without truth says that only
consistency and speed can be scored and shows the times per scan and each localizer's median
distance to global amcl."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from scanloc.estimates import TABLE_COLUMNS
from scanloc.evaluate.table2 import evaluate_runs
from scanloc.report.artifacts import Artifacts, with_timings
from scanloc.report.context import ReportContext
from scanloc.report.localizers import Localizers
from scanloc.report.render.document import Builder, Para, Table
from scanloc.report.sections import sites
from scanloc.report.sections.registry import SECTIONS
from scanloc.trajectory.format import Trajectory, save_trajectory

STEPS = 40
SENSOR = {"num_beams": 31, "angle_min": -1.5, "angle_max": 1.5, "range_max": 5.6}


def path_truth() -> np.ndarray:
    phase = np.linspace(0.0, np.pi, STEPS)
    return np.column_stack([2 + np.cos(phase), 2 + np.sin(phase), np.angle(np.exp(1j * phase))])


def write_estimates(root: Path, run: str, method: str, poses: np.ndarray) -> None:
    table = pd.DataFrame({"step": np.arange(STEPS), "t": np.arange(STEPS) * 0.1})
    table["x"], table["y"], table["theta"] = poses[:, 0], poses[:, 1], poses[:, 2]
    for column in TABLE_COLUMNS[5:]:
        table[column] = np.nan
    table["n_particles"] = 100
    folder = root / "reports/localize" / run
    folder.mkdir(parents=True, exist_ok=True)
    table[list(TABLE_COLUMNS)].to_csv(folder / f"{method}.csv", index=False)


def write_run(root: Path, name: str, truth: np.ndarray, has_truth: bool, **extra) -> None:
    traj = Trajectory(np.arange(STEPS) * 0.1, truth, path_truth())
    ranges = np.full((STEPS, 31), 3.0, dtype=np.float32)
    meta = {"name": name, "map": name[:-5], "sensor": SENSOR, "has_truth": has_truth, **extra}
    save_trajectory(traj, root / "data/trajectories" / name, ranges, meta)


def context(root: Path, bag_entries: dict, runs: list[str]) -> ReportContext:
    localization = evaluate_runs(
        runs,
        root / "data/trajectories",
        [root / "reports/localize"],
        root / "reports/metrics/localization.json",
        root / "reports/table2",
    )
    artifacts = Artifacts(root, path_truth(), with_timings(root, localization), {}, {})
    return ReportContext(
        builder=Builder(root, root / "reports", {}),
        artifacts=artifacts,
        localizers=Localizers.load(),
        verdicts=[],
        legend={},
        run={"profile": "smoke", "sites": dict.fromkeys(bag_entries, "bag")},
        figure_localizers=[],
        site_runs={"bag": ["real"]},
    )


def blocks(ctx: ReportContext) -> list:
    (section,) = sites.SECTION.build(ctx, sites.SECTION)
    (name,) = ctx.sites
    assert (section.id, section.title) == (f"site-{name}", f"Site {name} (bag)")
    return section.blocks


def test_the_site_sections_come_just_before_provenance() -> None:
    ids = [spec.id for spec in SECTIONS]
    assert ids[-2:] == ["site-{name}", "provenance"]


def test_a_bag_with_truth_shows_its_table2_figures(tmp_path: Path) -> None:
    truth = path_truth()
    built = {"split": {"mode": "window", "map_scans": 12, "evaluation_scans": 20}}
    write_run(tmp_path, "office_real", truth, True, **built, coverage={"covered": 17, "steps": 20})
    offset = np.array([0.1, -0.2, 0.0])
    write_estimates(tmp_path, "office_real", "amcl", truth + offset)
    timing = {"amcl": {"time_per_scan_s": 0.004}}
    (tmp_path / "reports/localize_timing").mkdir(parents=True)
    (tmp_path / "reports/localize_timing/office_real.json").write_text(json.dumps(timing))
    found = blocks(context(tmp_path, {"office": {"bag": "b"}}, ["office_real"]))
    table2, modern, _ = [b for b in found if isinstance(b, Table)]
    assert table2.header[:3] == ["method", "x error mean [m]", "x error std [m]"]
    assert [row[:3] for row in table2.rows] == [["amcl", "0.1000", "0.0000"]]
    assert modern.header[-1] == "time per scan [ms]" and modern.rows[0][-1] == "4"
    texts = [b.text for b in found if isinstance(b, Para)]
    assert any("built from 12 scans of the bag (window split)" in t for t in texts)
    assert any("covers 17 of 20 evaluated poses" in t for t in texts)
    assert not any("only consistency" in t for t in texts)


def test_a_bag_without_truth_shows_speed_and_agreement(tmp_path: Path) -> None:
    poses = path_truth()
    write_run(tmp_path, "robot_real", np.full((STEPS, 3), np.nan), False)
    write_estimates(tmp_path, "robot_real", "amcl_global", poses)
    shifted = poses + np.array([0.3, 0.4, 0.0])
    shifted[:10] = np.nan  # not yet localized: left out of the agreement
    write_estimates(tmp_path, "robot_real", "scanlocnet", shifted)
    timing = {"amcl_global": {"time_per_scan_s": 0.02}, "scanlocnet": {"time_per_scan_s": 0.005}}
    (tmp_path / "reports/localize_timing").mkdir(parents=True)
    (tmp_path / "reports/localize_timing/robot_real.json").write_text(json.dumps(timing))
    found = blocks(context(tmp_path, {"robot": {"bag": "b"}}, []))
    texts = [b.text for b in found if isinstance(b, Para)]
    assert any("only consistency and speed can be scored" in t for t in texts)
    (table,) = [b for b in found if isinstance(b, Table)]
    assert table.rows == [
        ["amcl_global", "20", "reference", "–"],
        ["scanlocnet", "5", "0.500", str(STEPS - 10)],
    ]
