"""A site's kind reaches the chain's stages as one config group (`+site_kind=<kind>`,
conf/site_kind/), and composes to what the per-kind flag strings of the three former chains
did: every value those stages read is the same, so their outputs keep their bytes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"

# The groups that stages/group_files.py replaces by the file `<group>_file` names: their
# composed option does not matter where the file is given.
FILE_GROUPS = ("sensor", "noise", "corruptions")

LOG_FILES = (
    "~sensor ~noise +sensor_file=data/maps/intel/sensor.yaml +noise_file=data/maps/intel/noise.yaml"
)
# (stage config, the overrides both commands share, the former chains' flags, the kind)
FORMER_COMMANDS = [
    ("scans", "dataset=map_validation dataset.map=intel", LOG_FILES, "log"),
    ("scans", "dataset=map_validation dataset.map=robot",
     "~sensor +sensor_file=data/maps/robot/sensor.yaml", "bag"),
    ("scans", "dataset=map_validation dataset.map=simple_rooms", "", "map"),
    ("scanlocnet", "map_name=intel",
     f"{LOG_FILES} +corruptions_file=data/maps/intel/corruptions.yaml "
     "real_scans.dataset=data/scans/intel_mapping real_log=true", "log"),
    ("scanlocnet", "map_name=robot",
     "~sensor +sensor_file=data/maps/robot/sensor.yaml real_log=true", "bag"),
    ("scanlocnet", "map_name=simple_rooms", "", "map"),
    ("localize", "map_name=intel trajectory=intel_real",
     "~sensor +sensor_file=data/maps/intel/sensor.yaml", "log"),
    ("localize", "map_name=robot trajectory=robot_real",
     "~sensor +sensor_file=data/maps/robot/sensor.yaml", "bag"),
    ("localize_seeds", "map_name=fr079 trajectory=fr079_kidnap odometry=laser",
     "~sensor +sensor_file=data/maps/fr079/sensor.yaml", "log"),
]  # fmt: skip


def _job_config(config_name: str, overrides: list[str]) -> dict[str, Any]:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose(config_name=config_name, overrides=overrides)
    return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]


def _flat(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for key, value in node.items():
            out |= _flat(value, f"{prefix}.{key}" if prefix else str(key))
        return out
    return {prefix: node}


@pytest.mark.parametrize(("config_name", "shared", "flags", "kind"), FORMER_COMMANDS)
def test_the_kind_group_composes_what_the_former_flags_did(
    config_name: str, shared: str, flags: str, kind: str
) -> None:
    former = _job_config(config_name, [*shared.split(), *flags.split(), "profile=laptop"])
    now = _job_config(config_name, [*shared.split(), f"+site_kind={kind}", "profile=laptop"])
    for group in FILE_GROUPS:
        if former.get(f"{group}_file"):  # replaced by the file's content either way
            former.pop(group, None)
            now.pop(group, None)
    former_values, now_values = _flat(former), _flat(now)
    for key, value in former_values.items():
        assert key in now_values, f"{config_name} +site_kind={kind}: '{key}' is gone"
        assert now_values[key] == value, f"{config_name} +site_kind={kind}: '{key}' differs"
    # What the group adds beyond the former flags reads a file the stage does not use, or a
    # key the stage's config does not have (`real_log` in localize): nothing a stage reads.
    added = set(now_values) - set(former_values)
    allowed = {f"{group}_file" for group in FILE_GROUPS} | {"real_log", "real_scans.dataset"}
    allowed |= {k for k in now_values if k.split(".")[0] in FILE_GROUPS}
    assert added <= allowed, f"{config_name} +site_kind={kind} adds {sorted(added - allowed)}"
