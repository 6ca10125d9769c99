"""`transfer` stage (paper §4.3, Fig. 9): the 1D CNN learns map 2 from random weights
(init=scratch) or from the weights it learnt on map 1 (init=pretrained); same data, epochs, seed.
A run by hand or a multirun job writes into its own Hydra folder, as the train stage's do."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from scanloc.hardware import split_machine_figures
from scanloc.io import write_json
from scanloc.models.seed_replicates import train_further_seeds
from scanloc.models.training import fit
from scanloc.stages._app import stage_main, timed_stage, to_dict

INITS = ("scratch", "pretrained")


@stage_main("transfer")
def main(cfg: DictConfig) -> None:
    if cfg.init not in INITS:
        raise ValueError(f"conf/transfer.yaml: init must be one of {INITS}, got {cfg.init!r}")
    run = cfg.transfer
    out_dir, metrics_path = Path(cfg.out_dir), Path(cfg.metrics_path)
    init_from = Path(cfg.pretrained_model) if cfg.init == "pretrained" else None
    fit_kwargs = {
        "model_cfg": to_dict(cfg.model.net),
        "dataset_dir": Path(cfg.dataset_dir),
        "epochs": int(run.epochs),
        "batch_size": int(run.batch_size),
        "lr": float(cfg.model.lr),
        "lr_decay": float(cfg.model.lr_decay),
        "max_samples": int(run.samples),
        "trainer_cfg": to_dict(cfg.trainer),
    }
    with timed_stage(f"transfer_{cfg.init}", cfg.timing_dir) as machine:
        metrics = fit(
            out_dir=out_dir,
            seed=int(run.seed),
            init_from=init_from,
            checkpoint_dir=Path(cfg.checkpoint_dir),
            **fit_kwargs,
        )
        if not metrics:  # a non-zero rank of a multi-process (DDP) run: rank 0 writes
            return
        # Every seed of the pre-trained run starts from the same map-1 model: they differ in
        # their data order and dropout masks only.
        metrics = train_further_seeds(
            metrics=metrics,
            out_dir=out_dir,
            seed=int(run.seed),
            seeds=int(run.get("seeds", 1)),
            fit_kwargs=fit_kwargs,
            init_from=init_from,
        )
        write_json(
            out_dir / "config.json",
            {
                "experiment": f"transfer_{cfg.init}",
                "profile": cfg.profile.name,
                "init": cfg.init,
                "init_from": cfg.pretrained_model if cfg.init == "pretrained" else None,
                "dataset": run.dataset,
                "samples": int(run.samples),
                "epochs": int(run.epochs),
                "batch_size": int(run.batch_size),
                "lr": float(cfg.model.lr),
                "lr_decay": float(cfg.model.lr_decay),
                "dropout": float(cfg.model.net.get("dropout", 0.0)),
                "seed": int(run.seed),
                "seeds": int(run.get("seeds", 1)),
            },
        )
        kept, figures = split_machine_figures(metrics)
        machine.update(figures)
        write_json(metrics_path, kept)


if __name__ == "__main__":
    main()
