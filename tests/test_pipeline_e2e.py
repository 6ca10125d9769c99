"""End to end: the whole `dvc repro` on the smoke profile in a temporary copy of the repository."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from scanloc.report.build import SECTIONS

REPO_ROOT = Path(__file__).resolve().parents[1]

TABLE2_KEYS = {
    "x_err_mean",
    "x_err_std",
    "y_err_mean",
    "y_err_std",
    "theta_sin_err_mean",
    "theta_sin_err_std",
    "pos_err_mean_m",
    "pos_err_median_m",
    "heading_err_mean_deg",
}
TABLE1_ROWS = ("mlp", "cnn1d_20k", "cnn1d_200k", "cnn2d")


def project_files() -> list[str]:
    """Tracked and untracked-but-not-ignored files: what a clean clone (plus local edits) holds."""
    out = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard"],
        cwd=REPO_ROOT,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return [f for f in out.splitlines() if (REPO_ROOT / f).is_file()]


def copy_project(dest: Path, profile: str) -> Path:
    """A fresh copy of the project (no data, models or DVC cache) set to `profile`."""
    for rel in project_files():
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO_ROOT / rel, target)
    (dest / "dvc.lock").unlink(missing_ok=True)
    params = yaml.safe_load((dest / "params.yaml").read_text())
    params["profile"] = profile
    (dest / "params.yaml").write_text(yaml.safe_dump(params))
    subprocess.run(["git", "init", "-q"], cwd=dest, check=True)
    return dest


def dvc(cwd: Path, *args: str, timeout: int = 1500) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.pop("SCANLOC_CONF", None)
    result = subprocess.run(
        [str(Path(sys.executable).parent / "dvc"), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert result.returncode == 0, f"dvc {' '.join(args)} failed:\n{result.stdout}\n{result.stderr}"
    return result


def lock_outs(repo: Path, prefixes: tuple[str, ...]) -> dict[str, str]:
    """Data output path -> md5 of the stages whose names start with one of `prefixes`.

    Wall-time metrics (reports/timing/) are outputs too but measure the machine, not the data.
    """
    lock = yaml.safe_load((repo / "dvc.lock").read_text())
    return {
        out["path"]: out["md5"]
        for name, stage in lock["stages"].items()
        if name.startswith(prefixes)
        for out in stage.get("outs", [])
        if out["path"].startswith("data/")
    }


@pytest.fixture(scope="module")
def smoke_repo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    repo = copy_project(tmp_path_factory.mktemp("smoke") / "repo", "smoke")
    dvc(repo, "repro")
    return repo


def test_smoke_repro_is_up_to_date(smoke_repo: Path) -> None:
    status = json.loads(dvc(smoke_repo, "status", "--json").stdout)
    assert status == {}, status


def test_smoke_repro_writes_the_contract_artifacts(smoke_repo: Path) -> None:
    grid_meta = yaml.safe_load((smoke_repo / "data/maps/sparse_obstacles/map.yaml").read_text())
    assert grid_meta["resolution"] == pytest.approx(0.02)
    assert (smoke_repo / "data/maps/simple_rooms/map.yaml").is_file()
    for name in ("map1_small", "map1_large", "map2_small"):
        meta = json.loads((smoke_repo / f"data/scans/{name}/meta.json").read_text())
        assert meta["count"] > 0
    assert (smoke_repo / "data/trajectories/map1_drive/meta.json").is_file()
    html = (smoke_repo / "reports/report.html").read_text()
    assert html.count('src="data:image/png;base64,') >= 6
    assert "http://" not in html and "https://" not in html
    markdown = (smoke_repo / "reports/report.md").read_text()
    for section_id, title in SECTIONS:
        assert f'id="{section_id}"' in html, section_id
        assert title in markdown, title


def test_smoke_metrics_hold_table1_and_table2(smoke_repo: Path) -> None:
    shown = json.loads(dvc(smoke_repo, "metrics", "show", "--json").stdout)
    metrics: dict[str, dict] = {}
    for workspace in shown.values():
        for path, content in workspace["data"].items():
            metrics[path] = content["data"]
    for row in TABLE1_ROWS:
        train = metrics[f"reports/metrics/train_{row}.json"]
        assert {"val_mae", "epoch_s"} <= set(train)
    localization = metrics["reports/metrics/localization.json"]
    for method in ("amcl", "cnn_single", "cnn_ensemble"):
        assert TABLE2_KEYS <= set(localization[method]), method


def test_scans_are_byte_reproducible_from_scratch(smoke_repo: Path, tmp_path: Path) -> None:
    again = copy_project(tmp_path / "repo", "smoke")
    dvc(again, "repro", "scans")
    prefixes = ("maps@", "scans@")
    first, second = lock_outs(smoke_repo, prefixes), lock_outs(again, prefixes)
    assert first and first == second
