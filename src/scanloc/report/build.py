"""Build the reproduction report from the pipeline's artifacts: one self-contained HTML page
(figures embedded as data URIs, inline CSS, a Content-Security-Policy that forbids any request)
and a Markdown twin whose figures are PNG files under `<out_dir>/figures/`.

Both are rendered from one list of sections made of paragraphs, tables, figures and
preformatted text, so they always say the same. Everything shown is read from the artifact
tree under `root` (layout in the module constants below); required inputs that are missing
raise an error naming the file, optional ones are reported as missing in their section.
"""

from __future__ import annotations

import importlib.metadata
import math
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from scanloc.evaluate.metrics import check_table
from scanloc.evaluate.table2 import (
    METHOD_ORDER,
    MODERN_COLUMNS,
    TABLE2_COLUMNS,
    TABLE2_NOTE,
    format_rows,
    ordered_methods,
)
from scanloc.hardware import describe_machine
from scanloc.io import atomic_path, read_json
from scanloc.report import figures
from scanloc.report.claims import (
    DIRECTION_ONLY,
    NOT_REPRODUCED,
    NOT_TESTABLE,
    REPRODUCED,
    VERDICT_LEGEND,
    Claim,
    Run,
    check_claims,
)
from scanloc.report.document import (
    Builder,
    Para,
    Pre,
    Section,
    Table,
    render_html,
    render_markdown,
)
from scanloc.report.summary import headline_metrics
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import OccupancyGrid

SECTIONS: tuple[tuple[str, str], ...] = (
    ("maps-and-scans", "Maps and scans"),
    ("table-1", "Table 1: training parameters"),
    ("learning-curves", "Learning curves"),
    ("localization", "Localization"),
    ("table-2", "Table 2"),
    ("paper-claims", "Paper claims"),
    ("learned-localizer", "Beyond the paper: a learned localizer that localizes"),
    ("global-localization", "Global localization and kidnapping"),
    ("real-data", "Real data"),
    ("provenance", "Provenance"),
)
# And one section per map of params.yaml `maps` (id map-<name>), before the provenance.
MAPS = {"sparse_obstacles": "map 1 (paper Fig. 6)", "simple_rooms": "map 2 (paper Fig. 8)"}
MAP1 = "sparse_obstacles"
ROWS = {"mlp": "MLP", "cnn1d_20k": "1D CNN 20k", "cnn1d_200k": "1D CNN 200k", "cnn2d": "2D CNN"}
TRANSFER = {"transfer/scratch": "random init", "transfer/pretrained": "pre-trained on map 1"}
METHOD_NOTES = {
    "amcl": "Monte Carlo localization (ROS amcl as implemented) from scans and odometry, "
    "tracking from the first true pose; hypotheses = particles",
    "amcl_global": "the same amcl without an initial pose (global localization), recovery off",
    "amcl_recovery": "amcl without an initial pose, recovery on (ROS 1's 0.001 / 0.1)",
    "scanlocnet": "beyond the paper: scanloc's learned localizer, each scan alone (its best "
    "hypothesis; hypotheses = its ranked k)",
    "scanlocnet_track": "beyond the paper: the learned localizer's hypotheses tracked with "
    "odometry (Gaussian-sum filter; hypotheses = components)",
    "hybrid": "beyond the paper: amcl with the learned localizer as its proposal, no initial pose",
    "amcl_nav2": "amcl with ROS 2 nav2's defaults (diff-corrected odometry model)",
    "cnn_single": "one 1D CNN (Table 1 row cnn1d_200k), each scan alone",
    "cnn_ensemble": "mean of several 1D CNNs (circular mean for θ), each scan alone; "
    "covariance = the members' spread; hypotheses = members",
    "cnn_ekf": "beyond the paper: an EKF fusing the ensemble's poses (with its covariance) with "
    "odometry over time, outliers gated; hypotheses = 1 Gaussian",
}
PAPER_RUN = "sparse_obstacles_drive"  # paper §4.4: the drive through map 1
TRAJECTORIES = Path("data/trajectories")
TRAJECTORY = TRAJECTORIES / PAPER_RUN
METRICS_DIR = Path("reports/metrics")
METRICS_JSON = METRICS_DIR / "localization.json"
LOCALIZE_DIRS = (Path("reports/localize"), Path("reports/localize_cnn"))
TIMING_DIR = Path("reports/timing")
RASTER_SIZE, RASTER_MAX_RANGE = 384, 7.1  # paper eq. 1–4 and the author's code (7.0 + 0.1)
PACKAGES = ("torch", "lightning", "numpy", "hydra-core", "dvc", "numba", "matplotlib", "pandas")

