"""`train_scanlocnet` stage (beyond the paper): the learned localizer with ranked hypotheses for
one map, trained on scans simulated afresh every epoch (scanloc.scanlocnet.training); for a
real log also scored on its mapping part's tune hold-out (`real_scans.dataset`), and trained
with that part's real scans mixed in where `real_scans.share` > 0 (off by default).

Ctrl-C (SIGINT) or SIGTERM stops it within moments with one line on stderr and exit status
128 + the signal's number, nothing written; the same command resumes after the last finished
epoch from checkpoint_dir (outside the DVC output) and ends with an uninterrupted run's bytes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from scanloc.data.scan_dataset import load_scan_dataset
from scanloc.hardware import split_machine_figures
from scanloc.io import write_json
from scanloc.models.training import load_model
from scanloc.scanlocnet.model import top_k
from scanloc.scanlocnet.pose_grid import PoseGrid
from scanloc.scanlocnet.real_scans import load_real_scans
from scanloc.scanlocnet.resume import TrainingStopped
from scanloc.scanlocnet.scan_stream import StreamSpec
from scanloc.scanlocnet.schedule import training_epochs
from scanloc.scanlocnet.training import RECALL_K, fit_scanlocnet, hypothesis_metrics
from scanloc.sensor.corruptions import KINDS
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.stages.group_files import load_group_files
from scanloc.world.map_server import load_map


def stream_corruptions(cfg: DictConfig) -> dict:
    """The stream's laser corruptions (a real log's, measured by the `real` stage), less the
    kinds `corruptions_off` names (an ablation): their rate, or the range noise, set to 0."""
    corruptions = to_dict(cfg.corruptions) if cfg.get("corruptions") else {}
    for kind in cfg.get("corruptions_off") or ():
        if kind == "noise":
            corruptions["noise_scale_m"] = 0.0
        elif kind in KINDS:
            corruptions[kind] = {"rate": 0.0, "mean_run": 1.0}
        else:
            raise ValueError(f"corruptions_off: expected some of {[*KINDS, 'noise']}, got {kind!r}")
    return corruptions


def tune_holdout_metrics(dataset: Path, model_path: Path) -> dict[str, float]:
    """The trained model's top-1 errors and top-K recall on a real-scans dataset's validation
    split (a log's tune hold-out: real scans it never trained on, where `real_scans.share` is
    chosen), keys prefixed `tune_heldout_`."""
    data = load_scan_dataset(dataset)
    rows = np.flatnonzero(data.is_val)
    model = load_model(model_path)
    ranges = np.ascontiguousarray(data.ranges[rows], dtype=np.float32)
    hyp = top_k(model, ranges, max(RECALL_K))
    figures = hypothesis_metrics(hyp.poses, np.asarray(data.poses[rows]), "tune_heldout_")
    return figures | {"tune_heldout_scans": len(rows)}


def samples_per_cell_floor(cfg: DictConfig) -> int:
    """The fewest training scans per pose cell (scanloc.scanlocnet.schedule): a real log's map
    trains denser, its scans being harder to place than a simulated map's (`real_log`)."""
    run = cfg.training
    return int(
        run.real_log_min_samples_per_cell if cfg.get("real_log") else run.min_samples_per_cell
    )


def train(cfg: DictConfig, out_dir: Path) -> tuple[dict, dict]:
    """Train the configured ScanLocNet into `out_dir`: (deterministic metrics, machine
    figures). A stop signal exits the process (module docstring)."""
    run = cfg.training
    grid = PoseGrid.from_map(
        load_map(cfg.map_yaml),
        float(cfg.grid.cell_size),
        int(cfg.grid.heading_bins),
        float(cfg.grid.clearance),
    )
    stream = StreamSpec(
        map_yaml=str(cfg.map_yaml),
        sensor=to_dict(cfg.sensor),
        noise=to_dict(cfg.noise),
        clearance=float(cfg.grid.clearance),
        scans_per_epoch=int(run.scans_per_epoch),
        seed=int(run.seed),
        corruptions=stream_corruptions(cfg),
    )
    real = cfg.get("real_scans") or {}
    real_scans = None
    if real.get("dataset") and real.get("share"):
        real_scans = load_real_scans(
            Path(real["dataset"]), grid, float(real["share"]), stream.num_beams
        )
    try:
        metrics = fit_scanlocnet(
            model_cfg=to_dict(cfg.net),
            grid=grid,
            stream=stream,
            val_dataset=Path(cfg.val_dataset),
            out_dir=out_dir,
            epochs=training_epochs(
                int(run.epochs),
                int(run.scans_per_epoch),
                grid.num_cells,
                samples_per_cell_floor(cfg),
            ),
            batch_size=int(run.batch_size),
            lr=float(run.lr),
            weight_decay=float(run.weight_decay),
            pct_start=float(run.pct_start),
            trainer_cfg=to_dict(cfg.trainer),
            checkpoint_dir=Path(cfg.checkpoint_dir),
            real_scans=real_scans,
        )
    except TrainingStopped as stop:
        print(f"train_scanlocnet {cfg.map_name}: {stop}", file=sys.stderr)
        sys.exit(128 + stop.signum)
    if real.get("dataset"):
        metrics |= tune_holdout_metrics(Path(real["dataset"]), out_dir / "model.pt")
    return split_machine_figures(metrics)


@stage_main("scanlocnet")
def main(cfg: DictConfig) -> None:
    load_group_files(cfg)
    with timed_stage(f"train_scanlocnet_{cfg.map_name}", cfg.timing_dir) as machine:
        kept, figures = train(cfg, Path(cfg.out_dir))
        machine.update(figures)
        write_json(Path(cfg.metrics_path), kept | {"map": cfg.map_name})


if __name__ == "__main__":
    main()
