"""Print a localizer config with every key its parts read, defaults included:
`python -m scanloc.localize.show hybrid`. A config file writes only what departs from its
parts' defaults; this shows what it amounts to (interpolations such as ${map_name} kept)."""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Mapping
from typing import Any

import yaml

from scanloc.localize.branch_and_bound import SearchParams, TopKParams
from scanloc.localize.catalog import raw_config
from scanloc.localize.config_params import parse_section
from scanloc.localize.fusion import FusionParams
from scanloc.localize.hypothesis_tracker import TrackerParams
from scanloc.localize.hypothesis_verification import VerifierParams
from scanloc.localize.kinds import KIND_SECTIONS, config_file, kind_of
from scanloc.localize.learned_localizer import LearnedParams
from scanloc.localize.mcl.config import MclConfig, sensor_model_params
from scanloc.localize.mcl.parts import MIXINGS, PROPOSALS, WEIGHTINGS

_PLAIN = {
    "search": SearchParams,
    "top_k": TopKParams,
    "learned": LearnedParams,
    "verifier": VerifierParams,
    "tracker": TrackerParams,
    "fusion": FusionParams,
}


def resolved(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """Every section the config's kind reads, each with all its keys."""
    where, kind = config_file(cfg), kind_of(cfg)
    sections = KIND_SECTIONS[kind]
    out: dict[str, Any] = {"meta": dict(cfg["meta"])}
    if "filter" in sections:
        mcl = MclConfig.from_sections(cfg, where)
        out["filter"] = dataclasses.asdict(mcl.filter)
        out["motion"] = dataclasses.asdict(mcl.odometry)
        out["sensor"] = {
            "laser_model_type": mcl.laser_model_type,
            "map_half_cell_offset": mcl.map_half_cell_offset,
            **dataclasses.asdict(mcl.laser),
            **sensor_model_params(cfg, where),
        }
        for registry in (PROPOSALS, MIXINGS, WEIGHTINGS):
            name, params = registry.params(cfg, where)
            out[registry.section] = {"type": name, **dataclasses.asdict(params)}
    for section, params in _PLAIN.items():
        if section in sections:
            out[section] = dataclasses.asdict(parse_section(params, cfg, section, where))
    if "ensemble" in sections:
        out["ensemble"] = dict(cfg.get("ensemble") or {})
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m scanloc.localize.show <localizer name>", file=sys.stderr)
        return 2
    try:
        cfg = resolved(raw_config(argv[0]))
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