# Paper Table 1 (None: no dropout).
PAPER_TABLE1: dict[str, dict[str, float | int | None]] = {
    "mlp": {
        "epochs": 2000,
        "batch_size": 100,
        "lr": 0.01,
        "lr_decay": 0.005,
        "dropout": 0.25,
        "samples": 20000,
    },
    "cnn1d_20k": {
        "epochs": 5000,
        "batch_size": 100,
        "lr": 0.006,
        "lr_decay": 0.0,
        "dropout": 0.1,
        "samples": 20000,
    },
    "cnn1d_200k": {
        "epochs": 400,
        "batch_size": 400,
        "lr": 0.006,
        "lr_decay": 0.0,
        "dropout": None,
        "samples": 200000,
    },
    "cnn2d": {
        "epochs": 400,
        "batch_size": 100,
        "lr": 0.01,
        "lr_decay": 0.005,
        "dropout": 0.1,
        "samples": 20000,
    },
}
TABLE1_PARAMS = (
    ("epochs", "Epochs"),
    ("batch_size", "Batch size"),
    ("lr", "Learn rate"),
    ("lr_decay", "LR-decay"),
    ("dropout", "Dropout"),
    ("samples", "Samples"),
)
# ---------------------------------------------------------------- artifact loading


def _required(path: Path, what: str) -> Path:
    if not path.exists():
        raise FileNotFoundError(f"{path}: missing, required by the report ({what})")
    return path


def metrics_path(name: str) -> Path:
    """Where the train / transfer stage writes a run's final metrics (a DVC metrics file)."""
    if name.startswith("transfer/"):
        return METRICS_DIR / f"transfer_{name.removeprefix('transfer/')}.json"
    return METRICS_DIR / f"train_{name}.json"


def load_run(root: Path, name: str) -> Run | None:
    """A run's history and config (models/<name>/) and final metrics (`metrics_path`), or None
    if its model folder does not exist."""
    folder = root / "models" / name
    if not folder.is_dir():
        return None
    history_path = _required(folder / "history.csv", "per-epoch training history")
    history = pd.read_csv(history_path)
    missing = [c for c in ("epoch", "train_mae", "val_mae") if c not in history.columns]
    if missing:
        raise ValueError(f"{history_path}: missing column(s) {missing}")
    metrics = read_json(_required(root / metrics_path(name), "final training metrics"))
    config = read_json(_required(folder / "config.json", "training parameters as run"))
    return Run(history, metrics, config)


def load_runs(root: Path) -> dict[str, Run]:
    """The Table 1 rows and the two transfer runs whose model folder exists."""
    runs = {name: load_run(root, name) for name in (*ROWS, *TRANSFER)}
    return {name: run for name, run in runs.items() if run is not None}


def load_tables(root: Path, run: str, steps: int) -> dict[str, pd.DataFrame]:
    """Every <method>.csv of trajectory `run` (reports/localize/<run>/ and
    reports/localize_cnn/<run>/), in report order, checked against the truth length."""
    paths = {
        p.stem: p for folder in LOCALIZE_DIRS for p in sorted((root / folder / run).glob("*.csv"))
    }
    tables = {}
    for name in ordered_methods(paths):
        table = pd.read_csv(paths[name])
        check_table(table, str(paths[name]), steps)
        tables[name] = table
    return tables


def load_truth(root: Path, run: str) -> np.ndarray:
    """True poses (T, 3) of trajectory `run`."""
    truth_path = _required(root / TRAJECTORIES / run / "truth.npy", "true trajectory")
    truth = np.load(truth_path)
    if truth.ndim != 2 or truth.shape[1] != 3:
        raise ValueError(f"{truth_path}: expected true poses of shape (T, 3), got {truth.shape}")
    return truth


