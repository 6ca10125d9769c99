"""`train` stage: train one Table 1 row, or the ensemble's further members, on a scan dataset.

Under DVC each row writes to models/<row>/. A run by hand or a job of a Hydra multirun (a sweep)
writes into its own Hydra folder instead (stages/_app.py), so it never overwrites the
pipeline's models.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from scanloc.hardware import split_machine_figures
from scanloc.io import write_json
from scanloc.stages._app import stage_main, timed_stage, to_dict


def run_config(cfg: DictConfig) -> dict[str, Any]:
    """What the report shows as "Table 1 as run" (deterministic: no times, no paths)."""
    exp = cfg.experiment
    return {
        "experiment": exp.name,
        "profile": cfg.profile.name,
        "model": str(cfg.model.net._target_).rsplit(".", 1)[-1],
        "dataset": exp.dataset,
        "samples": int(exp.samples),
        "epochs": int(exp.epochs),
        "batch_size": int(exp.batch_size),
        "lr": float(cfg.model.lr),
        "lr_decay": float(cfg.model.lr_decay),
        "dropout": float(cfg.model.net.get("dropout", 0.0)),
        "seed": int(exp.seed),
        "members": int(exp.get("members", 1)),
        "seeds": int(exp.get("seeds", 1)),
    }


def train(
    cfg: DictConfig, out_dir: Path, metrics_path: Path, machine: dict[str, Any]
) -> dict[str, Any]:
    """Train what `cfg.experiment` describes into out_dir and return its metrics; its
    machine-dependent figures go into `machine` (the stage's timing file), not metrics_path."""
    # Imported here so that `--cfg job` and a sweep's parent process stay fast.
    from scanloc.models.seed_replicates import train_further_seeds
    from scanloc.models.stacked_ensemble import fit_stacked
    from scanloc.models.training import fit

    exp = cfg.experiment
    common = {
        "model_cfg": to_dict(cfg.model.net),
        "dataset_dir": Path(cfg.dataset_dir),
        "epochs": int(exp.epochs),
        "batch_size": int(exp.batch_size),
        "lr": float(cfg.model.lr),
        "lr_decay": float(cfg.model.lr_decay),
        "max_samples": int(exp.samples),
    }
    members = int(exp.get("members", 1))
    if members > 1:
        # Member 0 is the Table 1 cnn1d_200k model itself; train members 1..members-1 together.
        seeds = [int(exp.seed) + k for k in range(1, members)]
        out_dirs = [out_dir / f"member_{k}" for k in range(1, members)]
        results = fit_stacked(
            out_dirs=out_dirs, seeds=seeds, trainer_cfg=to_dict(cfg.trainer), **common
        )
        metrics = {f"member_{k}": r for k, r in zip(range(1, members), results, strict=True)}
    else:
        metrics = fit(
            out_dir=out_dir,
            seed=int(exp.seed),
            trainer_cfg=to_dict(cfg.trainer),
            checkpoint_dir=Path(cfg.checkpoint_dir),
            **common,
        )
        if metrics:  # rank 0 of a DDP run, or the only process
            metrics = train_further_seeds(
                metrics=metrics,
                out_dir=out_dir,
                seed=int(exp.seed),
                seeds=int(exp.get("seeds", 1)),
                fit_kwargs={**common, "trainer_cfg": to_dict(cfg.trainer)},
            )
    if metrics:  # empty on the non-zero ranks of a multi-process (DDP) run: rank 0 writes
        kept, figures = split_machine_figures(metrics)
        machine.update(figures)
        write_json(out_dir / "config.json", run_config(cfg))
        write_json(metrics_path, kept)
    return metrics


@stage_main("train")
def main(cfg: DictConfig) -> float:
    with timed_stage(f"train_{cfg.experiment.name}", cfg.timing_dir) as machine:
        metrics = train(cfg, Path(cfg.out_dir), Path(cfg.metrics_path), machine)
    # The value a Hydra sweeper would minimise.
    return float(metrics.get("val_mae", float("nan")))


if __name__ == "__main__":
    main()
