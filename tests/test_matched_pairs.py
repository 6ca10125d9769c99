"""Matched pairs, declared and checked: a variant that names its baseline (`meta.matched_to`)
and what it changes (`meta.differs_in`) differs from it in those settings and in no other,
both configs composed in full as the localize stage composes them, every part's defaults
filled in, compared in both directions (a key only one side has is a difference too)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from scanloc.localize.catalog import LocalizerInfo, load_catalog
from scanloc.localize.show import resolved

CONF = Path(__file__).resolve().parents[1] / "conf"
CATALOG = load_catalog(CONF / "localizer")
MATCHED = sorted(name for name, info in CATALOG.items() if info.matched_to)


def composed(name: str) -> dict[str, Any]:
    """conf/localizer/<name>.yaml composed as the localize stage composes it (map 1), every
    part's defaults filled in."""
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(
            config_name="localize", overrides=["map_name=sparse_obstacles", f"localizer={name}"]
        )
    return resolved(OmegaConf.to_container(cfg.localizer, resolve=True))  # type: ignore[arg-type]


def flat(sections: Mapping[str, Any]) -> dict[str, Any]:
    """`section.key` -> value of every section but `meta` (what a localizer says of itself)."""
    return {
        f"{section}.{key}": value
        for section, values in sections.items()
        if section != "meta"
        for key, value in values.items()
    }


def differences(ours: Mapping[str, Any], theirs: Mapping[str, Any]) -> set[str]:
    """The `section.key`s whose values differ, or that only one side has."""
    missing = object()
    keys = set(ours) | set(theirs)
    return {k for k in keys if ours.get(k, missing) != theirs.get(k, missing)}


def undeclared(differing: Iterable[str], declared: Iterable[str]) -> set[str]:
    """The differing keys no `differs_in` entry (a section, or one section.key) covers."""
    declared = set(declared)
    return {k for k in differing if k not in declared and k.split(".")[0] not in declared}


def test_the_matched_variants_are_declared() -> None:
    assert {
        "amcl_global_matched",
        "amcl_recovery_matched",
        "hybrid_real",
        "hybrid_verified",
        "hybrid_start_only",
        "hybrid_no_proposal",
    } <= set(MATCHED)
    # amcl_global_matched's true match: the hybrid with recovery and mixing off
    assert CATALOG["amcl_global_matched"].matched_to == "hybrid_start_only"


@pytest.mark.parametrize("name", MATCHED)
def test_a_matched_pair_differs_only_in_what_it_declares(name: str) -> None:
    info: LocalizerInfo = CATALOG[name]
    assert info.matched_to in CATALOG, f"{name}: matched_to {info.matched_to!r} is no localizer"
    ours, theirs = flat(composed(name)), flat(composed(str(info.matched_to)))
    differing = differences(ours, theirs)
    extra = undeclared(differing, info.differs_in)
    assert not extra, f"{name} differs from {info.matched_to} in {sorted(extra)}, undeclared"
    for entry in info.differs_in:  # no stale claim: each declared part does differ
        assert any(k == entry or k.split(".")[0] == entry for k in differing), (name, entry)


def test_the_check_fails_on_an_undeclared_difference() -> None:
    """The comparison sees a changed value, a key one side lacks, and a whole section."""
    ours = {"filter.mode": "global", "mixing.type": "constant", "mixing.share": 0.05}
    theirs = {"filter.mode": "tracking", "mixing.type": "none"}
    differing = differences(ours, theirs)
    assert differing == {"filter.mode", "mixing.type", "mixing.share"}
    assert undeclared(differing, ["mixing"]) == {"filter.mode"}
    assert undeclared(differing, ["mixing", "filter.mode"]) == set()
    assert undeclared(differing, ["mixing.type"]) == {"filter.mode", "mixing.share"}


def test_hybrid_real_keeps_its_recovery_the_gates_and_amcl_real_none() -> None:
    """What hybrid_real's comment says of its filter: the gate is its recovery (w_slow held at
    the first update's mean weight), amcl_real has none."""
    ours, theirs = flat(composed("hybrid_real")), flat(composed("amcl_real"))
    assert theirs["filter.recovery_alpha_slow"] == theirs["filter.recovery_alpha_fast"] == 0
    assert ours["filter.recovery_alpha_slow"] == 0
    assert ours["mixing.type"] == "verified_gate" and ours["proposal.type"] == "learned"
