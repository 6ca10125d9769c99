"""scanloc's import contracts hold (pyproject.toml `[tool.importlinter]`): each package imports
only the floors below its own, every package is on a floor, and no package's modules import each
other in a cycle."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def test_lint_imports_keeps_every_contract() -> None:
    result = subprocess.run(
        [str(Path(sys.executable).parent / "lint-imports"), "--no-cache"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, f"lint-imports:\n{result.stdout}\n{result.stderr}"
    summary = re.search(r"Contracts: (\d+) kept, 0 broken", result.stdout)
    assert summary and int(summary.group(1)) >= 2, result.stdout  # the layers and the cycles
