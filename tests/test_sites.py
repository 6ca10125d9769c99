"""sites.yaml is what params.yaml and conf/seeds.yaml give (scanloc.sites), so dvc.yaml runs
the one chain on every site; a site it does not list is refused under DVC."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from scanloc.sites import (
    SITES,
    check_listed,
    expected_text,
    load_runs,
    pipeline_vars,
    run_part,
    site_kinds,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
RUNS = {
    "runs": {
        "map": {
            "made": ["drive", "kidnap", "tune"],
            "localized": ["drive", "kidnap"],
            "over_filter_seeds": [],
        },
        "tune_map": {"made": ["tune"], "localized": [], "over_filter_seeds": []},
        "log": {"localized": ["real"], "over_filter_seeds": ["real"]},
        "bag": {"localized": ["real"], "over_filter_seeds": []},
    },
    "odometry": ["wheel", "laser"],
    "paper_cnn_runs": {"map": "m1", "runs": ["drive"]},
}
PARAMS = {
    "bags": {"robot": {}},
    "maps": {"m1": {}, "m2": {}},
    "real_logs": {"aces": {}},
    "tune_maps": {"t1": {"config": "generated_rooms"}},
}


def test_the_committed_sites_yaml_is_what_params_yaml_gives() -> None:
    assert (REPO_ROOT / SITES).read_text() == expected_text(REPO_ROOT), (
        "sites.yaml is stale: run `python -m scanloc.sites` (or `make repro`)"
    )


def test_sites_come_in_params_order_maps_logs_bags_whatever_the_file_order() -> None:
    assert site_kinds(PARAMS) == {
        "m1": "map", "m2": "map", "t1": "tune_map", "aces": "log", "robot": "bag"
    }  # fmt: skip
    variables = pipeline_vars(PARAMS, RUNS, {"map1_small": "m1"})
    assert variables["site_list"] == "{m1:map,m2:map,aces:log,robot:bag}"  # no tune map
    assert list(variables["scan_sets"]) == [
        "map1_small",
        "m1_val",
        "m2_val",
        "t1_val",
        "aces_val",
        "robot_val",
    ]
    assert variables["sites"]["aces"] == {"kind": "log", "site_scans": "data/scans/aces_mapping"}
    assert variables["sites"]["robot"]["site_scans"] == "data/scans/robot_val"


def test_a_tune_map_is_made_and_trained_like_a_map_and_never_localized() -> None:
    variables = pipeline_vars(PARAMS, RUNS, {})
    assert variables["map_sites"] == {"m1": {}, "m2": {}, "t1": {"config": "generated_rooms"}}
    assert variables["trajectories"] == {
        "m1-drive": {"map": "m1", "run": "drive"}, "m1-kidnap": {"map": "m1", "run": "kidnap"},
        "m1-tune": {"map": "m1", "run": "tune"}, "m2-drive": {"map": "m2", "run": "drive"},
        "m2-kidnap": {"map": "m2", "run": "kidnap"}, "m2-tune": {"map": "m2", "run": "tune"},
        "t1-tune": {"map": "t1", "run": "tune"},
    }  # fmt: skip
    assert variables["sites"]["t1"] == {"kind": "map", "site_scans": "data/scans/t1_val"}
    assert variables["scan_sets"]["t1_val"]["kind"] == "map"
    assert not any(job["site"] == "t1" for job in variables["jobs"].values())


def test_jobs_are_each_sites_localized_runs_the_paper_cnns_and_the_filter_seed_runs() -> None:
    jobs = pipeline_vars(PARAMS, RUNS, {})["jobs"]
    assert list(jobs) == [
        "m1-drive", "m1-kidnap", "m2-drive", "m2-kidnap", "aces-real", "robot-real",
        "cnn-drive", "seeds-aces-real-wheel", "seeds-aces-real-laser",
    ]  # fmt: skip
    assert jobs["aces-real"] == {
        "stage": "localize", "site": "aces", "kind": "log", "run": "aces_real",
        "odometry": "wheel", "model": "models/scanlocnet/aces", "aux": "data/scans/aces_val",
        "out": "reports/localize/aces_real",
    }  # fmt: skip
    assert jobs["cnn-drive"]["out"] == "reports/localize_cnn/m1_drive"
    assert jobs["cnn-drive"]["model"] == "models/cnn1d_200k"
    seeds = jobs["seeds-aces-real-laser"]
    assert (seeds["stage"], seeds["odometry"]) == ("localize_seeds", "laser")
    assert seeds["out"] == "reports/localize_seeds/aces_real_laser"


def test_a_name_used_by_two_sites_and_a_pipeline_without_maps_are_refused() -> None:
    with pytest.raises(ValueError, match=r"'bags\.m1': the name is already a map site"):
        site_kinds({"maps": {"m1": {}}, "bags": {"m1": {}}})
    with pytest.raises(ValueError, match="field 'maps': expected at least one map"):
        site_kinds({"real_logs": {"aces": {}}})
    with pytest.raises(ValueError, match="field 'real_logs': expected a mapping"):
        site_kinds({"maps": {"m1": {}}, "real_logs": ["aces"]})


def test_a_site_sites_yaml_does_not_list_is_refused_under_dvc_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    shutil.copy(REPO_ROOT / SITES, tmp_path / SITES)
    monkeypatch.delenv("DVC_STAGE", raising=False)
    check_listed("office", tmp_path)  # by hand: any site
    monkeypatch.setenv("DVC_STAGE", "maps@office")
    check_listed("sparse_obstacles", tmp_path)
    with pytest.raises(ValueError, match=r"expected the site 'office'.*python -m scanloc\.sites"):
        check_listed("office", tmp_path)


@pytest.mark.parametrize("stage", ["evaluate", "report"])
def test_evaluate_and_report_without_sites_say_where_they_come_from(
    stage: str, tmp_path: Path
) -> None:
    """`sites` defaults to null (not `???`, which `dvc exp run -S conf/<stage>.yaml:...` refuses
    to compose): a run by hand without them is a clear error, not an empty table."""
    done = subprocess.run(
        [sys.executable, "-m", f"scanloc.stages.{stage}", f"hydra.run.dir={tmp_path}"],
        cwd=Path(__file__).resolve().parents[1],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode != 0
    assert f"conf/{stage}.yaml: field 'sites': expected {{name: kind}}" in done.stderr
    assert "Traceback" not in done.stderr


def test_every_made_run_has_its_part_of_the_split() -> None:
    """A run's meta.json says `tune` or `evaluation` (the tune command reads it); a run on
    neither list is an error naming conf/seeds.yaml, not a silent default."""
    runs = load_runs(REPO_ROOT)
    for kind, spec in runs.items():
        parts = {run: run_part(runs, kind, run) for run in spec["made"]}
        assert {r for r, p in parts.items() if p == "tune"} == set(spec["tune"]), kind
    assert run_part(runs, "map", "tune_kidnap") == "tune"
    assert run_part(runs, "log", "kidnap") == "evaluation"
    with pytest.raises(ValueError, match=r"conf/seeds.yaml: field 'runs.map': run 'mine'"):
        run_part(runs, "map", "mine")
