"""What a study chose is what its localizer's config says: a study's record
(reports/tuning/<study>.json, the tune@<study> stage's plot, committed with dvc.lock) sits
beside the config it decided, and this test fails when the two disagree, when the study scored
a run that is not a tune run, or when a study of params.yaml `tune_studies` has no record."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from scanloc.localize.catalog import raw_config
from scanloc.localize.show import resolved
from scanloc.stages.tune import with_keys

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
    assert {"hybrid", "hybrid_adaptive", "amcl_best"} <= set(studies)
    assert {TUNING / f"{study}.json" for study in studies} <= set(OUTPUTS)


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
