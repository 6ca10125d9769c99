"""Where the pipeline's stages leave what the report shows, and how it is read.

Everything the report says is read from the artifact tree under a root (the repository when the
`report` stage runs). Required inputs that are missing raise an error naming the file; the
loaders of optional ones return None (or nothing) and the sections say what is missing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scanloc.evaluate.metrics import check_table
from scanloc.evaluate.table2 import ordered_methods, read_timings
from scanloc.hardware import MACHINE_KEYS, device_sentence
from scanloc.io import read_json
from scanloc.report.paper import ENSEMBLE_SOURCE, PAPER_DRIVE, ROWS, TRANSFER
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import OccupancyGrid

TRAJECTORIES = Path("data/trajectories")
MAPS_DIR = Path("data/maps")
SCANS_DIR = Path("data/scans")
METRICS_DIR = Path("reports/metrics")
METRICS_JSON = METRICS_DIR / "localization.json"
GLOBAL_METRICS_JSON = METRICS_DIR / "global_localization.json"
REAL_SEEDS_JSON = METRICS_DIR / "real_seeds.json"
LOOK_ALIKES_JSON = METRICS_DIR / "look_alikes.json"
LOCALIZE_TIMING_DIR = Path("reports/localize_timing")
# The wall-clock figures per localizer that the report shows beside the evaluated metrics.
TIMING_FIGURES = ("time_per_scan_s", "time_per_scan_median_s", "setup_s")
LOCALIZE_DIRS = (Path("reports/localize"), Path("reports/localize_cnn"))
TIMING_DIR = Path("reports/timing")
REPORT_TIMING = "report"  # this stage's own timing file, from its previous run: not counted


def required(path: Path, what: str) -> Path:
    """`path`, or an error naming it and what the report needs it for."""
    if not path.exists():
        raise FileNotFoundError(f"{path}: missing, required by the report ({what})")
    return path


def as_float(value: Any) -> float:
    """A metric as a float; NaN for a missing, non-numeric or boolean one."""
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return math.nan
    return float(value)


@dataclass(frozen=True)
class TrainingRun:
    """One training run's artifacts: per-epoch history, final metrics and the config as run."""

    history: pd.DataFrame
    metrics: Mapping[str, Any]
    config: Mapping[str, Any]
    # The row's further seeds trained in this run (models/<row>/seeds/<seed>/; for the 1D CNN
    # 200k the ensemble's members, trained exactly like it): what its seed spread is taken over.
    replicates: tuple[TrainingRun, ...] = ()

    @property
    def seeds(self) -> tuple[TrainingRun, ...]:
        """This run and its replicates: one run per seed of the row."""
        return (self, *self.replicates)

    @property
    def val_mae(self) -> float:
        """Final epoch's validation MAE of this seed (the metrics file's `val_mae` is the
        mean over the row's seeds)."""
        return float(self.history["val_mae"].iloc[-1]) if len(self.history) else math.nan

    @property
    def train_mae(self) -> float:
        """Final epoch's training MAE."""
        return float(self.history["train_mae"].iloc[-1]) if len(self.history) else math.nan

    @property
    def epoch_s(self) -> float:
        return as_float(self.metrics.get("epoch_s"))

    @property
    def samples(self) -> int:
        return int(self.config.get("samples", self.metrics.get("samples", 0)) or 0)

    @property
    def epochs(self) -> int:
        return len(self.history)

    def val_mae_at(self, epoch: int) -> float:
        """Validation MAE after `epoch` epochs (NaN if the run is shorter)."""
        rows = self.history[self.history["epoch"] == epoch]
        return float(rows["val_mae"].iloc[0]) if len(rows) else math.nan

    @property
    def device(self) -> str:
        return device_sentence(self.metrics.get("device"))


def metrics_path(name: str) -> Path:
    """Where the train / transfer stage writes a run's final metrics (a DVC metrics file)."""
    if name.startswith("transfer/"):
        return METRICS_DIR / f"transfer_{name.removeprefix('transfer/')}.json"
    return METRICS_DIR / f"train_{name}.json"


def timing_path(name: str) -> Path:
    """The stage's timing file, which holds the run's machine-dependent figures (epoch_s,
    device: scanloc.hardware.MACHINE_KEYS) beside its wall time."""
    return TIMING_DIR / metrics_path(name).name


def _history(path: Path) -> pd.DataFrame:
    history = pd.read_csv(required(path, "per-epoch training history"))
    missing = [c for c in ("epoch", "train_mae", "val_mae") if c not in history.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}")
    return history


# What makes two trainings replicates of one row: everything in config.json but the seed.
REPLICATE_KEYS = (
    "model",
    "dataset",
    "samples",
    "epochs",
    "batch_size",
    "lr",
    "lr_decay",
    "dropout",
)


