"""Tuning on tune runs (scanloc.stages.tune): coordinate descent keeps exactly the options that
lower the score, dotted keys reach nested config fields, fitted alphas are scaled, and the
command runs a study end to end on a small run."""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from scanloc.localize.catalog import raw_config
from scanloc.localize.config_params import check_sections
from scanloc.localize.kinds import KIND_SECTIONS, LocalizeInputs, config_file, kind_of
from scanloc.localize.show import resolved
from scanloc.stages import tune
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import Trajectory, save_trajectory
from scanloc.world.map_server import save_map
from small_world import SPEC, small_map, ug01_scans

REPO = Path(__file__).resolve().parents[1]
PF = {"kind": "particle_filter"}  # a seeded kind: each trial runs once per seed


def test_dotted_keys_and_fitted_alphas() -> None:
    config = {"a": 1, "proposal": {"share": 0.1, "k": 3}}
    changed = tune.with_keys(config, {"proposal.share": 0.5, "b": 2})
    assert changed == {"a": 1, "b": 2, "proposal": {"share": 0.5, "k": 3}}
    assert config["proposal"]["share"] == 0.1  # the original is left alone
    assert tune.with_keys(config, {"x.y": 1})["x"] == {"y": 1}  # missing parents are made
    keys = tune.resolve_option(
        {"motion.odom_model_type": "diff-corrected", "fitted_alpha_scale": 2.0},
        [0.1, 0.2, 0.3, 0.4],
    )
    assert keys == {
        "motion.odom_model_type": "diff-corrected",
        "motion.odom_alpha1": 0.2, "motion.odom_alpha2": 0.4,
        "motion.odom_alpha3": 0.6, "motion.odom_alpha4": 0.8,
    }  # fmt: skip
    # the fitted alphas land in the `motion` section, beside what the config sets there
    amcl = {"meta": {"name": "amcl"}, "motion": {"odom_alpha5": 0.1}}
    assert tune.with_keys(amcl, keys)["motion"] == {
        "odom_alpha5": 0.1, "odom_model_type": "diff-corrected",
        "odom_alpha1": 0.2, "odom_alpha2": 0.4, "odom_alpha3": 0.6, "odom_alpha4": 0.8,
    }  # fmt: skip


def test_coordinate_descent_keeps_only_what_lowers_the_score(monkeypatch) -> None:
    seeds: set[int] = set()

    def toy(config: Mapping[str, Any], inputs: Any) -> dict[str, float]:
        seeds.add(config["filter"]["seed"])  # each trial's seed, in the `filter` section
        return {"score": abs(config["a"] - 3) + config["b"]["c"]}

    monkeypatch.setitem(tune.OBJECTIVES, "toy", toy)
    run = tune.TuneRun("r", None, {"meta": PF, "a": 0, "b": {"c": 1}})  # type: ignore[arg-type]
    factors = {
        "a": [{"a": 0}, {"a": 3}, {"a": 5}],
        "c": [{"b.c": 1}, {"b.c": 0}, {"b.c": 2}],
    }
    chosen, trials = tune.coordinate_descent(
        factors, [0, 0, 0, 0], [run], [0, 1], "toy", passes=3, canonical=dict
    )
    assert chosen == {"a": 3, "b.c": 0}
    assert [(t["factor"], t["option"], t["kept"]) for t in trials] == [
        ("start", {}, True),
        ("a", {"a": 3}, True),
        ("a", {"a": 5}, False),
        ("c", {"b.c": 0}, True),
        ("c", {"b.c": 2}, False),
        # the second sweep keeps nothing, so there is no third
        ("a", {"a": 0}, False),
        ("a", {"a": 5}, False),
        ("c", {"b.c": 1}, False),
        ("c", {"b.c": 2}, False),
    ]
    assert trials[3]["score"] == 0.0 and sorted(trials[0]["runs"]) == ["r/s0", "r/s1"]
    assert seeds == {0, 1}


