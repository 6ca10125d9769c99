"""The sweep commands of docs/experiments.md, run as written (the smoke profile added) from the
root of a fresh copy of the repository: the default sweep folder resolves, every job runs, each
sweep writes its summary.csv, and the compare command the section ends with reads one of
them."""

from __future__ import annotations

import csv
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from test_pipeline_e2e import REPO_ROOT, copy_project, dvc

pytestmark = pytest.mark.e2e  # copies the repository, runs dvc and the sweeps


def docs_section(title: str) -> str:
    text = (REPO_ROOT / "docs" / "experiments.md").read_text()
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## )", text, re.S | re.M)
    assert match, f"docs/experiments.md has no section '## {title}'"
    return match.group(1)


def sweep_commands() -> list[str]:
    """The `python -m ... -m ...` lines of the Sweeps section's code block."""
    block = re.search(r"```bash\n(.*?)```", docs_section("Sweeps"), re.S)
    assert block, "docs/experiments.md, Sweeps: no bash block"
    return [line for line in block.group(1).splitlines() if line.startswith("python -m")]


def run(command: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env.pop("DVC_STAGE", None)
    env.pop("SCANLOC_CONF", None)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    result = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, f"{shlex.join(command)}:\n{result.stdout}\n{result.stderr}"
    return result


def test_documented_sweeps_run_as_written(tmp_path: Path) -> None:
    commands = sweep_commands()
    sweeps = [c for c in commands if " -m " in c and "stages.compare" not in c]
    compares = [c for c in commands if "stages.compare" in c]
    assert len(sweeps) >= 2 and len(compares) == 1, commands
    repo = copy_project(tmp_path / "repo", "smoke")
    dvc(repo, "repro", "scans@map1_small")  # the datasets the sweeps train on
    folders = []
    for command in sweeps:
        before = set((repo / "multirun" / "train").glob("*"))
        run([*shlex.split(command), "profile=smoke"], repo)
        (folder,) = set((repo / "multirun" / "train").glob("*")) - before
        with open(folder / "summary.csv", newline="") as handle:
            rows = list(csv.DictReader(handle))
        jobs = len(re.search(r"=(\S*,\S*)", command).group(1).split(","))
        assert [row["status"] for row in rows] == ["ok"] * jobs, rows
        assert all(float(row["val_mae"]) > 0 for row in rows), rows
        folders.append(folder)
    # The compare line names its folder as multirun/train/<date>: use the first sweep.
    compare = compares[0].replace("multirun/train/<date>", str(folders[0].relative_to(repo)))
    result = run(shlex.split(compare), repo)
    written = re.search(r"compare: wrote (\S+compare\.html)", result.stdout)
    assert written and (repo / written.group(1)).is_file(), result.stdout
    assert "model.lr" in result.stdout and "t1_cnn1d_20k" in result.stdout, result.stdout
