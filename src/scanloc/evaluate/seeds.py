"""Global-localization figures over trajectory seeds: success rates with Wilson intervals and
the distribution of steps to converge and to recover, per map and localizer.

One map's evaluation set is its kidnap runs over several trajectory seeds (conf/seeds.yaml).
Each run gives one global-localization start (the stretch before the first kidnap) and one
recovery per kidnap. Following the seeds contract (docs/design.md ★): a figure over seeds
keeps the per-run metric name for its mean, with `<name>_ci95_low`, `<name>_ci95_high` and
`n_seeds` beside it, and the per-seed values under `seeds/<i>/<name>`.

- `convergence_success`: share of runs whose localizer converged (metrics.py) within
  `converge_within` steps of the start; Wilson 95 % interval over the n_seeds runs.
  `converged`: share that converged at all before the first kidnap (else steps_to_converge is
  censored); `recovered`: kidnaps recovered at all per run (mean, `_total`).
- `kidnaps_recovered_frac`: share of all kidnaps of the set recovered within 20 steps
  (metrics.RECOVERED_WITHIN_STEPS), pooled over the runs (`n_kidnaps` events in
  `n_runs_kidnapped` runs). Its interval counts runs, not events (`clustered_wilson_interval`,
  the effective count beside it as `_effective_n`): a run's kidnaps share its route, its scans
  and its filter, so they are not independent trials.
- `steps_to_converge` (mean, `_median`, `_max` = worst seed) and `recovery_steps` (`_mean`,
  `_median`, `_max` over all kidnaps): censored counts as in metrics.py (a localizer that never
  converges in a stretch gets the stretch's length), so they are lower bounds where censored.
- `relosses`, `false_convergences`: mean per run with a Student-t 95 % interval, and `_total`.
- Given which stretches are *ambiguous* (a copy of the map renders the same scans for their
  first 20 steps: look_alikes.py), `n_starts_ambiguous` / `n_kidnaps_ambiguous` count them and
  `convergence_success_resolvable` / `kidnaps_recovered_frac_resolvable` are the two rates over
  the other stretches only (`n_starts_resolvable`, `n_kidnaps_resolvable` trials, the latter
  in `n_runs_kidnaps_resolvable` runs, its interval by run): what a localizer achieves where
  the scans can tell.

Real logs are judged over *filter* seeds instead (one run, the particle filters' seeds:
`over_filter_seeds`, `evaluate_filter_seeds`): the run is the log, only the filter's draws
differ.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from scanloc.evaluate.metrics import RECOVERED_WITHIN_STEPS
from scanloc.evaluate.table2 import evaluate_trajectory

Z95 = 1.959963984540054  # the standard normal's 97.5 % quantile


def wilson_interval(successes: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default): unlike the normal
    approximation it stays inside [0, 1] and is not empty at 0 or n successes."""
    if trials <= 0 or not 0 <= successes <= trials:
        raise ValueError(
            f"wilson_interval: expected 0 <= successes <= trials, trials > 0; "
            f"got {successes} of {trials}"
        )
    return wilson_interval_at(successes / trials, float(trials), z)


