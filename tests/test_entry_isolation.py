"""Adding or editing one map, log or bag of params.yaml reruns only its own stages, evaluate and
report: asked of DVC itself, which resolves dvc.yaml against params.yaml (and the sites.yaml
that scanloc.sites writes from it) with one more entry of each table and says which stages'
commands or params depend on it."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO_ROOT = Path(__file__).resolve().parents[1]
NEW_ENTRIES = {
    "maps": {
        "office": {
            "config": "ros_file",
            "overrides": "map.path=/data/office/map.yaml",
            "depends": "/data/office",
        }
    },
    "real_logs": {"aces": {"log": "/data/aces.log.gz", "overrides": ""}},
    "bags": {
        "robot": {
            "bag": "/data/robot.bag",
            "map": "/data/office/map.yaml",
            "map_depends": "/data/office",
            "sensor": "auto",
            "overrides": "",
        }
    },
}
SHARED = {"evaluate", "report"}  # read every table: they list every run


def stage_table(folder: Path) -> dict[str, tuple[str, list[str]]]:
    """{stage: (command, params.yaml keys it depends on)} as DVC resolves the folder."""
    script = (
        "import json\n"
        "from dvc.repo import Repo\n"
        "from dvc.dependency.param import ParamsDependency\n"
        "out = {}\n"
        "for st in Repo('.').index.stages:\n"
        "    keys = [k for d in st.deps if isinstance(d, ParamsDependency)\n"
        "            and d.def_path.endswith('params.yaml') for k in d.params]\n"
        "    out[st.addressing] = [st.cmd, keys]\n"
        "print(json.dumps(out))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=folder, capture_output=True, text=True, check=True
    )
    return {k: (v[0], v[1]) for k, v in json.loads(done.stdout.splitlines()[-1]).items()}


def write_sites(folder: Path) -> None:
    """sites.yaml from the folder's params.yaml, as `make repro` writes it."""
    subprocess.run(
        [sys.executable, "-m", "scanloc.sites"], cwd=folder, capture_output=True, check=True
    )


@pytest.fixture(scope="module")
def pipeline_copy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("pipeline")
    for name in ("dvc.yaml", "params.yaml", "sites.yaml"):
        shutil.copy(REPO_ROOT / name, folder / name)
    shutil.copytree(REPO_ROOT / "conf", folder / "conf")
    dvc = Path(sys.executable).parent / "dvc"
    subprocess.run([str(dvc), "init", "--no-scm", "-q"], cwd=folder, check=True)
    return folder


@pytest.mark.parametrize("table", sorted(NEW_ENTRIES))
def test_a_new_entry_touches_only_its_own_stages_evaluate_and_report(
    pipeline_copy: Path, table: str
) -> None:
    before = stage_table(pipeline_copy)
    params_path = pipeline_copy / "params.yaml"
    original = params_path.read_text()
    params = yaml.safe_load(original)
    params[table] = {**(params.get(table) or {}), **NEW_ENTRIES[table]}
    params_path.write_text(yaml.safe_dump(params, sort_keys=False))
    sites_path = pipeline_copy / "sites.yaml"
    sites = sites_path.read_text()
    try:
        write_sites(pipeline_copy)
        after = stage_table(pipeline_copy)
    finally:
        params_path.write_text(original)
        sites_path.write_text(sites)
    (name,) = NEW_ENTRIES[table]
    own = {s for s in after if s not in before}
    assert own and all(re.search(rf"[@-]{name}([-_]|$)", s) for s in own), own
    # An existing stage reruns when its command or its params.yaml keys see the new entry.
    touched = {
        s
        for s, (cmd, keys) in before.items()
        if after[s][0] != cmd or any(k == table or k.startswith(f"{table}.{name}") for k in keys)
    }
    assert touched == SHARED, f"adding {table}.{name} would rerun {sorted(touched - SHARED)}"
    for stage, (_, keys) in after.items():  # no stage of one entry reads the whole table
        if stage not in SHARED:
            assert table not in keys, f"{stage} depends on the whole params.yaml {table!r}"