def test_an_option_an_earlier_choice_rules_out_is_skipped_with_its_reason(monkeypatch) -> None:
    def toy(config: Mapping[str, Any], inputs: Any) -> dict[str, float]:
        if config["w"] == "score" and not config["v"]:
            raise ValueError("proposal: weights_from 'score' needs verified hypotheses")
        return {"score": (0.0 if config["v"] else 1.0) + (0.5 if config["w"] == "score" else 0)}

    monkeypatch.setitem(tune.OBJECTIVES, "toy", toy)
    run = tune.TuneRun("r", None, {"meta": PF, "v": True, "w": "net"})  # type: ignore[arg-type]
    factors = {"v": [{"v": False}], "w": [{"w": "score"}]}
    chosen, trials = tune.coordinate_descent(factors, [0] * 4, [run], [0], "toy", canonical=dict)
    assert chosen == {}
    assert [t.get("skipped") is None for t in trials] == [True, True, True]  # v=True: no skip
    bad = {"meta": PF, "v": False, "w": "net"}
    chosen, trials = tune.coordinate_descent(
        factors,
        [0] * 4,
        [tune.TuneRun("r", None, bad)],
        [0],
        "toy",
        canonical=dict,  # type: ignore[arg-type]
    )
    assert trials[-1]["skipped"].startswith("proposal: weights_from") and not trials[-1]["kept"]
    assert "skipped" in tune.trials_markdown(trials)


def test_a_gain_below_min_gain_keeps_the_earlier_choice(monkeypatch) -> None:
    def toy(config: Mapping[str, Any], inputs: Any) -> dict[str, float]:
        return {"score": abs(config["a"] - 3) + config["c"] + 10.0}

    monkeypatch.setitem(tune.OBJECTIVES, "toy", toy)
    run = tune.TuneRun("r", None, {"meta": PF, "a": 0, "c": 1})  # type: ignore[arg-type]
    factors = {"a": [{"a": 3}], "c": [{"c": 0}]}  # 14 -> 11 (a gain of 21 %), then -> 10 (9 %)
    descent = functools.partial(tune.coordinate_descent, canonical=dict)  # toy configs as they are
    assert descent(factors, [0] * 4, [run], [0], "toy")[0] == {"a": 3, "c": 0}
    chosen, trials = descent(factors, [0] * 4, [run], [0], "toy", min_gain=0.1)
    assert chosen == {"a": 3} and [t["kept"] for t in trials] == [True, True, False]
    with pytest.raises(ValueError, match="min_gain"):
        descent(factors, [0] * 4, [run], [0], "toy", min_gain=1.0)


def test_a_gain_inside_the_seeds_noise_keeps_the_earlier_choice(monkeypatch) -> None:
    """Option b=1 lowers the mean score by 0.01 while the seeds move it by +-0.05 each: a
    paired gain of well under 2 standard errors, kept only when min_t allows any gain. Option
    a=1 gains 1.0 on every seed: kept either way."""
    luck = np.random.default_rng(3).normal(0.0, 0.05, 12)

    def toy(config: Mapping[str, Any], inputs: Any) -> dict[str, float]:
        seed = config["filter"]["seed"]
        noisy = luck[seed] if config["b"] else luck[seed] * 0.2
        return {"score": 2.0 - config["a"] - 0.01 * config["b"] + noisy}

    monkeypatch.setitem(tune.OBJECTIVES, "toy", toy)
    run = tune.TuneRun("r", None, {"meta": PF, "a": 0, "b": 0})  # type: ignore[arg-type]
    factors = {"a": [{"a": 1}], "b": [{"b": 1}]}
    descent = functools.partial(tune.coordinate_descent, canonical=dict)
    seeds = list(range(12))
    chosen, trials = descent(factors, [0] * 4, [run], seeds, "toy", min_t=2.0)
    assert chosen == {"a": 1}
    assert abs(trials[2]["gain_t"]) < 2.0 and trials[2]["score"] < trials[1]["score"]
    assert descent(factors, [0] * 4, [run], seeds, "toy", min_t=0.0)[0] == {"a": 1, "b": 1}
    with pytest.raises(ValueError, match="min_t"):
        descent(factors, [0] * 4, [run], seeds, "toy", min_t=-1.0)


def test_the_paired_t_weighs_the_gain_by_its_spread() -> None:
    best = {"runs": {"r/s0": {"score": 1.0}, "r/s1": {"score": 1.0}, "r/s2": {"score": 1.0}}}
    trial = {"runs": {"r/s0": {"score": 0.9}, "r/s1": {"score": 0.8}, "r/s2": {"score": 0.7}}}
    # gains 0.1, 0.2, 0.3: mean 0.2, standard error 0.1 / sqrt(3)
    assert tune.paired_gain_t(trial, best) == pytest.approx(0.2 / (0.1 / np.sqrt(3)))
    assert tune.paired_gain_t(best, best) == 0.0
    same = {"runs": {k: {"score": 0.5} for k in best["runs"]}}
    assert tune.paired_gain_t(same, best) == np.inf and tune.paired_gain_t(best, same) == -np.inf


