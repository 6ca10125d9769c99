"""End to end, beside the smoke repro (its own file, so that pytest-xdist runs it on the other
worker): the paper's maps and datasets, made from scratch with and without a user's maps, have
the same bytes: adding a map leaves the paper's entries of dvc.lock as they were. (No real
log: its stages are the smoke repro's.)"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from test_pipeline_e2e import USER_MAPS, copy_project, dvc, lock_outs

pytestmark = pytest.mark.e2e  # two `dvc repro scans` in copies: minutes (make test-all)


def test_scans_are_byte_reproducible_from_scratch(tmp_path: Path) -> None:
    with_maps = copy_project(tmp_path / "with_maps", "smoke", USER_MAPS, logs=())
    without = copy_project(tmp_path / "without", "smoke", logs=())
    for repo in (with_maps, without):
        dvc(repo, "repro", "scans")
    made = yaml.safe_load((with_maps / "dvc.lock").read_text())["stages"]
    assert {f"maps@{name}" for name in USER_MAPS} <= set(made)  # the user's maps were made
    prefixes = ("maps@", "scans@")
    first, second = lock_outs(with_maps, prefixes), lock_outs(without, prefixes)
    assert first and first == second
