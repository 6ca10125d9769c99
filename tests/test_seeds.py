"""The tune and evaluation trajectory sets (conf/seeds.yaml, conf/run/) are disjoint and
wired into the pipeline: a setting chosen on the tune set is never scored on its own runs."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
PROFILES = ("smoke", "laptop", "desk", "paper")


def _runs() -> list[str]:
    return sorted(p.stem for p in (CONF / "run").glob("*.yaml"))


def _composed(run: str, profile: str) -> dict:
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose("trajectory", overrides=[f"run={run}", f"profile={profile}"])
    return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]


def _kidnap_steps(doc: dict) -> set[int]:
    steps = int(doc["trajectory"]["num_steps"])
    return {round(f * steps) for f in doc["run"]["kidnap_at"]}


def test_tune_and_evaluation_seeds_and_kidnap_times_are_disjoint() -> None:
    sets = yaml.safe_load((CONF / "seeds.yaml").read_text())["seeds"]
    evaluation, tune = sets["evaluation"], sets["tune"]
    # a seed s draws the route, s + 1 the scans' noise: neither may be shared
    drawn = {s + d for s in evaluation["trajectory_seeds"] for d in (0, 1)}
    assert drawn.isdisjoint(s + d for s in tune["trajectory_seeds"] for d in (0, 1))
    eval_times = set(evaluation["kidnap_at"]) | set(evaluation["short_kidnap_at"])
    assert eval_times.isdisjoint(tune["kidnap_at"])
    assert len(set(evaluation["trajectory_seeds"])) == len(evaluation["trajectory_seeds"]) >= 5


@pytest.mark.parametrize("profile", PROFILES)
def test_every_run_composes_to_its_sets_seed_and_the_sets_never_meet(profile: str) -> None:
    sets = yaml.safe_load((CONF / "seeds.yaml").read_text())["seeds"]
    tune_seeds, eval_seeds = (
        sets["tune"]["trajectory_seeds"],
        sets["evaluation"]["trajectory_seeds"],
    )
    composed = {run: _composed(run, profile) for run in _runs()}
    tune = {r: d for r, d in composed.items() if r.startswith("tune")}
    evaluation = {r: d for r, d in composed.items() if not r.startswith("tune")}
    assert tune and len([r for r in evaluation if r.startswith("kidnap")]) >= 5
    for run, doc in tune.items():
        assert doc["trajectory"]["seed"] in tune_seeds, run
    for run, doc in evaluation.items():
        assert doc["trajectory"]["seed"] in eval_seeds, run
        assert doc["run"]["kind"] == "drive" or len(doc["run"]["kidnap_at"]) >= 3, run
    kidnap_seeds = [d["trajectory"]["seed"] for r, d in evaluation.items() if r != "drive"]
    assert sorted(kidnap_seeds) == sorted(eval_seeds)  # one evaluation kidnap run per seed
    tune_steps = set().union(*(_kidnap_steps(d) for d in tune.values()))
    eval_steps = set().union(*(_kidnap_steps(d) for d in evaluation.values()))
    if profile != "smoke":  # smoke runs are too short for distinct kidnap steps
        assert tune_steps.isdisjoint(eval_steps)
    names = {d["name"] for d in composed.values()}
    assert len(names) == len(composed)  # each run its own trajectory folder


def test_laptop_stretches_leave_room_to_converge_and_confirm() -> None:
    for run in _runs():
        doc = _composed(run, "laptop")
        steps = int(doc["trajectory"]["num_steps"])
        bounds = [0, *sorted(_kidnap_steps(doc)), steps]
        assert min(b - a for a, b in itertools.pairwise(bounds)) >= 40, run


def test_the_pipeline_runs_the_evaluation_set_and_scores_only_it() -> None:
    """conf/seeds.yaml `runs` is the one list (dvc.yaml reads it through `vars`): a map makes a
    run per conf/run file, localizes and scores the evaluation runs, never a tune run."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    assert stages["trajectory"]["foreach"] == "${trajectories}"  # scanloc.sites: runs.<kind>.made
    runs = yaml.safe_load((CONF / "seeds.yaml").read_text())["runs"]
    assert set(runs["map"]["made"]) == set(_runs())
    for kind in runs.values():
        scored = kind["scored_over_seeds"] + kind["localized"] + kind["over_filter_seeds"]
        assert set(scored) <= set(kind["made"]), kind
        assert not any(r.startswith("tune") for r in scored)
        # every made run is on one side of the split, never both (its meta.json says which)
        assert set(kind["made"]) == set(kind["localized"]) | set(kind["tune"]), kind
        assert not set(kind["localized"]) & set(kind["tune"]), kind
    assert len(runs["map"]["scored_over_seeds"]) >= 5