def test_a_misspelt_run_entry_is_refused_with_its_study() -> None:
    with pytest.raises(ValueError, match=r"study\.yaml: field 'runs'.*unknown keys \['map_yml'\]"):
        tune.check_run_entry({"run_dir": "r", "map_name": "m", "map_yml": "x"}, "study.yaml")
    with pytest.raises(ValueError, match=r"lacks \['map_name'\]"):
        tune.check_run_entry({"run_dir": "r"}, "study.yaml")
    with pytest.raises(ValueError, match=r"odometry expected one of \('wheel', 'laser'\)"):
        tune.check_run_entry({"run_dir": "r", "map_name": "m", "odometry": "lidar"}, "study.yaml")
    tune.check_run_entry({"run_dir": "r", "map_name": "m", "odometry": "laser"}, "study.yaml")


@pytest.mark.parametrize(
    ("meta", "said"),
    [({"part": "evaluation"}, "says part 'evaluation'"), ({}, "has no field 'part'")],
)
def test_a_study_naming_a_scored_run_is_refused(tmp_path: Path, meta: dict, said: str) -> None:
    """The split enforced: the tune command stops before any trial when a study names a run
    that is scored (or one whose part nobody wrote down), naming the study and the run."""
    run = tmp_path / "sparse_obstacles_kidnap"
    run.mkdir()
    (run / "meta.json").write_text(json.dumps(meta))
    spec = {"run_dir": str(run), "map_name": "sparse_obstacles"}
    with pytest.raises(
        ValueError, match=rf"study\.yaml: field 'runs': run {run} is not a tune run.*{said}"
    ):
        tune.check_tune_part(spec, "study.yaml")
    (run / "meta.json").write_text(json.dumps({"part": "tune"}))
    tune.check_tune_part(spec, "study.yaml")


def test_the_command_refuses_a_scored_run(tmp_path: Path) -> None:
    """The same refusal from the command line: a clear error naming the study, no traceback,
    no output written."""
    run = tmp_path / "sparse_obstacles_kidnap"
    run.mkdir()
    (run / "meta.json").write_text(json.dumps({"part": "evaluation"}))
    out = tmp_path / "out.json"
    cmd = [sys.executable, "-m", "scanloc.stages.tune", "study=hybrid",
           f"study.runs=[{{run_dir: {run}, map_name: sparse_obstacles}}]",
           f"out_path={out}", f"hydra.run.dir={tmp_path / 'h'}"]  # fmt: skip
    env = os.environ | {"PYTHONPATH": str(REPO / "src")}
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    assert done.returncode != 0 and not out.exists()
    assert "conf/study/hybrid.yaml: field 'runs'" in done.stderr
    assert "is not a tune run" in done.stderr and "Traceback" not in done.stderr


def test_every_tune_map_stands_for_that_run_of_each_tune_map(tmp_path: Path) -> None:
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"maps": {"m1": {}}, "tune_maps": {"t1": {}, "t2": {}}}))
    maps = tune.tune_maps(params)
    assert maps == ["t1", "t2"]
    explicit = {"run_dir": "data/trajectories/intel_tune", "map_name": "intel"}
    runs = tune.expand_runs([{"every_tune_map": "tune_kidnap"}, explicit], maps, "s.yaml")
    assert runs == [
        {"run_dir": "data/trajectories/t1_tune_kidnap", "map_name": "t1"},
        {"run_dir": "data/trajectories/t2_tune_kidnap", "map_name": "t2"},
        explicit,
    ]
    for bad, maps_given in (({"every_tune_map": "tune_kidnap", "odometry": "laser"}, maps),
                            ({"every_tune_map": "tune_kidnap"}, [])):  # fmt: skip
        with pytest.raises(ValueError, match=r"s\.yaml: field 'runs'.*every_tune_map"):
            tune.expand_runs([bad], maps_given, "s.yaml")


