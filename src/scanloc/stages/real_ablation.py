"""`real_ablation` stage (beyond the paper): the learned localizer trained without one of a real
log's measured laser corruptions (or without all of them, or with all of them: the matched
baseline `none`), scored on the log's held-out real scans (conf/real_ablation.yaml). The
report's ablation table shows what each corruption, and the verification, changes in top-K
recall on real scans, every variant trained alike."""

from __future__ import annotations

import tempfile
from pathlib import Path

from omegaconf import DictConfig, open_dict

from scanloc.evaluate.table2 import RECALL_K, evaluate_all
from scanloc.io import write_json
from scanloc.localize.catalog import raw_config
from scanloc.localize.kinds import LocalizeInputs, run_localizer
from scanloc.sensor.corruptions import KINDS
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages._app import conf_dir, stage_main, timed_stage, to_dict
from scanloc.stages.group_files import load_group_files
from scanloc.stages.localize import laser_mount
from scanloc.stages.train_scanlocnet import train
from scanloc.trajectory.format import load_trajectory

VARIANTS = ("none", *KINDS, "noise", "all")


def variant_off(variant: str) -> list[str]:
    """The corruption kinds a variant switches off."""
    if variant not in VARIANTS:
        raise ValueError(f"variant: expected one of {list(VARIANTS)}, got {variant!r}")
    if variant == "none":
        return []
    return [*KINDS, "noise"] if variant == "all" else [variant]


def localizer_config(name: str, model: Path, calibration_scans: str) -> dict:
    """conf/localizer/<name>.yaml (merged over its defaults list) with this model and, where
    it verifies its hypotheses, these calibration scans."""
    cfg = raw_config(name, Path(conf_dir()) / "localizer")
    learned = {**cfg["learned"], "model": str(model)}
    if learned.get("verified"):
        learned["calibration_scans"] = calibration_scans
    return {**cfg, "learned": learned}


def score_on_run(cfg: DictConfig, model: Path) -> dict[str, float]:
    """The evaluation's metrics (scanloc.evaluate.table2.evaluate_all) of the model's hypotheses
    on the run's scans, raw (top-1/5/20 recall) and verified (top-1 recall, its median error
    and calibration error)."""
    run_dir = Path(cfg.run_dir)
    trajectory, ranges = load_trajectory(run_dir)
    laser = laser_spec_from_config(to_dict(cfg.sensor))
    inputs = LocalizeInputs(trajectory, ranges, Path(cfg.map_yaml), laser, laser_mount(run_dir))
    calibration = str(cfg.val_dataset)
    runs = {
        name: run_localizer(localizer_config(name, model, calibration), inputs)
        for name in ("scanlocnet", "scanlocnet_verified")
    }
    metrics = evaluate_all(
        trajectory.truth,
        {name: run.table for name, run in runs.items()},
        hypotheses={name: run.hypotheses["poses"] for name, run in runs.items()},
        scores={"scanlocnet_verified": runs["scanlocnet_verified"].hypotheses["scores"]},
    )
    raw, verified = metrics["scanlocnet"], metrics["scanlocnet_verified"]
    return {f"top{k}_recall": raw[f"top{k}_recall"] for k in RECALL_K} | {
        "verified_top1_recall": verified["top1_recall"],
        "verified_pos_err_median_m": verified["pos_err_median_m"],
        "calibration_ece": verified["calibration_ece"],
    }


@stage_main("real_ablation")
def main(cfg: DictConfig) -> None:
    load_group_files(cfg)
    with open_dict(cfg):
        cfg.corruptions_off = variant_off(str(cfg.variant))
    name = f"real_ablation_{cfg.map_name}_{cfg.variant}"
    with timed_stage(name, cfg.timing_dir) as machine, tempfile.TemporaryDirectory() as tmp:
        kept, figures = train(cfg, Path(tmp))
        machine.update(figures)
        scores = score_on_run(cfg, Path(tmp) / "model.pt")
        doc = {
            "log": str(cfg.map_name),
            "variant": str(cfg.variant),
            "corruptions_off": list(cfg.corruptions_off),
            "val_top5_recall": kept.get("val_top5_recall"),
        }
        write_json(Path(cfg.metrics_path), doc | {k: round(v, 6) for k, v in scores.items()})


if __name__ == "__main__":
    main()