def clustered_wilson_interval(
    successes: Sequence[int], trials: Sequence[int], z: float = Z95
) -> tuple[float, float, float]:
    """(low, high, effective n) of the pooled rate sum(successes) / sum(trials) over runs
    (clusters) whose events may be correlated: a cluster-robust Wilson interval, the Wilson
    score interval at the effective sample size n / deff. The design effect deff is the
    ratio estimator's between-run variance over the binomial one; n_eff is clipped to
    [runs, events], i.e. an intra-run correlation between 0 (independent events: the pooled
    Wilson interval) and 1 (a run is one trial). Where every event succeeded or failed, the
    spread cannot be estimated and the run count is used: the cautious end."""
    y, n = np.asarray(successes, np.float64), np.asarray(trials, np.float64)
    if y.shape != n.shape or y.size == 0 or (n <= 0).any() or (y < 0).any() or (y > n).any():
        raise ValueError(
            "clustered_wilson_interval: expected per-run successes and trials of equal length, "
            f"0 <= successes <= trials, trials > 0; got {list(successes)} of {list(trials)}"
        )
    runs, total = y.size, float(n.sum())
    p = float(y.sum()) / total
    binomial = p * (1.0 - p) / total
    if runs < 2 or binomial == 0.0:
        n_eff = float(runs)
    else:
        between = runs / (runs - 1) * float(np.sum((y - p * n) ** 2)) / total**2
        n_eff = total if between == 0.0 else total * binomial / between
    n_eff = min(max(n_eff, float(runs)), total)
    low, high = wilson_interval_at(p, n_eff, z)
    return low, high, n_eff


