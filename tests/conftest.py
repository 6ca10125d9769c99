"""Shared fixtures: where the paper's STDR maps live, and small worlds built in memory."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data" / "stdr_maps"


@pytest.fixture(scope="session")
def stdr_maps_dir() -> Path:
    """The STDR originals (GPL-3, never copied into the repo); skip when ../shared is absent."""
    if not (SHARED_DATA / "sparse_obstacles.yaml").is_file():
        pytest.skip(f"STDR maps not available at {SHARED_DATA}")
    return SHARED_DATA