def dataset_map_name(meta: Mapping[str, Any]) -> str:
    """The map a dataset was taken on: meta.json's `map` is {"name": ..., ...} (or a bare name)."""
    entry = meta.get("map", "?")
    return str(entry.get("name", "?")) if isinstance(entry, Mapping) else str(entry)


def find_dataset(root: Path, map_name: str) -> Path | None:
    """The smallest dataset (then first by name) whose meta.json says it was taken on `map_name`."""
    found = []
    for meta_path in sorted((root / "data" / "scans").glob("*/meta.json")):
        meta = read_json(meta_path)
        if dataset_map_name(meta) == map_name:
            found.append((int(meta.get("count", 0)), meta_path.parent.name, meta_path.parent))
    return min(found)[2] if found else None


def laser_from_meta(meta: Mapping[str, Any], meta_path: Path) -> LaserSpec:
    try:
        return laser_spec_from_config(meta.get("sensor"))
    except ValueError as err:
        raise ValueError(f"{meta_path}: field 'sensor': {err}") from None


def example_scan(dataset: Path) -> tuple[np.ndarray, np.ndarray, int]:
    """(pose, ranges, index) of the first validation scan (memory-mapped: datasets can be big)."""
    is_val = np.load(_required(dataset / "is_val.npy", "train/validation split"), mmap_mode="r")
    index = int(np.argmax(is_val)) if np.any(is_val) else 0
    poses = np.load(_required(dataset / "poses.npy", "scan poses"), mmap_mode="r")
    ranges = np.load(_required(dataset / "ranges.npy", "scan ranges"), mmap_mode="r")
    return np.array(poses[index], dtype=np.float64), np.array(ranges[index], np.float64), index


# ---------------------------------------------------------------- formatting helpers


def _num(value: Any, digits: int = 4) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    if isinstance(value, int):
        return f"{value:,}"
    return "–" if not math.isfinite(value) else f"{value:.{digits}g}"


def _scale(ours: Any, paper: Any) -> str:
    if not isinstance(ours, (int, float)) or not isinstance(paper, (int, float)) or not paper:
        return "–"
    return f"×{ours / paper:.3g}"


def package_versions() -> list[list[str]]:
    rows = [["python", platform.python_version()]]
    for name in PACKAGES:
        try:
            rows.append([name, importlib.metadata.version(name)])
        except importlib.metadata.PackageNotFoundError:
            rows.append([name, "not installed"])
    return rows


# ---------------------------------------------------------------- sections


def maps_section(b: Builder) -> tuple[Section, dict[str, OccupancyGrid]]:
    section = Section(*SECTIONS[0])
    section.blocks.append(
        Para(
            "The two maps, each with one scan of its dataset (the first validation scan) "
            "drawn as red beams; beams without a return are drawn light to the maximum range. "
            "For map 1 the same scan is also shown as the 1D CNN sees it (range per beam), "
            "around the robot, and rasterised as the 2D CNN's input image."
        )
    )
    grids: dict[str, OccupancyGrid] = {}
    for map_name, label in MAPS.items():
        yaml_path = b.root / "data" / "maps" / map_name / "map.yaml"
        if map_name == MAP1:
            _required(yaml_path, "map 1")
        if not yaml_path.is_file():
            rel = yaml_path.relative_to(b.root).as_posix()
            section.blocks.append(Para(f"{label} ({map_name}): not available ({rel})."))
            continue
        grids[map_name] = load_map(yaml_path)
        section.blocks += _map_views(b, map_name, label, grids[map_name])
    dataset_rows = []
    for meta_path in sorted((b.root / "data" / "scans").glob("*/meta.json")):
        meta = read_json(meta_path)
        is_val = np.load(_required(meta_path.parent / "is_val.npy", "split"), mmap_mode="r")
        dataset_rows.append(
            [
                meta_path.parent.name,
                dataset_map_name(meta),
                _num(meta.get("count")),
                f"{100 * float(np.mean(is_val)):.1f} %",
                _num(meta.get("seed")),
            ]
        )
    if dataset_rows:
        section.blocks.append(Para("Scan datasets (poses uniform over the free space, θ uniform)."))
        section.blocks.append(
            Table(["dataset", "map", "scans", "validation share", "seed"], dataset_rows)
        )
    return section, grids


