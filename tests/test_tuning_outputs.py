"""What a study chose is what its localizer's config says: a study's output
(reports/tuning/<study>.json, written by `python -m scanloc.stages.tune study=<study>`) is
committed beside the config it decided (not as DVC metrics: its every trial's figures would
be hundreds of columns of `dvc metrics show`), and this test fails when the two disagree or
when the study scored a run that is not a tune run."""

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


def test_the_hybrids_studies_are_committed() -> None:
    assert {TUNING / "hybrid.json", TUNING / "hybrid_adaptive.json"} <= set(OUTPUTS)


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