def _replicate(folder: Path, config: Mapping[str, Any]) -> TrainingRun:
    """A further seed of a row: fit's files in `folder` (history.csv, metrics.json)."""
    metrics = read_json(required(folder / "metrics.json", "a seed's final training metrics"))
    return TrainingRun(_history(folder / "history.csv"), metrics, config)


def load_replicates(root: Path, name: str, config: Mapping[str, Any]) -> tuple[TrainingRun, ...]:
    """The row's further seeds: models/<name>/seeds/<seed>/, and for the 1D CNN 200k the
    ensemble's members where the ensemble was trained exactly like it."""
    folders = sorted((root / "models" / name / "seeds").glob("*/history.csv"))
    if name == ENSEMBLE_SOURCE:
        ensemble = root / "models" / "ensemble"
        if (ensemble / "config.json").is_file():
            ensemble_config = read_json(ensemble / "config.json")
            # Member k is seed + k: the same base seed, or a member may repeat the row itself.
            alike = ("seed", *REPLICATE_KEYS)
            if all(ensemble_config.get(k) == config.get(k) for k in alike):
                folders += sorted(ensemble.glob("member_*/history.csv"))
    return tuple(_replicate(path.parent, config) for path in folders)


def load_run(root: Path, name: str) -> TrainingRun | None:
    """A run's history and config (models/<name>/), final metrics (`metrics_path`) and further
    seeds (`load_replicates`), or None if its model folder does not exist."""
    folder = root / "models" / name
    if not folder.is_dir():
        return None
    history = _history(folder / "history.csv")
    metrics = read_json(required(root / metrics_path(name), "final training metrics"))
    timing = root / timing_path(name)
    if timing.is_file():  # absent when the models came from elsewhere: epoch_s is then NaN
        figures = read_json(timing)
        metrics = {**metrics, **{k: figures[k] for k in MACHINE_KEYS if k in figures}}
    config = read_json(required(folder / "config.json", "training parameters as run"))
    return TrainingRun(history, metrics, config, load_replicates(root, name, config))


def load_runs(root: Path) -> dict[str, TrainingRun]:
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


def estimate_tables(root: Path, run: str, methods: list[str]) -> dict[str, pd.DataFrame]:
    """The estimate tables of `methods` that trajectory `run` has, in the order given."""
    found = {}
    for method in methods:
        for folder in LOCALIZE_DIRS:
            path = root / folder / run / f"{method}.csv"
            if path.is_file():
                found[method] = pd.read_csv(path)
    return found


def load_truth(root: Path, run: str) -> np.ndarray:
    """True poses (T, 3) of trajectory `run`."""
    truth_path = required(root / TRAJECTORIES / run / "truth.npy", "true trajectory")
    truth = np.load(truth_path)
    if truth.ndim != 2 or truth.shape[1] != 3:
        raise ValueError(f"{truth_path}: expected true poses of shape (T, 3), got {truth.shape}")
    return truth


def map_yaml(root: Path, name: str) -> Path:
    return root / MAPS_DIR / name / "map.yaml"


def dataset_map_name(meta: Mapping[str, Any]) -> str:
    """The map a dataset was taken on: meta.json's `map` is {"name": ..., ...} (or a bare name)."""
    entry = meta.get("map", "?")
    return str(entry.get("name", "?")) if isinstance(entry, Mapping) else str(entry)


def find_dataset(root: Path, map_name: str) -> Path | None:
    """The smallest dataset (then first by name) whose meta.json says it was taken on `map_name`."""
    found = []
    for meta_path in sorted((root / SCANS_DIR).glob("*/meta.json")):
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
    is_val = np.load(required(dataset / "is_val.npy", "train/validation split"), mmap_mode="r")
    index = int(np.argmax(is_val)) if np.any(is_val) else 0
    poses = np.load(required(dataset / "poses.npy", "scan poses"), mmap_mode="r")
    ranges = np.load(required(dataset / "ranges.npy", "scan ranges"), mmap_mode="r")
    return np.array(poses[index], dtype=np.float64), np.array(ranges[index], np.float64), index


def scanlocnet_run(root: Path, map_name: str) -> tuple[dict | None, pd.DataFrame | None]:
    """The learned localizer's final metrics and training history on a map (None if absent)."""
    metrics_file = root / METRICS_DIR / f"scanlocnet_{map_name}.json"
    history_path = root / "models" / "scanlocnet" / map_name / "history.csv"
    metrics = read_json(metrics_file) if metrics_file.is_file() else None
    timing = root / TIMING_DIR / f"train_scanlocnet_{map_name}.json"
    if metrics is not None and timing.is_file():  # its machine-dependent figures (train_s)
        figures = read_json(timing)
        metrics |= {k: figures[k] for k in MACHINE_KEYS if k in figures}
    history = pd.read_csv(history_path) if history_path.is_file() else None
    return metrics, history