def _map_views(b: Builder, map_name: str, label: str, grid: OccupancyGrid) -> list:
    """The map with an example scan, and for map 1 the scan's three other views."""
    dataset = find_dataset(b.root, map_name)
    if dataset is None:
        return [Para(f"{label}: no scan dataset found for {map_name}.")]
    laser = laser_from_meta(read_json(dataset / "meta.json"), dataset / "meta.json")
    pose, ranges, index = example_scan(dataset)
    angles = laser.beam_angles()
    if ranges.shape != angles.shape:
        raise ValueError(
            f"{dataset / 'ranges.npy'}: {ranges.size} beams, meta.json says {angles.size}"
        )
    width, height = grid.size_m
    title = f"{label}: {map_name}, {width:.2f} × {height:.2f} m"
    blocks = [
        b.figure(
            f"map_{map_name}.png",
            f"{title}; scan {index} of dataset {dataset.name} at x = {pose[0]:.2f} m, "
            f"y = {pose[1]:.2f} m, θ = {np.degrees(pose[2]):.1f}°.",
            lambda p: figures.plot_map_scan(grid, pose, ranges, angles, p, title, laser.range_max),
        )
    ]
    if map_name == MAP1:
        blocks += _scan_views(b, ranges, angles, laser)
    return blocks


def _scan_views(b: Builder, ranges: np.ndarray, angles: np.ndarray, laser: LaserSpec) -> list:
    image = figures.rasterize_scan(ranges, angles, RASTER_SIZE, RASTER_MAX_RANGE)
    return [
        b.figure(
            "scan_1d.png",
            "Paper Fig. 1a / 3: the raw scan, 667 ranges over ±120° "
            f"(no return = fill value {laser.no_return_value:g} m).",
            lambda p: figures.plot_scan_ranges(ranges, angles, p, laser.range_max),
        ),
        b.figure(
            "scan_2d.png",
            "Paper Fig. 1b: the scan's end points around the robot.",
            lambda p: figures.plot_scan_points(ranges, angles, p, laser.range_max),
        ),
        b.figure(
            "scan_image.png",
            f"Paper Fig. 5: the scan rasterised by eq. 1–4 "
            f"(x = sin α·r as row, y = cos α·r as column, {RASTER_SIZE}×{RASTER_SIZE} px, max "
            f"{RASTER_MAX_RANGE} m, fill-value points included, as in the author's code).",
            lambda p: figures.plot_scan_image(image, p, RASTER_MAX_RANGE),
        ),
    ]


def table1_section(b: Builder, runs: Mapping[str, Run]) -> Section:
    section = Section(*SECTIONS[1])
    profile = b.context.get("profile", "?")
    present = [r for r in ROWS if r in runs]
    if not present:
        section.blocks.append(Para("No Table 1 models found under models/."))
        return section
    section.blocks.append(
        Para(
            f"The paper's Table 1 beside the parameters as run in profile '{profile}' "
            "(models/<row>/config.json). The profile scales epochs and samples down to fit "
            "its time budget; the scale rows give the factor. Precision bf16-mixed is bf16 "
            "autocast with a float32 output layer (trainer precision auto, on CPUs with bf16 "
            "instructions). What was measured (docs/benchmarks.md, Precision): 4 seeds in "
            "each precision, where a Welch test found no significant difference of the mean "
            "validation MAE (|t| < 2); that is an absence of evidence at that sample size, "
            "not a proof that the two are equivalent."
        )
    )
    header = ["parameter"]
    for row in present:
        header += [f"{ROWS[row]} paper", f"{ROWS[row]} ours"]
    rows = []
    for key, title in TABLE1_PARAMS:
        line = [title]
        for row in present:
            line += [_num(PAPER_TABLE1[row][key]), _num(runs[row].config.get(key))]
        rows.append(line)
    for key, title in (("epochs", "epochs scale"), ("samples", "samples scale")):
        line = [title]
        for row in present:
            line += ["", _scale(runs[row].config.get(key), PAPER_TABLE1[row][key])]
        rows.append(line)
    for key in ("dataset", "model"):
        line = [key]
        for row in present:
            line += ["", str(runs[row].config.get(key, "–"))]
        rows.append(line)
    line = ["precision"]  # the paper's Keras trained in float32
    for row in present:
        line += ["32-true", str(runs[row].metrics.get("precision", "–"))]
    rows.append(line)
    section.blocks.append(Table(header, rows))
    transfer = [t for t in TRANSFER if t in runs]
    if transfer:
        section.blocks.append(
            Para(
                "Transfer to map 2 (paper §4.3): the same 1D CNN trained on map 2 from random "
                "weights and from the weights of the map-1 1D CNN (the paper pre-trained "
                "2000 epochs on 20k samples)."
            )
        )
        keys = ("dataset", "samples", "epochs", "batch_size", "lr", "lr_decay", "dropout")
        section.blocks.append(
            Table(
                ["run", *keys],
                [[TRANSFER[t]] + [_num(runs[t].config.get(k)) for k in keys] for t in transfer],
            )
        )
    return section


