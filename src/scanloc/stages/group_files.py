"""`+sensor_file=<yaml>` / `+noise_file=<yaml>`: a stage's sensor or noise config read from a
file in place of a conf/ group option. The `real` stage reads a log's laser from the log itself
and writes it into data/maps/<log>/ (sensor.yaml, noise.yaml), so that a log needs no
hand-written conf/sensor file; the stages after it (scans, train_scanlocnet, localize) call
this first thing."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf, open_dict

GROUPS = ("sensor", "noise")


def load_group_files(cfg: DictConfig) -> None:
    """Replace cfg.sensor / cfg.noise by the YAML file that cfg.sensor_file / noise_file name."""
    for group in GROUPS:
        if cfg.get(f"{group}_file"):
            with open_dict(cfg):
                cfg[group] = OmegaConf.load(cfg[f"{group}_file"])