def wilson_interval_at(rate: float, n: float, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of an observed `rate` at a (possibly fractional) sample size
    `n`: what `wilson_interval` gives for rate · n successes in n trials."""
    denom = 1.0 + z * z / n
    centre = (rate + z * z / (2 * n)) / denom
    half = z * math.sqrt(rate * (1 - rate) / n + z * z / (4 * n * n)) / denom
    # At a rate of 0 (or 1) the bound is 0 (or 1) exactly; rounding would leave ~1e-17.
    low = 0.0 if rate == 0.0 else max(0.0, centre - half)
    high = 1.0 if rate == 1.0 else min(1.0, centre + half)
    return low, high


def mean_interval(values: Sequence[float]) -> tuple[float, float, float]:
    """Mean and Student-t 95 % interval of per-seed counts, clipped at 0 (a count is never
    negative); one value: the interval is that value, there being no spread to estimate."""
    arr = np.asarray(values, dtype=np.float64)
    mean = float(arr.mean())
    if arr.size < 2:
        return mean, mean, mean
    half = float(stats.t.ppf(0.975, arr.size - 1) * arr.std(ddof=1) / math.sqrt(arr.size))
    return mean, max(0.0, mean - half), mean + half


def _rate(name: str, successes: int, trials: int) -> dict[str, float]:
    low, high = wilson_interval(successes, trials)
    return {name: successes / trials, f"{name}_ci95_low": low, f"{name}_ci95_high": high}


def _clustered_rate(name: str, successes: Sequence[int], trials: Sequence[int]) -> dict[str, float]:
    """A rate pooled over runs with its run-clustered interval and the effective count."""
    low, high, n_eff = clustered_wilson_interval(successes, trials)
    return {
        name: sum(successes) / sum(trials),
        f"{name}_ci95_low": low,
        f"{name}_ci95_high": high,
        f"{name}_effective_n": n_eff,
    }


def _mean(name: str, values: Sequence[float]) -> dict[str, float]:
    mean, low, high = mean_interval(values)
    total = float(np.sum(values))
    return {name: mean, f"{name}_ci95_low": low, f"{name}_ci95_high": high, f"{name}_total": total}


def recovery_counts(metrics: Mapping[str, Any]) -> list[float]:
    """The per-kidnap recovery steps (`recovery_steps_<k>`, k = 1, 2, ...) of one run."""
    return [float(metrics[f"recovery_steps_{k}"]) for k in range(1, int(metrics["kidnaps"]) + 1)]


def _resolvable_rates(
    runs: Sequence[Mapping[str, Any]],
    quick: Sequence[int],
    ambiguous: Sequence[Sequence[bool]],
) -> dict[str, Any]:
    """The start and kidnap rates over the stretches that are not ambiguous (module doc)."""
    if len(ambiguous) != len(runs):
        raise ValueError(f"over_seeds: {len(ambiguous)} look-alike lists for {len(runs)} runs")
    starts = [int(q) for q, flags in zip(quick, ambiguous, strict=True) if not flags[0]]
    kidnaps: list[list[int]] = []  # per run, its resolvable kidnaps' outcomes
    for run, flags in zip(runs, ambiguous, strict=True):
        counts = recovery_counts(run) if run.get("kidnaps") else []
        if len(flags) != 1 + len(counts):
            raise ValueError(
                f"over_seeds: {len(flags)} look-alike flags for a run of {1 + len(counts)} "
                "stretches"
            )
        pairs = zip(counts, flags[1:], strict=True)
        outcomes = [int(c <= RECOVERED_WITHIN_STEPS) for c, a in pairs if not a]
        if outcomes:
            kidnaps.append(outcomes)
    n_resolvable = sum(map(len, kidnaps))
    out: dict[str, Any] = {
        "n_starts_ambiguous": len(runs) - len(starts),
        "n_starts_resolvable": len(starts),
        "n_kidnaps_ambiguous": sum(len(f) - 1 for f in ambiguous) - n_resolvable,
        "n_kidnaps_resolvable": n_resolvable,
        "n_runs_kidnaps_resolvable": len(kidnaps),
    }
    if starts:
        out |= _rate("convergence_success_resolvable", sum(starts), len(starts))
    if kidnaps:
        out |= _clustered_rate(
            "kidnaps_recovered_frac_resolvable",
            [sum(k) for k in kidnaps],
            [len(k) for k in kidnaps],
        )
    return out


def over_seeds(
    runs: Sequence[Mapping[str, Any]],
    converge_within: int,
    ambiguous: Sequence[Sequence[bool]] | None = None,
) -> dict[str, Any]:
    """One localizer's figures over its evaluation runs (one metrics dict per seed, in seed
    order; see the module docstring); `ambiguous`: per run, per stretch (start, each kidnap),
    whether a look-alike lasts its first steps."""
    if not runs:
        raise ValueError("over_seeds: no runs")
    steps = [float(r["steps_to_converge"]) for r in runs]
    quick = [int(bool(r["converged"]) and r["steps_to_converge"] <= converge_within) for r in runs]
    out: dict[str, Any] = {"n_seeds": len(runs), "converge_within_steps": converge_within}
    out |= _rate("convergence_success", sum(quick), len(runs))
    out |= _rate("converged", sum(int(bool(r["converged"])) for r in runs), len(runs))
    out |= _mean("steps_to_converge", steps)
    out["steps_to_converge_median"] = float(np.median(steps))
    out["steps_to_converge_max"] = max(steps)
    kidnapped = [r for r in runs if r.get("kidnaps")]
    if kidnapped:
        counts = [c for r in kidnapped for c in recovery_counts(r)]
        recovered = [
            round(float(r["kidnaps_recovered_frac"]) * int(r["kidnaps"])) for r in kidnapped
        ]
        out["n_kidnaps"] = len(counts)
        out["n_runs_kidnapped"] = len(kidnapped)
        out |= _mean("recovered", [float(r["recovered"]) for r in kidnapped])
        out |= _clustered_rate(
            "kidnaps_recovered_frac", recovered, [int(r["kidnaps"]) for r in kidnapped]
        )
        out["recovery_steps_mean"] = float(np.mean(counts))
        out["recovery_steps_median"] = float(np.median(counts))
        out["recovery_steps_max"] = max(counts)
    for name in ("relosses", "false_convergences"):
        values = [float(r[name]) for r in runs if r.get(name) is not None]
        if len(values) == len(runs):
            out |= _mean(name, values)
    if ambiguous is not None:
        out |= _resolvable_rates(runs, quick, ambiguous)
    out["seeds"] = {
        str(i): {
            "convergence_success": quick[i],
            "steps_to_converge": steps[i],
            **{
                k: r[k]
                for k in (
                    "kidnaps_recovered_frac",
                    "recovery_steps_max",
                    "relosses",
                    "false_convergences",
                )
                if r.get(k) is not None
            },
        }
        for i, r in enumerate(runs)
    }
    return out


def global_localization(
    localization: Mapping[str, Mapping[str, Mapping[str, Any]]],
    evaluation_sets: Mapping[str, Sequence[str]],
    converge_within: int,
    ambiguous: Mapping[str, Sequence[bool]] | None = None,
) -> dict[str, dict[str, dict[str, Any]]]:
    """{map: {localizer: figures over seeds}} from the per-trajectory metrics
    {trajectory: {localizer: metrics}}; `evaluation_sets` names each map's evaluation runs in
    seed order. A localizer is scored over the runs that have it (n_seeds says how many).
    `ambiguous`: per trajectory, its stretches' look-alike flags (a map whose runs are all in
    it gets the rates over its resolvable stretches)."""
    ambiguous = ambiguous or {}
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for map_name, trajectories in evaluation_sets.items():
        missing = [t for t in trajectories if t not in localization]
        if missing:
            raise ValueError(f"global localization of {map_name}: no metrics for {missing}")
        methods = sorted({m for t in trajectories for m in localization[t]})
        out[map_name] = {}
        for m in methods:
            scored = [t for t in trajectories if m in localization[t]]
            flags = [ambiguous[t] for t in scored] if all(t in ambiguous for t in scored) else None
            out[map_name][m] = over_seeds(
                [localization[t][m] for t in scored], converge_within, flags
            )
    return out


# What a real-log run is judged by over filter seeds (reports/metrics/real_seeds.json).
FILTER_SEED_METRICS = (
    "pos_err_rmse_m",
    "pos_err_median_m",
    "heading_err_rmse_deg",
    "frac_gross_over_1m",
    "steps_to_converge",
    "kidnaps_recovered_frac",
    "recovery_steps_max",
    "relosses",
)


def over_filter_seeds(runs: Mapping[int, Mapping[str, Any]]) -> dict[str, Any]:
    """One localizer's figures over filter seeds on one run ({seed: metrics}): per metric of
    FILTER_SEED_METRICS the mean with a Student-t 95 % interval and the worst seed (`_max`),
    `n_seeds`, and the per-seed values under `seeds/<seed>/` (the seeds contract). A
    deterministic localizer has one seed: its interval is its value."""
    if not runs:
        raise ValueError("over_filter_seeds: no runs")
    out: dict[str, Any] = {"n_seeds": len(runs)}
    for name in FILTER_SEED_METRICS:
        values = [float(r[name]) for r in runs.values() if r.get(name) is not None]
        if len(values) != len(runs) or not np.isfinite(values).all():
            continue
        mean, low, high = mean_interval(values)
        out |= {name: mean, f"{name}_ci95_low": low, f"{name}_ci95_high": high}
        out[f"{name}_max"] = max(values)
    out["seeds"] = {
        str(seed): {k: r[k] for k in FILTER_SEED_METRICS if r.get(k) is not None}
        for seed, r in sorted(runs.items())
    }
    return out


def evaluate_filter_seeds(trajectory_dir: Path, seeds_dir: Path) -> dict[str, dict[str, Any]]:
    """{localizer: figures over seeds} of a localize_seeds folder (<seeds_dir>/s<seed>/
    <localizer>.csv) against its trajectory."""
    folders = sorted(
        (p for p in Path(seeds_dir).glob("s*") if p.is_dir() and p.name[1:].isdigit()),
        key=lambda p: int(p.name[1:]),
    )
    if not folders:
        raise FileNotFoundError(f"{seeds_dir}: no s<seed>/ folders of estimate tables")
    per_localizer: dict[str, dict[int, Mapping[str, Any]]] = {}
    for folder in folders:
        for name, metrics in evaluate_trajectory(Path(trajectory_dir), [folder]).items():
            per_localizer.setdefault(name, {})[int(folder.name[1:])] = metrics
    return {name: over_filter_seeds(runs) for name, runs in sorted(per_localizer.items())}