def _run_table(runs: Mapping[str, Run], names: Mapping[str, str]) -> Table:
    header = [
        "model",
        "final train MAE",
        "final val. MAE",
        "best val. MAE",
        "val. position error [m]",
        "val. heading error [°]",
        "s / epoch",
        "epochs",
        "parameters",
    ]
    rows = []
    for name, label in names.items():
        if name not in runs:
            continue
        run = runs[name]
        last = run.history.iloc[-1].to_dict() if len(run.history) else {}
        rows.append(
            [
                label,
                _num(run.train_mae),
                _num(run.val_mae),
                _num(run.metrics.get("best_val_mae")),
                _num(last.get("val_pos_err_m")),
                _num(last.get("val_heading_err_deg")),
                _num(run.metrics.get("epoch_s"), 3),
                _num(run.metrics.get("epochs")),
                _num(run.metrics.get("params")),
            ]
        )
    return Table(header, rows)


def curves_section(b: Builder, runs: Mapping[str, Run]) -> Section:
    section = Section(*SECTIONS[2])
    rows = {ROWS[r]: runs[r].history for r in ROWS if r in runs}
    if rows:
        section.blocks.append(
            b.figure(
                "fig7_learning_curves.png",
                "Paper Fig. 7: training (a) and validation (b) loss (MAE over x [m], y [m], "
                "θ [rad]) of the four Table 1 models, log scale.",
                lambda p: figures.plot_learning_curves(rows, p, "Table 1 models (map 1)"),
            )
        )
        section.blocks.append(_run_table(runs, ROWS))
    else:
        section.blocks.append(Para("No Table 1 training histories found under models/."))
    transfer = {TRANSFER[t]: runs[t].history for t in TRANSFER if t in runs}
    if transfer:
        section.blocks.append(
            b.figure(
                "fig9_transfer_curves.png",
                "Paper Fig. 9: training (a) and validation (b) loss of the 1D CNN on map 2, "
                "from random weights and pre-trained on map 1.",
                lambda p: figures.plot_learning_curves(transfer, p, "Transfer to map 2"),
            )
        )
        section.blocks.append(_run_table(runs, TRANSFER))
    else:
        section.blocks.append(Para("Transfer runs (models/transfer/) not available."))
    return section


def localization_section(
    b: Builder, grid: OccupancyGrid, truth: np.ndarray, tables: Mapping[str, pd.DataFrame]
) -> Section:
    section = Section(*SECTIONS[3])
    absent = [m for m in METHOD_ORDER if m not in tables]
    section.blocks.append(
        Para(
            f"The robot drives {len(truth)} steps through map 1 "
            f"({TRAJECTORY.as_posix()}). Each localizer estimates every step's pose: amcl from "
            "the scans and odometry, the CNNs from each step's scan alone."
        )
    )
    if absent:
        section.blocks.append(
            Para(f"Not available: {', '.join(absent)} (no reports/localize/<method>.csv).")
        )
    if not tables:
        return section
    rows = []
    for name, table in tables.items():
        valid = table[["x", "y", "theta"]].notna().all(axis=1)
        hypotheses = table["n_particles"].median() if "n_particles" in table else None
        rows.append(
            [
                name,
                METHOD_NOTES.get(name, "–"),
                f"{int(valid.sum())} / {len(table)}",
                _num(None if hypotheses is None else float(hypotheses), 4),
            ]
        )
    section.blocks.append(
        Table(["method", "what it is", "steps with an estimate", "median hypotheses"], rows)
    )
    section.blocks.append(
        b.figure(
            "fig10_trajectories.png",
            "Paper Fig. 10: position estimates (red) against the true path (blue), one "
            "panel per localizer.",
            lambda p: figures.plot_trajectories(grid, truth, tables, p),
        )
    )
    section.blocks.append(
        b.figure(
            "errors_over_time.png",
            "Position and heading error along the trajectory (log scale).",
            lambda p: figures.plot_errors_over_time(truth, tables, p),
        )
    )
    with_cov = {
        n: t
        for n, t in tables.items()
        if {"cov_xx", "cov_xy", "cov_yy"} <= set(t.columns) and t["cov_xx"].notna().any()
    }
    if with_cov:
        section.blocks.append(
            b.figure(
                "uncertainty.png",
                "Uncertainty: 2σ ellipses of the position covariance "
                "(ensemble: spread of the members; amcl: particle cloud) along the path; "
                "a calibrated 2σ ellipse holds the truth 86.5 % of the time.",
                lambda p: figures.plot_uncertainty(grid, truth, with_cov, p),
            )
        )
    return section


