"""scanloc.lock_diff: which dvc.lock outputs a repro on another CPU class may change (the trained
models and what is computed from them) and which must reproduce byte for byte (the data)."""

from __future__ import annotations

import copy
import subprocess
from pathlib import Path

import pytest
import yaml

from scanloc.lock_diff import (
    changed_outputs,
    classify,
    declared_stages,
    main,
    precision_dependent,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
DVC_YAML = yaml.safe_load((REPO_ROOT / "dvc.yaml").read_text())
LOCK = yaml.safe_load((REPO_ROOT / "dvc.lock").read_text())


def with_hash(lock: dict, stage: str, path: str, md5: str = "0" * 32) -> dict:
    """A copy of `lock` in which `stage`'s output `path` has another hash."""
    changed = copy.deepcopy(lock)
    (out,) = [o for o in changed["stages"][stage]["outs"] if o["path"] == path]
    out["md5"] = md5
    return changed


def test_the_trainings_are_declared_and_what_reads_their_models_follows() -> None:
    assert declared_stages(DVC_YAML) == {"train", "transfer", "train_scanlocnet", "real_ablation"}
    found = precision_dependent(LOCK, declared_stages(DVC_YAML))
    # read a model: the localizers, the evaluation, the report
    for stage in ("localize@sparse_obstacles-drive", "localize@cnn-drive", "evaluate", "report"):
        assert stage in found, stage
    # the data: maps, scans, trajectories, real runs
    data = [s for s in LOCK["stages"] if s.split("@")[0] in ("maps", "scans", "trajectory", "real")]
    assert data and not found & set(data)


def test_a_changed_model_is_allowed_and_a_changed_map_is_a_defect() -> None:
    model = with_hash(LOCK, "train@mlp", "models/mlp")
    assert classify(DVC_YAML, LOCK, model) == ([("train@mlp", "models/mlp")], [])
    data = with_hash(LOCK, "maps@sparse_obstacles", "data/maps/sparse_obstacles")
    assert classify(DVC_YAML, LOCK, data) == (
        [],
        [("maps@sparse_obstacles", "data/maps/sparse_obstacles")],
    )
    assert classify(DVC_YAML, LOCK, LOCK) == ([], [])


def test_the_command_compares_with_the_commit_and_fails_on_changed_data(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "dvc.yaml").write_text(yaml.safe_dump(DVC_YAML))
    (tmp_path / "dvc.lock").write_text(yaml.safe_dump(LOCK))
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "."], check=True)
    subprocess.run([*git, "commit", "-qm", "lock"], check=True)
    assert main(["--repo", str(tmp_path)]) == 0
    changed = with_hash(
        LOCK, "trajectory@sparse_obstacles-drive", "data/trajectories/sparse_obstacles_drive"
    )
    (tmp_path / "dvc.lock").write_text(yaml.safe_dump(changed))
    assert main(["--repo", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "1 outputs changed that must reproduce byte for byte" in out
    assert "trajectory@sparse_obstacles-drive: data/trajectories/sparse_obstacles_drive" in out


def test_outputs_are_matched_by_path_so_a_renamed_stage_is_still_compared() -> None:
    old = {"stages": {"real_train@intel": {"outs": [{"path": "models/x", "md5": "a"}]}}}
    same = {"stages": {"train_scanlocnet@intel": {"outs": [{"path": "models/x", "md5": "a"}]}}}
    other = {"stages": {"train_scanlocnet@intel": {"outs": [{"path": "models/x", "md5": "b"}]}}}
    gone: dict = {"stages": {}}
    assert changed_outputs(old, same) == []
    assert changed_outputs(old, other) == [("train_scanlocnet@intel", "models/x")]
    assert changed_outputs(old, gone) == [("real_train@intel", "models/x")]
