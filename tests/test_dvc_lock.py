"""dvc.lock is true: DVC's hash of every source and config dependency equals the committed one,
also after Python and numba have written their caches next to the sources."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SOURCE_PREFIXES = ("src/", "conf/", "params.yaml")


def _git(*args: str) -> str:
    return subprocess.run(
        ["git", *args], cwd=REPO_ROOT, check=True, capture_output=True, text=True
    ).stdout


def _local_changes() -> list[str]:
    """Tracked files that differ from HEAD: then dvc.lock cannot be expected to match yet."""
    return [line for line in _git("status", "--porcelain", "--untracked-files=no").splitlines()]


def _dvc_status() -> dict:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    out = subprocess.run(
        [str(Path(sys.executable).parent / "dvc"), "status", "--json"],
        cwd=REPO_ROOT,
        env=env,
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    return json.loads(out.stdout or "{}")


def changed_source_dependencies(status: dict) -> list[str]:
    """`stage: path (change)` for each source/config dependency or param `dvc status` reports,
    and `stage: changed command` where the stage's command is not the locked one."""
    found = []
    for stage, changes in status.items():
        for change in changes if isinstance(changes, list) else []:
            if isinstance(change, str):  # "changed command", "always changed"
                if change != "always changed":
                    found.append(f"{stage}: {change}")
                continue
            for path, what in change.get("changed deps", {}).items():
                if path.startswith(SOURCE_PREFIXES):
                    found.append(f"{stage}: {path} ({what})")
            for path, what in change.get("changed params", {}).items():
                found.append(f"{stage}: params {path} ({what})")
    return found


def test_changed_source_dependencies_reads_dvc_status() -> None:
    status = {
        "maps@a": [
            {"changed deps": {"src/scanloc/world": "modified", "data/x": "deleted"}},
            {"changed outs": {"data/maps/a": "not in cache"}},
        ],
        "report": [{"changed params": {"conf/report.yaml": {"claims.claim1.min_margin": 1}}}],
        "real_train@intel": ["changed command"],
        "bench": ["always changed"],
    }
    assert changed_source_dependencies(status) == [
        "maps@a: src/scanloc/world (modified)",
        "report: params conf/report.yaml ({'claims.claim1.min_margin': 1})",
        "real_train@intel: changed command",
    ]


@pytest.mark.e2e  # the committed pipeline's state: checked before a release
def test_dvc_lock_matches_the_sources_with_caches_written_next_to_them() -> None:
    if not (REPO_ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    if changes := _local_changes():
        pytest.skip(f"{len(changes)} changed files: dvc.lock is checked on a clean checkout")
    # What Python and numba leave next to the sources on any machine that ran them.
    caches = [
        REPO_ROOT / "src/scanloc/world/__pycache__/probe._kernel-1.py311.nbi",
        REPO_ROOT / "src/scanloc/world/__pycache__/probe._kernel-1.py311.1.nbc",
        REPO_ROOT / "src/scanloc/sensor/__pycache__/probe.cpython-311.pyc",
    ]
    created = []
    for path in caches:
        path.parent.mkdir(exist_ok=True)
        if not path.exists():
            path.write_bytes(b"machine-specific cache")
            created.append(path)
    try:
        changed = changed_source_dependencies(_dvc_status())
    finally:
        for path in created:
            path.unlink()
    assert changed == [], "dvc.lock is stale: rerun the pipeline and commit dvc.lock\n" + "\n".join(
        changed
    )
