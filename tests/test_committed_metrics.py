"""The metrics files are committed with the dvc.lock they came from, and the README's results
table is what they give (scanloc.report.readme_results), so no figure there can go stale."""

from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path

import pytest
import yaml

from scanloc.report.readme_results import (
    BEGIN,
    END,
    committed_table,
    readme_table,
    results_rows,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
METRICS_PREFIXES = ("reports/metrics/", "reports/summary.json")


def _locked_metrics() -> dict[str, str]:
    """{path: md5} of every metrics file dvc.lock records."""
    lock = yaml.safe_load((REPO_ROOT / "dvc.lock").read_text())
    found = {}
    for stage in lock["stages"].values():
        for out in stage.get("outs", []):
            if out["path"].startswith(METRICS_PREFIXES) and "md5" in out:
                found[out["path"]] = out["md5"]
    return found


def test_every_locked_metrics_file_is_committed_with_the_locks_hash() -> None:
    locked = _locked_metrics()
    assert "reports/summary.json" in locked
    tracked = set(
        subprocess.run(
            ["git", "ls-files", "reports"], cwd=REPO_ROOT, capture_output=True, text=True
        ).stdout.split()
    )
    for path, md5 in sorted(locked.items()):
        assert path in tracked, f"{path}: in dvc.lock but not committed"
        digest = hashlib.md5((REPO_ROOT / path).read_bytes()).hexdigest()
        assert digest == md5, f"{path}: its bytes are not the ones dvc.lock records"


def test_the_readmes_results_table_is_the_committed_metrics() -> None:
    readme = (REPO_ROOT / "README.md").read_text()
    assert readme_table(readme) == committed_table(REPO_ROOT), (
        "README.md's results table differs from reports/summary.json: run `make readme`"
    )


def test_results_rows_follow_the_summary_keys() -> None:
    summary = {
        "t1_cnn2d": 3.0,
        "t1_mlp": 2.5,
        "claims_reproduced": 2,
        "claims_inconclusive": 0,
        "pos_amcl": 0.04,
        "lost_hybrid": 0.25,
        "real_top5_office": 0.5,
        "top5_office": 0.75,
        "real_rmse_office": None,
        "wall_s": 120.0,
    }
    rows = results_rows(summary)
    keys = [key for _, _, key in rows]
    assert keys[:3] == ["t1_mlp", "t1_cnn2d", "claims_*"]  # Table 1 in the paper's row order
    values = {key: value for _, value, key in rows}
    assert values["claims_*"] == "2 reproduced"  # verdicts no claim got are left out
    assert values["lost_hybrid"] == "25.0 %"
    assert values["real_top5_office"] == "50.0 %" and values["top5_office"] == "75.0 %"
    assert values["real_rmse_office"] == "–"
    assert values["wall_s"] == "2.0 min"
    assert keys.count("top5_office") == 1  # `real_top5_` is not also read as `top5_`


@pytest.mark.parametrize("text", ["no markers", f"{END}\n{BEGIN}"])
def test_a_readme_without_its_markers_has_no_table(text: str) -> None:
    assert readme_table(text) == ""
