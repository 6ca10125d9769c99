"""`tune` stage: choose a localizer's settings on tune runs, by coordinate descent
(conf/tune.yaml; a study in conf/study/ names the localizer, its tune runs, the objective and
the factors).

DVC runs each study of params.yaml `tune_studies` (`tune@<study>`) and tracks its record,
reports/tuning/<study>.json (every trial, its score, the choice); the choice is written into
the localizer's config by a person, with its figures, and tests/test_tuning_outputs.py fails
when the config no longer holds it. The tune runs are never scored (a tune map's or a map's
tune_kidnap run, a real log's mapping part: conf/seeds.yaml), so a setting is never chosen on
the runs that judge it: the stage refuses any run whose meta.json does not say `part: tune`.
A study's run entry `{every_tune_map: <run>}` stands for that run of every tune map
(params.yaml `tune_maps`): generated maps nothing is scored on. Prints one Markdown row per
trial; the last line is one JSON object of the result.

Why coordinate descent and not a full grid: the amcl_real study's 7 factors of 2–4 options
are 2592 configurations; one factor at a time, in the study's order, is 13 trials a sweep (a
second sweep revisits each factor with the others' choices made), and each factor's effect can
be read off the table.

Objectives (lower is better, a mean over runs and seeds):
- `tracking`: position RMSE [m] + heading RMSE [rad], each run cut at its kidnap steps and every
  stretch tracked from its own first pose;
- `global`: over the run's stretches (the start and each kidnap), the share not converged
  within 20 steps + the mean steps to converge / 100 (censored counts) + the tracking position
  error [m] (1 m when never converged): one failure in ten stretches weighs like 10 steps more
  per stretch or 10 cm more tracking error. The issue's goal (every stretch within 20 steps)
  comes first, speed and accuracy break ties.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from hydra import compose
from omegaconf import DictConfig

from scanloc.evaluate.metrics import (
    RECOVERED_WITHIN_STEPS,
    convergence_metrics,
    localization_metrics,
)
from scanloc.io import read_json, write_json
from scanloc.localize.kinds import LocalizeInputs, run_localizer, with_seed
from scanloc.localize.mcl.motion_fit import fit_odometry_alphas
from scanloc.localize.show import resolved
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.sites import PARAMS, site_kinds
from scanloc.stages._app import conf_dir, stage_main, timed_stage, to_dict
from scanloc.stages.localize import ODOMETRY_SOURCES, laser_mount, select_odometry
from scanloc.trajectory.format import Trajectory, load_trajectory

FITTED_SCALE_KEY = "fitted_alpha_scale"
DEFAULT_SENSOR = "urg04lx"  # the maps' laser (conf/localize.yaml)
NEVER_CONVERGED_ERROR_M = 1.0


@dataclass(frozen=True)
class TuneRun:
    """One tune run as the localizers see it, and the localizer's config composed for its map."""

    name: str
    inputs: LocalizeInputs
    localizer: dict[str, Any]