def table2_section(metrics: Mapping[str, Mapping[str, Any]]) -> Section:
    section = Section(*SECTIONS[4])
    section.blocks.append(
        Para(f"Paper Table 2 (its numbers were lost; layout as described). {TABLE2_NOTE}")
    )
    section.blocks.append(Table(*format_rows(metrics, TABLE2_COLUMNS)))
    section.blocks.append(
        Para(
            "Modern metrics: position error = Euclidean distance; heading error wrapped to "
            "±180° (unlike the sine difference it tells θ from 180° − θ); shares of steps "
            "within 0.1 / 0.25 / 0.5 m and gross failures beyond 1 m; calibration = share of "
            "steps whose true position lies inside the 1σ / 2σ ellipse of the estimate's "
            "position covariance (a calibrated Gaussian: 39.3 % / 86.5 %; the single CNN has "
            "no covariance). Time per scan is measured on the machine that ran the stage."
        )
    )
    section.blocks.append(Table(*format_rows(metrics, MODERN_COLUMNS)))
    return section


VERDICT_CLASSES = {
    REPRODUCED: "v-reproduced",
    DIRECTION_ONLY: "v-direction",
    NOT_REPRODUCED: "v-not",
    NOT_TESTABLE: "v-untestable",
}


def claims_section(claims: list[Claim]) -> Section:
    section = Section(*SECTIONS[5])
    section.blocks.append(
        Para(
            "Each finding of the paper (Section 4), what the paper reports, what we measured, "
            "and the verdict by the rule in the last column (its thresholds: "
            "conf/report.yaml). Our runs are scaled down by the profile (see Table 1), so "
            "numbers measured at a smaller scale are not expected to match the paper's; the "
            "verdict says so rather than excusing it. Verdicts:"
        )
    )
    section.blocks.append(
        Table(
            ["verdict", "meaning"],
            [[name, meaning] for name, meaning in VERDICT_LEGEND.items()],
            [VERDICT_CLASSES[name] for name in VERDICT_LEGEND],
        )
    )
    header = ["#", "paper's claim", "paper", "ours", "verdict", "rule"]
    rows = [[str(c.number), c.paper, c.paper_figure, c.ours, c.verdict, c.rule] for c in claims]
    section.blocks.append(Table(header, rows, [VERDICT_CLASSES[c.verdict] for c in claims]))
    return section


def provenance_section(b: Builder) -> Section:
    section = Section(*SECTIONS[9])
    ctx = b.context
    commit = ctx.get("git_commit") or "not recorded"
    section.blocks.append(
        Para(
            f"Profile: {ctx.get('profile', '?')}. Git commit: {commit}. Hardware (machine "
            f'that built this report): {describe_machine()}. Paper: R. Dietrich, "Deep Learning '
            'Localization", Oregon State University, 2017.'
        )
    )
    section.blocks.append(Table(["package", "version"], package_versions()))
    stage_rows, total = [], 0.0
    for path in sorted((b.root / TIMING_DIR).glob("*.json")):
        if path.stem == "report":  # this stage's own time, from its previous run
            continue
        doc = read_json(path)
        stage_rows.append([str(doc.get("stage", path.stem)), _num(doc.get("wall_s"), 4)])
        total += float(doc.get("wall_s", 0.0))
    if stage_rows:
        stage_rows.append(["total", _num(total, 4)])
        section.blocks.append(Table(["stage", "wall time [s]"], stage_rows))
    else:
        section.blocks.append(Para("No stage timings found (reports/timing/)."))
    params = ctx.get("params")
    if params:
        text = yaml.safe_dump(params, sort_keys=True, allow_unicode=True, default_flow_style=False)
        section.blocks.append(Pre("Resolved parameters", text))
    return section


