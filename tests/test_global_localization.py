"""Figures over seeds: the Wilson interval and the per-map, per-localizer aggregate."""

from __future__ import annotations

import math

import pytest
from scipy import stats

from scanloc.evaluate.seeds import global_localization, mean_interval, over_seeds, wilson_interval


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
    assert fig["kidnaps_recovered_frac_ci95_low"] == wilson_interval(5, 9)[0]
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
