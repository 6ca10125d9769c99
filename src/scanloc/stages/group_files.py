"""`+sensor_file=<yaml>` / `+noise_file=<yaml>` / `+corruptions_file=<yaml>`: a stage's sensor,
noise or laser-corruption config read from a file in place of a conf/ group option. The `real`
stage reads a log's laser from the log itself, measures its corruptions on the mapping part,
and writes them into data/maps/<log>/ (sensor.yaml, noise.yaml, corruptions.yaml), so that a
log needs no hand-written conf/sensor file; the stages after it (scans, train_scanlocnet,
localize) call this first thing."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf, open_dict

GROUPS = ("sensor", "noise", "corruptions")


def load_group_files(cfg: DictConfig) -> None:
    """Replace cfg.<group> by the YAML file that cfg.<group>_file names, for each of GROUPS."""
    for group in GROUPS:
        if cfg.get(f"{group}_file"):
            with open_dict(cfg):
                cfg[group] = OmegaConf.load(cfg[f"{group}_file"])