def stage_timings(root: Path) -> list[tuple[str, Any]]:
    """(stage, wall time [s] as recorded) of every stage's timing file but the report's own."""
    timings = []
    for path in sorted((root / TIMING_DIR).glob("*.json")):
        if path.stem == REPORT_TIMING:
            continue
        doc = read_json(path)
        timings.append((str(doc.get("stage", path.stem)), doc.get("wall_s")))
    return timings


def localize_timings(root: Path, run: str) -> dict[str, dict[str, float]]:
    """{localizer: wall-clock figures} of trajectory `run`, from the localize stages' timing
    files (reports/localize_timing/<run>.json, <run>_cnn.json): they measure the machine, so
    they live outside the evaluate stage's hashed metrics; {} if there are none."""
    timings: dict[str, dict[str, float]] = {}
    for suffix in ("", "_cnn"):
        timings |= read_timings(root / LOCALIZE_TIMING_DIR / f"{run}{suffix}.json")
    return timings


def with_timings(
    root: Path, localization: Mapping[str, Mapping[str, Mapping[str, Any]]]
) -> dict[str, dict[str, dict[str, Any]]]:
    """The evaluated metrics of every trajectory with each localizer's wall-clock figures
    (`TIMING_FIGURES`, where measured) merged in."""
    merged = {}
    for run, methods in localization.items():
        timings = localize_timings(root, run)
        merged[run] = {
            name: metrics | {k: v for k, v in timings.get(name, {}).items() if k in TIMING_FIGURES}
            for name, metrics in methods.items()
        }
    return merged


def load_global_figures(root: Path) -> Mapping[str, Mapping[str, Mapping[str, Any]]] | None:
    """{map: {localizer: figures over the evaluation seeds}} from evaluate, or None."""
    path = root / GLOBAL_METRICS_JSON
    return read_json(path) if path.is_file() else None


def load_real_seed_figures(root: Path) -> Mapping[str, Mapping[str, Any]] | None:
    """{<log>_<run>: {odometry: {localizer: figures over filter seeds}}} from evaluate, or
    None."""
    path = root / REAL_SEEDS_JSON
    return read_json(path) if path.is_file() else None


def load_look_alikes(root: Path) -> Mapping[str, Mapping[str, Any]] | None:
    """{map: its symmetries and look-alike stretches (evaluate/look_alikes.py)}, or None."""
    path = root / LOOK_ALIKES_JSON
    return read_json(path) if path.is_file() else None


def total_stage_seconds(root: Path) -> float:
    """The sum of the stages' wall times in reports/timing/ (the report's own excluded)."""
    return sum(float(wall_s or 0.0) for _, wall_s in stage_timings(root))


@dataclass
class Artifacts:
    """What several sections and the claims read, loaded once: the paper drive's truth and
    estimate tables, the localization metrics of every trajectory (with the localize stages'
    wall-clock figures merged in), the training runs, the figures over seeds (trajectory
    seeds of the maps, filter seeds of the real logs) and the maps' look-alike stretches (None
    if evaluate wrote none)."""

    root: Path
    truth: np.ndarray
    localization: Mapping[str, Mapping[str, Mapping[str, Any]]]
    runs: Mapping[str, TrainingRun]
    tables: Mapping[str, pd.DataFrame]
    _grids: dict[str, OccupancyGrid] = field(default_factory=dict, repr=False)
    global_figures: Mapping[str, Mapping[str, Mapping[str, Any]]] | None = None
    real_seed_figures: Mapping[str, Mapping[str, Any]] | None = None
    look_alikes: Mapping[str, Mapping[str, Any]] | None = None

    @classmethod
    def load(cls, root: Path) -> Artifacts:
        truth = load_truth(root, PAPER_DRIVE)
        path = root / METRICS_JSON
        localization = read_json(required(path, "localization metrics from evaluate"))
        if PAPER_DRIVE not in localization:
            raise ValueError(f"{path}: field '{PAPER_DRIVE}': missing (paper Table 2)")
        runs = load_runs(root)
        tables = load_tables(root, PAPER_DRIVE, len(truth))
        return cls(
            root,
            truth,
            with_timings(root, localization),
            runs,
            tables,
            global_figures=load_global_figures(root),
            real_seed_figures=load_real_seed_figures(root),
            look_alikes=load_look_alikes(root),
        )

    @property
    def paper_metrics(self) -> Mapping[str, Mapping[str, Any]]:
        """The localization metrics of the paper's drive, per localizer (Table 2)."""
        return self.localization[PAPER_DRIVE]

    def grid(self, name: str) -> OccupancyGrid | None:
        """data/maps/<name>/map.yaml, read once; None if the map is absent."""
        if name not in self._grids:
            path = map_yaml(self.root, name)
            if not path.is_file():
                return None
            self._grids[name] = load_map(path)
        return self._grids[name]
