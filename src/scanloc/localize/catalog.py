"""The one list of localizers: every conf/localizer/<name>.yaml, read with its metadata.

A localizer config declares, in its `meta` section, what the pipeline and the report need to
know of it (its other sections are its parts' parameters, localize/kinds.py):
- `name`: the file's name;
- `kind`: the registered class or function that runs it (scanloc.localize.kinds);
- `group`: `tracking` (starts from the true first pose), `global` (no initial pose), or
  `learned` (from each scan, or learned hypotheses tracked over time);
- `note`: one line for the report's tables;
- `stages`: which pipeline stages run it (`localize`: every map, log and run; `localize_cnn`:
  the paper's CNN localizers on map 1; `[]`: a documented variant to run by hand);
- `global_table` (optional, false): whether the report's global-localization table lists it;
- `matched_to`, `differs_in` (optional, together): the baseline this variant is compared with
  and what it changes (`section` or `section.key` entries); every other setting of the two,
  composed in full, is equal (tests/test_matched_pairs.py). A claim about one file: never
  inherited by a config that names this one in its defaults.
Adding a localizer is adding one such file (plus, for a new kind, one registered class).
A config may inherit from another through its Hydra defaults list (`defaults: [amcl, _self_]`):
sections merge key by key as Hydra merges them, so metadata is inherited too, unless the file
sets its own.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

CONF_DIR = Path("conf/localizer")
GROUPS = ("tracking", "global", "learned")
STAGES = ("localize", "localize_cnn")
META_FIELDS = (
    "name",
    "kind",
    "group",
    "note",
    "stages",
    "global_table",
    "matched_to",
    "differs_in",
)
MATCH_FIELDS = ("matched_to", "differs_in")


@dataclass(frozen=True)
class LocalizerInfo:
    """What the pipeline and the report know of one localizer config."""

    name: str
    kind: str
    group: str
    note: str
    stages: tuple[str, ...]
    global_table: bool
    matched_to: str | None = None
    differs_in: tuple[str, ...] = ()


def _read(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ValueError(f"{path}: not valid YAML ({err})") from err
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping of localizer settings")
    return data


def raw_config(name: str, conf_dir: Path = CONF_DIR) -> dict[str, Any]:
    """conf/localizer/<name>.yaml merged over the configs its defaults list names (parents
    first, `_self_` last), without interpolation: what Hydra composes."""
    path = conf_dir / f"{name}.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such localizer config")
    own = _read(path)
    merged: dict[str, Any] = {}
    for parent in own.pop("defaults", []) or []:
        if parent != "_self_":
            merged = _merge(merged, raw_config(str(parent), conf_dir))
    return _merge(merged, own)


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """`over` merged into `base`, mappings key by key (as OmegaConf merges)."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _info(name: str, cfg: Mapping[str, Any], path: Path) -> LocalizerInfo:
    meta = cfg.get("meta")
    if not isinstance(meta, Mapping):
        raise ValueError(f"{path}: section 'meta' missing (expected {', '.join(META_FIELDS)})")
    unknown = sorted(set(meta) - set(META_FIELDS))
    if unknown:
        raise ValueError(
            f"{path}: section 'meta': unknown key {unknown[0]!r}; known: {', '.join(META_FIELDS)}"
        )

    def need(key: str, expected: str) -> Any:
        if key not in meta:
            raise ValueError(f"{path}: section 'meta': key '{key}' missing (expected {expected})")
        return meta[key]

    kind = str(need("kind", "the localizer's kind"))
    group = str(need("group", f"one of {list(GROUPS)}"))
    if group not in GROUPS:
        raise ValueError(
            f"{path}: section 'meta': key 'group': expected one of {list(GROUPS)}, got {group!r}"
        )
    stages = need("stages", f"a list of stages from {list(STAGES)}, or []")
    if not isinstance(stages, list) or any(s not in STAGES for s in stages):
        raise ValueError(
            f"{path}: section 'meta': key 'stages': expected a list of {list(STAGES)}, "
            f"got {stages!r}"
        )
    if meta.get("name") != name:
        raise ValueError(
            f"{path}: section 'meta': key 'name': expected {name!r}, got {meta.get('name')!r}"
        )
    return LocalizerInfo(
        name=name,
        kind=kind,
        group=group,
        note=str(need("note", "one line for the report")),
        stages=tuple(stages),
        global_table=bool(meta.get("global_table", False)),
        **_match(path),
    )


def _match(path: Path) -> dict[str, Any]:
    """`matched_to` and `differs_in` of the file's own `meta` (not its parents'): a variant of
    a matched variant changes more than its parent claimed."""
    own = _read(path).get("meta") or {}
    given = [key for key in MATCH_FIELDS if key in own]
    if not given:
        return {}
    differs_in = own.get("differs_in")
    if len(given) == 1 or not isinstance(own["matched_to"], str):
        raise ValueError(
            f"{path}: section 'meta': keys 'matched_to' (a localizer's name) and 'differs_in' "
            f"(a list of sections or section.key) go together; got {given}"
        )
    if not isinstance(differs_in, list) or not differs_in:
        raise ValueError(
            f"{path}: section 'meta': key 'differs_in': expected a non-empty list of sections or "
            f"section.key, got {differs_in!r}"
        )
    return {"matched_to": own["matched_to"], "differs_in": tuple(map(str, differs_in))}


def load_catalog(conf_dir: Path = CONF_DIR) -> dict[str, LocalizerInfo]:
    """Every localizer config of `conf_dir`, by name, in file-name order."""
    paths = sorted(Path(conf_dir).glob("*.yaml"))
    return {p.stem: _info(p.stem, raw_config(p.stem, conf_dir), p) for p in paths}


def stage_localizers(stage: str, conf_dir: Path = CONF_DIR) -> list[str]:
    """The names of the localizers `stage` runs, in file-name order."""
    if stage not in STAGES:
        raise ValueError(f"stage {stage!r}: expected one of {list(STAGES)}")
    return [n for n, info in load_catalog(conf_dir).items() if stage in info.stages]


def package_key(name: str) -> str:
    """The key under `localizers` at which a listed localizer is composed: its name, with
    `_global_` written `-global-`, since Hydra reads `_global_` in a package path as its root
    package (`localizers.amcl_global_matched` would land at `atched`)."""
    return name.replace("_global_", "-global-")


def localizer_overrides(stage: str, conf_dir: Path | None = None) -> list[str]:
    """Hydra overrides that compose the localizers `stage` runs into its config, each under
    `localizers.<package_key(name)>` as a defaults entry `localizer@localizers.<key>` would.
    `conf_dir` defaults to the stages' config tree: $SCANLOC_CONF/localizer, else
    conf/localizer."""
    if conf_dir is None:
        conf_dir = Path(os.environ.get("SCANLOC_CONF", "conf")) / "localizer"
    names = stage_localizers(stage, conf_dir)
    return [f"+localizer@localizers.{package_key(n)}={n}" for n in names]