def test_tracking_cuts_a_run_at_its_kidnaps() -> None:
    traj = Trajectory(
        times=np.arange(6.0), truth=np.zeros((6, 3)), odometry=np.zeros((6, 3)), kidnap_steps=(2, 5)
    )
    inputs = LocalizeInputs(traj, np.zeros((6, 4), np.float32), Path("m.yaml"), SPEC)
    pieces = tune.stretches(inputs)
    assert [len(p.trajectory.truth) for p in pieces] == [2, 3, 1]
    assert [p.trajectory.times[0] for p in pieces] == [0.0, 2.0, 5.0]
    assert all(p.trajectory.kidnap_steps == () for p in pieces)
    assert tune.steps_of(inputs, 0, 4).trajectory.kidnap_steps == (2,)  # re-based, kept inside


def test_the_command_runs_a_study(tmp_path: Path) -> None:
    grid = small_map()
    save_map(grid, tmp_path / "map" / "map.yaml")
    traj = drive_trajectory(grid, 30, seed=1, clearance=0.25)
    scans = ug01_scans(grid, traj.truth, seed=2)
    save_trajectory(traj, tmp_path / "run", scans, meta={"part": "tune"})
    map_yaml = tmp_path / "map" / "map.yaml"
    runs = f"[{{run_dir: {tmp_path / 'run'}, map_name: small, map_yaml: {map_yaml}}}]"
    cmd = [sys.executable, "-m", "scanloc.stages.tune", "study=amcl_real", f"study.runs={runs}"]
    cmd += ["study.localizer=amcl", "study.min_gain=0.0"]  # from ROS's defaults, as first run
    cmd += [
        "seeds=[0]",
        "passes=1",
        f"out_path={tmp_path / 'out.json'}",
        f"hydra.run.dir={tmp_path / 'h'}",
    ]
    env = os.environ | {"PYTHONPATH": str(REPO / "src")}
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["study"] == "amcl_real" and result["runs"] == ["run/wheel"]
    trials = json.loads((tmp_path / "out.json").read_text())["trials"]
    # every option but each factor's current one is tried once: 19 options of 7 factors
    assert len(trials) == 1 + 19 - 7 and trials[0]["factor"] == "start"
    assert all(t["pos_err_rmse_m"] < 0.5 for t in trials)  # amcl tracks the small room
    with pytest.raises(KeyError):
        trials[0]["steps_to_converge"]  # the tracking objective's figures only


@pytest.mark.parametrize("study_file", sorted((REPO / "conf" / "study").glob("*.yaml")), ids=str)
def test_every_study_names_what_the_tune_command_reads(study_file: Path) -> None:
    """A study file's typo would surface only minutes into a run (or never, for a factor key
    the filter ignores): its name, objective, run entries (the pipeline's runs) and every
    key it tries (`section.key` of the localizer's config, or fitted_alpha_scale) are checked
    up front: each option, set on the study's localizer as the tune command sets it, must
    leave a config whose kind reads every section and whose parts know every key."""
    study = yaml.safe_load(study_file.read_text())
    assert study["name"] == study_file.stem
    assert study["objective"] in tune.OBJECTIVES
    assert (REPO / "conf" / "localizer" / f"{study['localizer']}.yaml").is_file()
    tune_runs = {
        run for kind in yaml.safe_load((REPO / "conf" / "seeds.yaml").read_text())["runs"].values()
        for run in kind["tune"]
    }  # fmt: skip
    maps = tune.tune_maps(REPO / "params.yaml")
    for run in tune.expand_runs(study["runs"], maps, study_file.name):
        tune.check_run_entry(run, study_file.name)
        assert str(run["run_dir"]).startswith("data/trajectories/")
        name = Path(run["run_dir"]).name  # <site>_<run>: a run of the tune side of the split
        assert name.removeprefix(f"{run['map_name']}_") in tune_runs, (study_file.name, name)
    localizer = raw_config(study["localizer"], REPO / "conf" / "localizer")
    kind = kind_of(localizer)
    for factor, options in study["factors"].items():
        for option in options:
            keys = tune.resolve_option(option, [0.1, 0.2, 0.3, 0.4])
            config = tune.with_keys(localizer, keys)
            where = f"{study_file.name}: factor {factor}: {config_file(config)}"
            check_sections(config, KIND_SECTIONS[kind], where, f"a localizer of kind '{kind}'")
            whole = resolved(config)  # every section parsed by its part: unknown keys fail
            for dotted, value in keys.items():
                section, key = dotted.split(".")
                assert whole[section][key] == value, f"{where}: {dotted} does not reach its part"
