"""Figures over seeds: the Wilson interval and the per-map, per-localizer aggregate."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from scanloc.evaluate.seeds import (
    clustered_wilson_interval,
    global_localization,
    mean_interval,
    over_seeds,
    wilson_interval,
)


def test_wilson_interval_matches_a_hand_computation_and_scipy() -> None:
    # 3 of 5, z = 1.96: centre (0.6 + 1.96²/10) / (1 + 1.96²/5), half-width
    # 1.96 √(0.24/5 + 1.96²/100) / (1 + 1.96²/5)
    z = 1.959963984540054
    denom = 1 + z * z / 5
    centre, half = (0.6 + z * z / 10) / denom, z * math.sqrt(0.048 + z * z / 100) / denom
    low, high = wilson_interval(3, 5)
    assert (low, high) == pytest.approx((centre - half, centre + half), abs=1e-12)
    assert (low, high) == pytest.approx((0.2307, 0.8824), abs=1e-4)
    for k, n in ((0, 5), (5, 5), (14, 15), (1, 3)):
        ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
        assert wilson_interval(k, n) == pytest.approx((ci.low, ci.high), abs=1e-12)
    assert wilson_interval(0, 5)[0] == 0.0 and wilson_interval(5, 5)[1] == 1.0
    with pytest.raises(ValueError, match="successes"):
        wilson_interval(6, 5)


def test_clustered_wilson_spans_independent_events_to_one_trial_per_run() -> None:
    """Runs that each recover half their kidnaps (no spread between runs) are independent
    events: the pooled Wilson interval. Runs that recover all or none (all the spread between
    runs) are one trial each: Wilson over the runs. All recovered: the run count (the
    spread cannot be estimated, the cautious end)."""
    low, high, n_eff = clustered_wilson_interval([2, 2, 2, 2, 2], [4, 4, 4, 4, 4])
    assert n_eff == 20 and (low, high) == pytest.approx(wilson_interval(10, 20), abs=1e-12)
    low, high, n_eff = clustered_wilson_interval([3, 3, 0, 0], [3, 3, 3, 3])
    assert n_eff == 4 and (low, high) == pytest.approx(wilson_interval(2, 4), abs=1e-12)
    low, high, n_eff = clustered_wilson_interval([3] * 5, [3] * 5)
    assert n_eff == 5 and (low, high) == wilson_interval(5, 5)
    with pytest.raises(ValueError, match="successes"):
        clustered_wilson_interval([4], [3])


def _ratio_variance(y: np.ndarray, n: np.ndarray) -> float:
    """The textbook ratio estimator's variance of a pooled rate over clusters (Cochran 6.9:
    (1 - f) / (m n̄²) · Σ (y_i - p n_i)² / (m - 1), no finite-population correction)."""
    m, p = len(y), y.sum() / n.sum()
    return float(np.sum((y - p * n) ** 2) / (m - 1) / (m * n.mean() ** 2))


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(1, 6), st.integers(0, 6)).map(lambda t: (min(t[1], t[0]), t[0])),
        min_size=2,
        max_size=8,
    )
)
def test_clustered_wilson_uses_the_ratio_estimators_design_effect(runs) -> None:
    y = np.array([s for s, _ in runs], np.float64)
    n = np.array([t for _, t in runs], np.float64)
    p = y.sum() / n.sum()
    low, high, n_eff = clustered_wilson_interval(y.astype(int).tolist(), n.astype(int).tolist())
    assert len(runs) <= n_eff <= n.sum()
    assert 0.0 <= low <= p <= high <= 1.0
    if 0 < p < 1:
        variance = _ratio_variance(y, n)
        if variance > 0:
            expected = min(max(p * (1 - p) / variance, len(runs)), n.sum())
            assert n_eff == pytest.approx(expected, rel=1e-9)
    assert (low, high) == pytest.approx(
        stats_wilson(p, n_eff), abs=1e-12
    )  # Wilson at the effective sample size


def stats_wilson(p: float, n: float) -> tuple[float, float]:
    """Wilson's score interval written from its quadratic (not the library's closed form)."""
    z2 = 1.959963984540054**2
    a, b, c = 1 + z2 / n, -(2 * p + z2 / n), p * p
    disc = math.sqrt(max(b * b - 4 * a * c, 0.0))
    return max(0.0, (-b - disc) / (2 * a)), min(1.0, (-b + disc) / (2 * a))


def test_mean_interval_is_student_t() -> None:
    mean, low, high = mean_interval([10.0, 11.0, 12.0])
    half = stats.t.ppf(0.975, 2) * 1.0 / math.sqrt(3)
    assert (mean, low, high) == pytest.approx((11.0, 11.0 - half, 11.0 + half))
    assert mean_interval([4.0]) == (4.0, 4.0, 4.0)
    assert mean_interval([0.0, 0.0, 3.0])[1] == 0.0  # a count's interval stays >= 0


def _run(steps: float, converged: int, recoveries: list[float], quick: int, **extra) -> dict:
    run = {"steps_to_converge": steps, "converged": converged, "kidnaps": len(recoveries)}
    run |= {f"recovery_steps_{k}": v for k, v in enumerate(recoveries, 1)}
    run |= {"recovered": len(recoveries), "kidnaps_recovered_frac": quick / len(recoveries)}
    return run | {"recovery_steps_max": max(recoveries), "relosses": 0} | extra


def test_over_seeds_pools_kidnaps_and_keeps_per_seed_values() -> None:
    runs = [
        _run(3, 1, [2, 5, 9], 3, false_convergences=0),
        _run(25, 1, [1, 30, 4], 2, relosses=2, false_convergences=1),
        _run(40, 0, [40, 40, 40], 0, recovered=0, false_convergences=0),
    ]
    fig = over_seeds(runs, converge_within=20)
    assert fig["n_seeds"] == 3 and fig["n_kidnaps"] == 9
    assert fig["convergence_success"] == pytest.approx(1 / 3)  # 25 and 40 are too slow
    low, high = wilson_interval(1, 3)
    assert (fig["convergence_success_ci95_low"], fig["convergence_success_ci95_high"]) == (
        low,
        high,
    )
    assert fig["kidnaps_recovered_frac"] == pytest.approx(5 / 9)
    assert fig["converged"] == pytest.approx(2 / 3) and fig["recovered_total"] == 6
    # 3, 2 and 0 of 3 per run: the interval counts the 3 runs, not the 9 kidnaps
    assert fig["n_runs_kidnapped"] == 3
    low, high, n_eff = clustered_wilson_interval([3, 2, 0], [3, 3, 3])
    assert (fig["kidnaps_recovered_frac_ci95_low"], fig["kidnaps_recovered_frac_ci95_high"]) == (
        low,
        high,
    )
    assert fig["kidnaps_recovered_frac_effective_n"] == n_eff and 3 <= n_eff < 9
    assert low < wilson_interval(5, 9)[0] and high > wilson_interval(5, 9)[1]
    assert (fig["steps_to_converge_median"], fig["steps_to_converge_max"]) == (25, 40)
    assert fig["steps_to_converge"] == pytest.approx(68 / 3)
    assert (fig["recovery_steps_median"], fig["recovery_steps_max"]) == (9, 40)
    assert fig["relosses"] == pytest.approx(2 / 3) and fig["relosses_total"] == 2
    assert fig["false_convergences_total"] == 1
    assert fig["seeds"]["1"]["relosses"] == 2 and fig["seeds"]["2"]["convergence_success"] == 0


def test_false_convergences_need_every_run_to_have_a_covariance() -> None:
    runs = [_run(3, 1, [2, 5, 9], 3, false_convergences=0), _run(3, 1, [2, 5, 9], 3)]
    assert "false_convergences" not in over_seeds(runs, converge_within=20)


def test_global_localization_groups_each_maps_evaluation_runs() -> None:
    good, bad = _run(0, 1, [1, 1, 1], 3), _run(50, 0, [50, 50, 50], 0)
    localization = {
        "room_kidnap": {"hybrid": good, "amcl_global": bad},
        "room_kidnap_s1": {"hybrid": good, "amcl_global": bad},
        "room_tune_kidnap": {"hybrid": bad},  # not in the evaluation set: never scored
    }
    figures = global_localization(localization, {"room": ["room_kidnap", "room_kidnap_s1"]}, 20)
    assert figures["room"]["hybrid"]["convergence_success"] == 1.0
    assert figures["room"]["hybrid"]["n_seeds"] == 2 and figures["room"]["hybrid"]["n_kidnaps"] == 6
    assert figures["room"]["amcl_global"]["kidnaps_recovered_frac"] == 0.0
    with pytest.raises(ValueError, match="room_kidnap_s2"):
        global_localization(localization, {"room": ["room_kidnap", "room_kidnap_s2"]}, 20)


def test_resolvable_rates_leave_out_the_ambiguous_stretches() -> None:
    runs = [
        _run(3, 1, [2, 5, 30], 2),  # start resolvable and quick; kidnap 3 (30 steps) ambiguous
        _run(25, 1, [1, 30, 4], 2),  # start ambiguous (and slow); kidnap 2 (30 steps) resolvable
    ]
    flags = [[False, False, False, True], [True, False, False, False]]
    fig = over_seeds(runs, converge_within=20, ambiguous=flags)
    assert (fig["n_starts_ambiguous"], fig["n_starts_resolvable"]) == (1, 1)
    assert (fig["n_kidnaps_ambiguous"], fig["n_kidnaps_resolvable"]) == (1, 5)
    assert fig["convergence_success_resolvable"] == 1.0
    assert fig["kidnaps_recovered_frac_resolvable"] == pytest.approx(4 / 5)
    low, high = wilson_interval(4, 5)
    assert fig["kidnaps_recovered_frac_resolvable_ci95_low"] == low
    assert fig["kidnaps_recovered_frac_resolvable_ci95_high"] == high
    assert fig["kidnaps_recovered_frac"] == pytest.approx(4 / 6)  # all kidnaps: unchanged
    every = over_seeds(runs, converge_within=20, ambiguous=[[True] * 4, [True] * 4])
    assert every["n_kidnaps_resolvable"] == 0 and "kidnaps_recovered_frac_resolvable" not in every
    with pytest.raises(ValueError, match="3 look-alike flags"):
        over_seeds(runs, converge_within=20, ambiguous=[[False] * 3, [False] * 4])
    with pytest.raises(ValueError, match="1 look-alike lists for 2 runs"):
        over_seeds(runs, converge_within=20, ambiguous=[[False] * 4])


def test_global_localization_scores_resolvable_stretches_only_with_every_runs_flags() -> None:
    good = _run(0, 1, [1, 1, 1], 3)
    localization = {"room_kidnap": {"hybrid": good}, "room_kidnap_s1": {"hybrid": good}}
    sets = {"room": ["room_kidnap", "room_kidnap_s1"]}
    flags = {"room_kidnap": [False, True, False, False], "room_kidnap_s1": [False] * 4}
    figures = global_localization(localization, sets, 20, flags)
    assert figures["room"]["hybrid"]["n_kidnaps_resolvable"] == 5
    partial = global_localization(localization, sets, 20, {"room_kidnap": flags["room_kidnap"]})
    assert "n_kidnaps_resolvable" not in partial["room"]["hybrid"]