def with_keys(config: Mapping[str, Any], keys: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of `config` with the dotted `keys` set (nested mappings copied, not shared)."""
    out = json.loads(json.dumps(config))
    for dotted, value in keys.items():
        *parents, leaf = dotted.split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def resolve_option(option: Mapping[str, Any], fitted: Sequence[float]) -> dict[str, Any]:
    """A factor option as localizer config keys: `fitted_alpha_scale: k` becomes
    motion.odom_alpha1..4 = k × the fitted alphas."""
    keys = {k: v for k, v in option.items() if k != FITTED_SCALE_KEY}
    if FITTED_SCALE_KEY in option:
        scale = float(option[FITTED_SCALE_KEY])
        keys |= {f"motion.odom_alpha{i}": scale * a for i, a in enumerate(fitted, start=1)}
    return keys


def steps_of(inputs: LocalizeInputs, start: int, stop: int) -> LocalizeInputs:
    """Steps [start, stop) of a run as a run of their own (kidnap steps inside it re-based)."""
    traj = inputs.trajectory
    laser = None if traj.laser_odometry is None else traj.laser_odometry[start:stop]
    piece = Trajectory(
        times=traj.times[start:stop], truth=traj.truth[start:stop],
        odometry=traj.odometry[start:stop], laser_odometry=laser,
        kidnap_steps=tuple(k - start for k in traj.kidnap_steps if start < k < stop),
    )  # fmt: skip
    return LocalizeInputs(
        piece, inputs.ranges[start:stop], inputs.map_yaml, inputs.laser, inputs.laser_mount
    )


def stretches(inputs: LocalizeInputs) -> list[LocalizeInputs]:
    """The run cut at its kidnap steps: each stretch tracked from its own first true pose."""
    bounds = [0, *inputs.trajectory.kidnap_steps, len(inputs.trajectory.truth)]
    return [steps_of(inputs, a, b) for a, b in itertools.pairwise(bounds)]


def tracking_score(config: Mapping[str, Any], inputs: LocalizeInputs) -> dict[str, float]:
    """Position and heading RMSE over the run's stretches (objective `tracking`)."""
    pos, heading = [], []
    for piece in stretches(inputs):
        m = localization_metrics(piece.trajectory.truth, run_localizer(config, piece).table)
        pos.append(m["pos_err_rmse_m"])
        heading.append(m["heading_err_rmse_deg"])
    pos_rmse, heading_rmse = float(np.mean(pos)), float(np.mean(heading))
    return {
        "score": pos_rmse + math.radians(heading_rmse),
        "pos_err_rmse_m": pos_rmse,
        "heading_err_rmse_deg": heading_rmse,
    }


def global_score(config: Mapping[str, Any], inputs: LocalizeInputs) -> dict[str, float]:
    """Failures, steps and tracking error over the run's stretches (objective `global`)."""
    traj = inputs.trajectory
    table = run_localizer(config, inputs).table
    m = convergence_metrics(traj.truth, table, traj.kidnap_steps)
    kidnaps = int(m.get("kidnaps", 0))
    started = bool(m["converged"]) and m["steps_to_converge"] <= RECOVERED_WITHIN_STEPS
    recovered = m.get("kidnaps_recovered_frac", 0.0) * kidnaps
    failures = (1 + kidnaps - int(started) - recovered) / (1 + kidnaps)
    steps = (m["steps_to_converge"] + m.get("recovery_steps_mean", 0.0) * kidnaps) / (1 + kidnaps)
    error = m["tracking_pos_err_mean_m"]
    error = NEVER_CONVERGED_ERROR_M if not math.isfinite(error) else error
    return {
        "score": failures + steps / 100.0 + error,
        "failures": failures,
        "steps": steps,
        "tracking_pos_err_mean_m": error,
    }


OBJECTIVES: dict[str, Callable[[Mapping[str, Any], LocalizeInputs], dict[str, float]]] = {
    "tracking": tracking_score,
    "global": global_score,
}


def score_trial(
    keys: Mapping[str, Any], runs: Sequence[TuneRun], seeds: Sequence[int], objective: str
) -> dict[str, Any]:
    """The objective's figures on every run and seed with `keys` set, and their means."""
    per_run = {
        f"{run.name}/s{seed}": OBJECTIVES[objective](
            with_seed(with_keys(run.localizer, keys), int(seed)), run.inputs
        )
        for run in runs
        for seed in seeds
    }
    figures = sorted({k for r in per_run.values() for k in r})
    return {k: float(np.mean([r[k] for r in per_run.values()])) for k in figures} | {
        "runs": per_run
    }


def paired_gain_t(trial: Mapping[str, Any], best: Mapping[str, Any]) -> float:
    """The paired t statistic of a trial's gain over the best so far: the mean over the run x
    seed pairs of (best's score - the trial's) divided by its standard error. The same gain on
    every pair (or a single pair) gives +-inf: nothing to weigh it against; no gain gives 0."""
    gains = np.array([best["runs"][k]["score"] - trial["runs"][k]["score"] for k in best["runs"]])
    mean = float(gains.mean())
    spread = float(gains.std(ddof=1)) if len(gains) > 1 else 0.0
    if spread == 0.0:
        return math.copysign(math.inf, mean) if mean else 0.0
    return mean / (spread / math.sqrt(len(gains)))


def coordinate_descent(
    factors: Mapping[str, Sequence[Mapping[str, Any]]],
    fitted: Sequence[float],
    runs: Sequence[TuneRun],
    seeds: Sequence[int],
    objective: str,
    passes: int = 1,
    min_gain: float = 0.0,
    canonical: Callable[[dict[str, Any]], dict[str, Any]] = resolved,
    min_t: float = 0.0,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The chosen keys and every trial, in order (module doc): up to `passes` sweeps over the
    factors, stopping after a sweep that keeps nothing (a later factor's choice can change
    which option of an earlier one is best). An option is kept when it lowers the best score
    so far by more than the fraction `min_gain` of it (0: by anything) and its gain, paired
    over the runs and seeds, is at least `min_t` standard errors (`paired_gain_t`; 0: any
    gain), so that a margin inside the seeds' noise does not decide a factor. Two trials are
    the same when their configs are, every default filled in (`canonical`). An option that
    cannot go with the choices made so far (its localizer refuses the config: a score
    weighting once verification is off) is recorded as `skipped`, with the reason, and not
    scored."""
    if not 0.0 <= min_gain < 1.0:
        raise ValueError(
            f"field 'min_gain' (conf/tune.yaml or the study's): expected a fraction in [0, 1), "
            f"got {min_gain}"
        )
    if not min_t >= 0.0:
        raise ValueError(
            f"field 'min_t' (conf/tune.yaml or the study's): expected a number >= 0, got {min_t}"
        )
    base = runs[0].localizer
    chosen: dict[str, Any] = {}
    scored: dict[str, dict[str, Any]] = {}  # by the whole config: none is run twice

    def whole(keys: dict[str, Any]) -> dict[str, Any]:
        """The config with `keys` set, every default filled in: an option that writes a
        default is the setting it already had."""
        return canonical(with_keys(base, keys))

    def score(keys: dict[str, Any]) -> dict[str, Any]:
        config = json.dumps(whole(keys), sort_keys=True)
        if config not in scored:
            scored[config] = score_trial(keys, runs, seeds, objective)
        return scored[config]

    best = score(chosen)
    trials = [{"factor": "start", "option": {}, "pass": 0, **best, "kept": True}]
    for sweep in range(1, passes + 1):
        improved = False
        for factor, options in factors.items():
            for option in options:
                keys = resolve_option(option, fitted)
                if whole(chosen | keys) == whole(chosen):
                    continue  # the current setting: already scored
                try:
                    result = score(chosen | keys)
                except ValueError as err:  # the option cannot go with an earlier choice
                    trials.append({"factor": factor, "option": keys, "pass": sweep,
                                   "skipped": str(err), "kept": False})  # fmt: skip
                    continue
                gain_t = paired_gain_t(result, best)
                kept = result["score"] < best["score"] * (1.0 - min_gain) and gain_t >= min_t
                significance = {"gain_t": gain_t} if math.isfinite(gain_t) else {}
                trials.append(
                    {"factor": factor, "option": keys, "pass": sweep, **result, **significance,
                     "kept": kept}
                )  # fmt: skip
                if kept:
                    best, chosen, improved = result, chosen | keys, True
        if not improved:
            break
    return chosen, trials


EVERY_TUNE_MAP = "every_tune_map"
REQUIRED_RUN_KEYS = ("run_dir", "map_name")
OPTIONAL_RUN_KEYS = ("map_yaml", "sensor_file", "odometry")


def tune_maps(params_path: Path = PARAMS) -> list[str]:
    """The tune maps of params.yaml, in its order."""
    params = yaml.safe_load(params_path.read_text()) or {}
    return [site for site, kind in site_kinds(params, params_path).items() if kind == "tune_map"]


def expand_runs(entries: Sequence[Mapping[str, Any]], maps: Sequence[str], where: str) -> list:
    """A study's run entries with each `{every_tune_map: <run>}` replaced by that run of every
    tune map in `maps`."""
    runs: list[dict[str, Any]] = []
    for spec in entries:
        if EVERY_TUNE_MAP not in spec:
            runs.append(dict(spec))
            continue
        if len(spec) != 1 or not maps:
            raise ValueError(
                f"{where}: field 'runs': entry {dict(spec)}: expected '{EVERY_TUNE_MAP}' alone"
                + ("" if maps else f", and at least one tune map in {PARAMS} `tune_maps`")
            )
        run = spec[EVERY_TUNE_MAP]
        runs += [{"run_dir": f"data/trajectories/{m}_{run}", "map_name": m} for m in maps]
    return runs


def check_run_entry(spec: Mapping[str, Any], where: str) -> None:
    """A study's run entry names the keys tune_run reads, and only those, with an odometry
    source the localize stage knows: a misspelt optional key (a map_yml) would otherwise be
    ignored and the run localized in the wrong map."""
    missing = [k for k in REQUIRED_RUN_KEYS if k not in spec]
    unknown = sorted(set(spec) - set(REQUIRED_RUN_KEYS) - set(OPTIONAL_RUN_KEYS))
    if missing or unknown:
        raise ValueError(
            f"{where}: field 'runs': entry {dict(spec)} "
            + (f"lacks {missing}" if missing else f"has unknown keys {unknown}")
            + f"; expected {list(REQUIRED_RUN_KEYS)} and optionally {list(OPTIONAL_RUN_KEYS)}"
        )
    if spec.get("odometry", "wheel") not in ODOMETRY_SOURCES:
        raise ValueError(
            f"{where}: field 'runs': entry {dict(spec)}: odometry expected one of "
            f"{ODOMETRY_SOURCES}, got {spec['odometry']!r}"
        )


def check_tune_part(spec: Mapping[str, Any], where: str) -> None:
    """Refuse a run that is not a tune run: choosing a setting on a run that is scored is
    tuning on the test set. A run's part is in its meta.json (written by the stage that made
    it from conf/seeds.yaml `runs`, scanloc.sites.run_part); a run without one is refused too,
    since nothing says it is never scored."""
    meta_path = Path(spec["run_dir"]) / "meta.json"
    if not meta_path.is_file():
        raise ValueError(f"{where}: field 'runs': {meta_path} does not exist")
    part = read_json(meta_path).get("part")
    if part != "tune":
        said = f"says part {part!r}" if part is not None else "has no field 'part'"
        raise ValueError(
            f"{where}: field 'runs': run {spec['run_dir']} is not a tune run (its meta.json "
            f"{said}; expected 'tune'). A study may choose settings on tune runs only "
            "(conf/seeds.yaml `runs.<kind>.tune`), never on the runs that are scored"
        )


def tune_run(spec: Mapping[str, Any], localizer: str, max_steps: int | None) -> TuneRun:
    """A study's run entry (REQUIRED_RUN_KEYS, OPTIONAL_RUN_KEYS) loaded, with the localizer
    composed for its map as the localize stage composes it."""
    run_dir = Path(spec["run_dir"])
    traj, ranges = load_trajectory(run_dir)
    odometry = str(spec.get("odometry", "wheel"))
    sensor_file = Path(
        spec.get("sensor_file") or Path(conf_dir()) / "sensor" / f"{DEFAULT_SENSOR}.yaml"
    )
    spec_laser = laser_spec_from_config(yaml.safe_load(sensor_file.read_text()))
    map_yaml = Path(spec.get("map_yaml") or f"data/maps/{spec['map_name']}/map.yaml")
    overrides = [f"localizer={localizer}", f"map_name={spec['map_name']}"]
    composed = to_dict(compose(config_name="localize", overrides=overrides).localizer)
    inputs = LocalizeInputs(
        select_odometry(traj, odometry, run_dir), ranges, map_yaml, spec_laser, laser_mount(run_dir)
    )
    if max_steps is not None:
        inputs = steps_of(inputs, 0, max_steps)
    return TuneRun(f"{run_dir.name}/{odometry}", inputs, composed)


def trials_markdown(trials: Sequence[Mapping[str, Any]]) -> str:
    """One row per trial: factor, option, the objective's figures, kept."""
    figures = [k for k in trials[0] if k not in ("factor", "option", "pass", "kept", "runs")]
    lines = [
        "| pass | factor | option | " + " | ".join(figures) + " | kept |",
        "|---|---|---|" + "---|" * len(figures) + "---|",
    ]
    for t in trials:
        if "skipped" in t:
            lines.append(
                f"| {t['pass']} | {t['factor']} | {t['option']} | skipped: {t['skipped']} |"
            )
            continue
        option = ", ".join(
            f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in t["option"].items()
        )
        values = " | ".join(f"{t[k]:.4f}" for k in figures)
        kept = "yes" if t["kept"] else ""
        lines.append(
            f"| {t['pass']} | {t['factor']} | {option or 'the config'} | {values} | {kept} |"
        )
    return "\n".join(lines)


@stage_main("tune")
def main(cfg: DictConfig) -> None:
    study = to_dict(cfg.study)
    if study["objective"] not in OBJECTIVES:
        raise ValueError(
            f"conf/study/{study['name']}.yaml: field 'objective': expected one of "
            f"{sorted(OBJECTIVES)}, got {study['objective']!r}"
        )
    where = f"conf/study/{study['name']}.yaml"
    max_steps = None if cfg.max_steps is None else int(cfg.max_steps)
    entries = expand_runs(study["runs"], tune_maps(), where)
    for spec in entries:
        check_run_entry(spec, where)
        check_tune_part(spec, where)
    seeds = [int(s) for s in study.get("seeds", cfg.seeds)][: cfg.max_seeds]
    with timed_stage(f"tune_{study['name']}", cfg.timing_dir):
        runs = [tune_run(spec, study["localizer"], max_steps) for spec in entries]
        first = runs[0].inputs.trajectory
        fitted = fit_odometry_alphas(first.odometry, first.truth, first.kidnap_steps)
        chosen, trials = coordinate_descent(
            study["factors"],
            fitted,
            runs,
            seeds,
            study["objective"],
            int(cfg.passes),
            float(study.get("min_gain", cfg.min_gain)),
            min_t=float(study.get("min_t", cfg.min_t)),
        )
    result = {
        "study": study["name"],
        "localizer": study["localizer"],
        "objective": study["objective"],
        "runs": [run.name for run in runs],
        "seeds": seeds,
        "fitted_alphas": list(fitted),
        "chosen": chosen,
        "trials": [{"trial": i, **trial} for i, trial in enumerate(trials)],
    }
    write_json(Path(cfg.out_path), result)
    print(trials_markdown(trials))
    print(json.dumps({k: v for k, v in result.items() if k != "trials"}))


if __name__ == "__main__":
    main()
