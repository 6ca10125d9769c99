"""What a study chose is what its localizer's config says: a study's record
(reports/tuning/<study>.json, the tune@<study> stage's plot, committed with dvc.lock) sits
beside the config it decided, and this test fails when the two disagree, when the study scored
a run that is not a tune run, or when a study of params.yaml `tune_studies` has no record."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir

from scanloc.localize.catalog import raw_config
from scanloc.localize.show import resolved
from scanloc.stages._app import to_dict
from scanloc.stages.tune import expand_runs, tune_maps, with_keys

REPO = Path(__file__).resolve().parents[1]
TUNING = REPO / "reports" / "tuning"
OUTPUTS = sorted(TUNING.glob("*.json"))
TUNE_RUNS = {
    run
    for kind in yaml.safe_load((REPO / "conf" / "seeds.yaml").read_text())["runs"].values()
    for run in kind["tune"]
}


def test_every_tune_stage_has_its_record() -> None:
    studies = yaml.safe_load((REPO / "params.yaml").read_text())["tune_studies"]
    assert {"hybrid", "amcl_best"} <= set(studies)
    assert {TUNING / f"{study}.json" for study in studies} <= set(OUTPUTS)


@pytest.mark.parametrize(
    "study", yaml.safe_load((REPO / "params.yaml").read_text())["tune_studies"]
)
def test_a_tune_stages_record_is_its_study_as_written(study: str) -> None:
    """The record of tune@<study> ran the study as conf/study/<study>.yaml and params.yaml's
    tune maps give it now, at the profile of params.yaml: its runs, its seeds, every trial
    numbered. (A record kept from an earlier study, on other runs, fails here; dvc.lock's
    hashes say whether the sources changed since, tests/test_dvc_lock.py.)"""
    profile = yaml.safe_load((REPO / "params.yaml").read_text())["profile"]
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base=None):
        cfg = compose("tune", overrides=[f"study={study}", f"profile={profile}"])  # as tune@
    spec = to_dict(cfg.study)
    record = json.loads((TUNING / f"{study}.json").read_text())
    assert (record["study"], record["localizer"]) == (study, spec["localizer"])
    entries = expand_runs(spec["runs"], tune_maps(REPO / "params.yaml"), study)
    expected_runs = [
        f"{Path(entry['run_dir']).name}/{entry.get('odometry', 'wheel')}" for entry in entries
    ]
    assert record["runs"] == expected_runs, study
    assert record["seeds"] == list(spec.get("seeds", cfg.seeds))[: cfg.max_seeds], study
    assert [t["trial"] for t in record["trials"]] == list(range(len(record["trials"])))


@pytest.mark.parametrize("path", OUTPUTS, ids=lambda p: p.stem)
def test_the_localizer_holds_its_studys_choice(path: Path) -> None:
    result = json.loads(path.read_text())
    config = raw_config(result["localizer"], REPO / "conf" / "localizer")
    assert resolved(with_keys(config, result["chosen"])) == resolved(config), (
        f"conf/localizer/{result['localizer']}.yaml does not hold what {path.name} chose: "
        f"{result['chosen']}"
    )
    for run in result["runs"]:  # <site>_<run>/<odometry>
        folder = run.split("/")[0]
        assert any(folder.endswith(f"_{tune}") for tune in TUNE_RUNS), (path.name, run)