TITLE = "scanloc: reproducing “Deep Learning Localization” (Dietrich 2017)"


def _summary(claims: list[Claim], profile: str) -> str:
    by_verdict: dict[str, list[str]] = {}
    for claim in claims:
        by_verdict.setdefault(claim.verdict, []).append(str(claim.number))
    verdicts = "; ".join(f"{v}: {', '.join(n)}" for v, n in by_verdict.items())
    return (
        f"A reproduction of R. Dietrich's 2017 paper: neural networks regress a robot's pose "
        f"from one laser scan in a known map and are compared with Monte Carlo localization "
        f"(amcl). Profile '{profile}'. Paper claims (section Paper claims) — {verdicts}."
    )


def build_report(
    root: Path,
    out_dir: Path,
    context: Mapping[str, Any],
    claim_thresholds: Mapping[str, Mapping[str, Any]],
) -> dict[str, Any]:
    """Write <out_dir>/report.html (self-contained), <out_dir>/report.md and
    <out_dir>/figures/*.png from the artifacts under `root`; return the headline metrics
    (summary.py).

    context: {"profile": str, "params": dict (resolved config), "git_commit": str | None,
    "maps": [names of params.yaml `maps`], "real_logs": [names of its `real_logs`]};
    claim_thresholds: conf/report.yaml's `claims`.
    """
    from scanloc.report import beyond, real_data

    root, out_dir = Path(root), Path(out_dir)
    b = Builder(root, out_dir, context)
    truth = load_truth(root, PAPER_RUN)
    all_metrics = read_json(_required(root / METRICS_JSON, "localization metrics from evaluate"))
    if PAPER_RUN not in all_metrics:
        raise ValueError(f"{root / METRICS_JSON}: field '{PAPER_RUN}': missing (paper Table 2)")
    metrics = all_metrics[PAPER_RUN]
    runs = load_runs(root)
    tables = load_tables(root, PAPER_RUN, len(truth))
    maps, grids = maps_section(b)
    claims = check_claims(runs, metrics, claim_thresholds)
    map_names = list(context.get("maps") or [MAP1])
    sections = [
        maps,
        table1_section(b, runs),
        curves_section(b, runs),
        localization_section(b, grids[MAP1], truth, tables),
        table2_section(metrics),
        claims_section(claims),
        beyond.learned_section(b, map_names, all_metrics),
        beyond.global_section(b, map_names, all_metrics),
        real_data.real_data_section(b, list(context.get("real_logs") or []), all_metrics),
        *[beyond.map_section(b, name, all_metrics) for name in map_names],
        provenance_section(b),
    ]
    summary = _summary(claims, str(context.get("profile", "?")))
    for stale in b.figure_dir.glob("*.png"):
        if stale.name not in b.written:
            stale.unlink()
    with atomic_path(out_dir / "report.md") as tmp:
        tmp.write_text(render_markdown(sections, TITLE, summary), encoding="utf-8")
    with atomic_path(out_dir / "report.html") as tmp:
        tmp.write_text(render_html(sections, TITLE, summary, b.figure_dir), encoding="utf-8")
    table1 = {row: runs[row].val_mae for row in ROWS if row in runs}
    return headline_metrics(
        table1,
        all_metrics,
        map_names,
        claims,
        total_stage_seconds(root),
        list(context.get("real_logs") or []),
    )


def total_stage_seconds(root: Path) -> float:
    """The sum of the stages' wall times in reports/timing/ (the report's own excluded)."""
    return sum(
        float(read_json(path).get("wall_s", 0.0))
        for path in sorted((root / TIMING_DIR).glob("*.json"))
        if path.stem != "report"
    )
