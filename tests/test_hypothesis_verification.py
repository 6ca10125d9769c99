"""Verified hypotheses (scanloc.localize.hypothesis_verification, score_calibration) and the
calibration error (scanloc.evaluate.metrics): refinement pulls a perturbed pose back onto the
map, a look-alike elsewhere scores lower, the calibration recovers a known logistic law, and
the expected calibration error matches its definition."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanloc.estimates import estimate_table
from scanloc.evaluate.metrics import expected_calibration_error, reliability_bins
from scanloc.evaluate.table2 import evaluate_all
from scanloc.localize.hypothesis_verification import (
    HypothesisVerifier,
    VerifierParams,
    inlier_margins,
    merge_duplicates,
)
from scanloc.localize.kinds import LocalizeInputs, learned_hypotheses
from scanloc.localize.score_calibration import ScoreCalibration
from scanloc.pose import wrap_angle
from scanloc.scanlocnet.model import Hypotheses
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.trajectory.format import Trajectory
from small_world import SPEC, ug01_scans

TRUTH = np.array([[3.0, 2.2, 0.4]])


@pytest.fixture(scope="module")
def verifier(room) -> HypothesisVerifier:
    return HypothesisVerifier(room, SPEC, VerifierParams())


@pytest.fixture(scope="module")
def scan(room) -> np.ndarray:
    return ug01_scans(room, TRUTH, seed=3)[0]


def _hypotheses(poses: list[list[float]]) -> Hypotheses:
    k = len(poses)
    weights = np.linspace(0.5, 0.1, k)[None]
    return Hypotheses(np.array([poses], float), weights, np.full((1, k, 3), 0.1))


OFFSETS = [(0.3, -0.2, 6.0), (-0.25, 0.25, -8.0), (0.0, 0.35, 3.0)]


@pytest.mark.parametrize("offset", OFFSETS)
def test_refinement_moves_a_perturbed_hypothesis_back_to_the_truth(verifier, scan, offset) -> None:
    """On a noisy scan (1σ 3 % of the range beyond 1 m: 9 cm at 3 m) to within a few cm (beams
    that overshoot through the room's 10 cm walls bias it slightly)."""
    start = TRUTH + np.array([[offset[0], offset[1], math.radians(offset[2])]])
    refined, features = verifier.features(scan, start, np.array([0.5]))
    assert np.hypot(*(refined[0, :2] - TRUTH[0, :2])) < 0.05
    assert abs(math.degrees(wrap_angle(refined[0, 2] - TRUTH[0, 2]))) < 1.0
    assert features[0, 0] > 0.8  # most beams end on the map at the refined pose


@pytest.mark.parametrize("offset", OFFSETS)
def test_refinement_on_an_exact_scan_lands_on_the_truth(room, verifier, offset) -> None:
    exact = cast_exact(CastMap.from_grid(room), TRUTH, SPEC.beam_angles(), SPEC.range_max)[0]
    scan = np.where(np.isfinite(exact), exact, SPEC.no_return_value)
    start = TRUTH + np.array([[offset[0], offset[1], math.radians(offset[2])]])
    refined, features = verifier.features(scan, start, np.array([0.5]))
    assert np.hypot(*(refined[0, :2] - TRUTH[0, :2])) < 0.005
    assert abs(math.degrees(wrap_angle(refined[0, 2] - TRUTH[0, 2]))) < 0.1
    assert features[0, 0] > 0.99


def test_a_pose_elsewhere_explains_fewer_beams_than_the_truth(verifier, scan) -> None:
    poses = np.vstack([TRUTH, [[1.0, 1.0, 2.0]], [[4.8, 4.0, -1.0]]])
    _, features = verifier.features(scan, poses, np.full(3, 0.3))
    assert features[0, 0] > 0.8
    assert features[1:, 0].max() < features[0, 0] - 0.3
    assert features[1:, 1].min() > features[0, 1]  # and they lie farther from the map


def test_verification_re_ranks_the_truth_to_the_top_and_merges_duplicates(verifier, scan) -> None:
    near = TRUTH[0] + [0.2, 0.1, 0.05]
    also_near = TRUTH[0] + [-0.15, 0.2, -0.05]
    hyp = _hypotheses([[1.0, 1.0, 2.0], [4.8, 4.0, -1.0], list(near), list(also_near)])
    out = verifier.verify(scan, hyp)
    assert np.hypot(*(out.poses[0, 0, :2] - TRUTH[0, :2])) < 0.05
    assert out.scores is not None and out.scores[0, 0] == out.scores[0].max()
    assert (out.weights[0] > 0).sum() == 3  # the two near ones refined onto one pose
    assert np.all(np.diff(out.scores[0, :3]) <= 0)
    assert out.poses.shape == hyp.poses.shape and out.scores[0, 3] == 0.0


def test_a_scan_without_returns_explains_nothing(verifier) -> None:
    empty = np.full(SPEC.num_beams, SPEC.no_return_value)
    _, features = verifier.features(empty, TRUTH, np.array([0.5]))
    assert features[0, 0] == 0.0 and features[0, 1] == 1.0


def test_merge_keeps_the_best_of_each_cluster() -> None:
    poses = np.array([[0, 0, 0], [0.1, 0, 0.02], [2, 0, 0], [0.05, 0, 1.0]], float)
    kept = merge_duplicates(poses, np.array([0.2, 0.9, 0.5, 0.1]), 0.25, math.radians(5))
    assert kept.tolist() == [1, 2, 3]


def test_the_margin_is_to_the_best_hypothesis_elsewhere() -> None:
    poses = np.array([[0, 0, 0], [0.1, 0, 0], [3, 0, 0]], float)  # the first two: one pose
    margins = inlier_margins(np.array([0.9, 0.8, 0.6]), poses, VerifierParams())
    assert margins == pytest.approx([0.3, 0.2, -0.3])
    assert inlier_margins(np.array([0.7]), poses[:1], VerifierParams()) == pytest.approx([0.7])


def test_unknown_verifier_keys_are_named(monkeypatch) -> None:
    """The `verifier` section of a verified localizer: an unknown key names the file, the
    section and the key; a value the verifier cannot work with is refused."""
    import scanloc.localize.kinds as kinds

    monkeypatch.setattr(kinds, "scan_hypotheses", lambda *a, **k: (None, lambda s: None, 0.0))
    traj = Trajectory(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)))
    inputs = LocalizeInputs(traj, np.zeros((1, SPEC.num_beams)), Path("unused.yaml"), SPEC)
    cfg = verified_config("mine", verifier={"iteration": 3})
    with pytest.raises(
        ValueError, match=r"mine\.yaml: section 'verifier': unknown key 'iteration'"
    ):
        learned_hypotheses(cfg, inputs)
    with pytest.raises(ValueError, match=r"mine\.yaml: section 'verifier': need iterations >= 0"):
        learned_hypotheses(verified_config("mine", verifier={"match_beams": 2}), inputs)
    with pytest.raises(ValueError, match="distances must be > 0"):
        VerifierParams(huber=0.0)


def test_calibration_recovers_a_known_logistic_law() -> None:
    rng = np.random.default_rng(0)
    features = rng.normal(size=(20000, 2))
    true_p = 1 / (1 + np.exp(-(0.5 + 2.0 * features[:, 0] - 1.0 * features[:, 1])))
    hits = rng.random(20000) < true_p
    calibration = ScoreCalibration.fit(features, hits, ridge=1e-6)
    assert np.abs(calibration.probability(features) - true_p).max() < 0.03
    again = ScoreCalibration.from_dict(calibration.to_dict())
    assert np.array_equal(again.probability(features), calibration.probability(features))
    assert expected_calibration_error(calibration.probability(features), hits) < 0.02


def test_calibration_stays_finite_on_separable_data() -> None:
    features = np.array([[0.0], [0.1], [0.9], [1.0]])
    calibration = ScoreCalibration.fit(features, np.array([False, False, True, True]))
    p = calibration.probability(features)
    assert np.all(np.isfinite(calibration.coefficients)) and p[0] < 0.5 < p[3]


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0, 1), st.booleans()), min_size=1, max_size=60),
    st.integers(1, 12),
)
def test_ece_matches_its_definition(pairs, bins) -> None:
    scores = np.array([p for p, _ in pairs])
    hits = np.array([h for _, h in pairs])
    total = 0.0
    for b in range(bins):  # the definition, one bin at a time ([b/bins, (b+1)/bins), last closed)
        upper = (b + 1) / bins
        inside = (scores >= b / bins) & ((scores < upper) | ((b == bins - 1) & (scores <= 1)))
        inside &= np.minimum((scores * bins).astype(int), bins - 1) == b  # float edge cases
        if inside.any():
            total += inside.sum() * abs(hits[inside].mean() - scores[inside].mean())
    assert expected_calibration_error(scores, hits, bins) == pytest.approx(total / len(pairs))
    count, _, _ = reliability_bins(scores, hits, bins)
    assert count.sum() == len(pairs)


def test_ece_of_an_overconfident_score_is_its_gap() -> None:
    assert expected_calibration_error(np.full(10, 0.9), np.arange(10) < 5) == pytest.approx(0.4)


def test_evaluation_scores_the_top1_calibration_of_verified_hypotheses() -> None:
    truth = np.zeros((4, 3))
    poses = np.zeros((4, 2, 3))
    poses[2:, 0, 0] = 3.0  # the last two top-1s are wrong
    scores = np.array([[1.0, 0.1], [1.0, 0.1], [0.0, 0.1], [0.5, 0.1]])
    table = estimate_table(np.arange(4), np.arange(4.0), poses[:, 0], np.zeros((4, 3, 3)), 2)
    metrics = evaluate_all(truth, {"v": table}, hypotheses={"v": poses}, scores={"v": scores})
    assert metrics["v"]["top1_recall"] == 0.5
    assert metrics["v"]["calibration_ece"] == pytest.approx(0.5 / 4)  # only the 0.5 bin is off


@pytest.mark.slow
def test_the_learned_localizer_benchmark_reports_every_part(quick_benchmark) -> None:
    figures = quick_benchmark("learned_localizer.py")
    assert {"scanlocnet", "cnn1d"} <= figures.keys()
    maps = figures["scaling"]["maps"]
    assert [m["cells"] for m in maps] == sorted(m["cells"] for m in maps) and len(maps) == 2
    # Measured growths are reported, not judged here: their sign is a timing, which a loaded
    # machine (the smoke repro beside this test in `make test-all`) can flip.
    for measured in ("decode_ms_growth", "train_steps_s_growth"):
        assert math.isfinite(figures["scaling"][measured]["per_cell"]), measured
    # the larger map trains more epochs (its floor of scans per cell), so longer in all
    assert maps[1]["epochs"] > maps[0]["epochs"]
    assert figures["scaling"]["budget_estimate_s_growth"]["per_cell"] > 0  # a model, not a clock
    assert figures["inference"]["verification_ms"] > 0
    assert figures["inference"]["total_ms"] >= figures["inference"]["hypotheses_ms"]


def test_calibration_without_a_single_right_hypothesis_is_a_small_constant() -> None:
    calibration = ScoreCalibration.fit(np.random.default_rng(0).normal(size=(99, 3)), np.zeros(99))
    assert np.allclose(calibration.probability(np.zeros((4, 3))), 0.5 / 100)


def verified_config(name: str, verifier: dict | None = None, **learned: object) -> dict:
    """A verified learned localizer's config: its `learned` and `verifier` sections."""
    return {
        "meta": {"name": name},
        "learned": {
            "model": "m.pt",
            "verified": True,
            "calibration_scans": "val",
            "calibration_count": 5,
            "k": 20,
            **learned,
        },
        "verifier": verifier or {"iterations": 3},
    }


def test_a_verified_config_without_calibration_scans_names_the_key() -> None:
    traj = Trajectory(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)))
    inputs = LocalizeInputs(traj, np.zeros((1, SPEC.num_beams)), Path("unused.yaml"), SPEC)
    cfg = verified_config("mine", model="missing.pt")
    del cfg["learned"]["calibration_scans"]
    with pytest.raises(
        ValueError, match=r"mine\.yaml: section 'learned': key 'calibration_scans': expected"
    ):
        learned_hypotheses(cfg, inputs)


def test_localizers_of_one_stage_share_a_calibration_fitted_once(monkeypatch) -> None:
    import scanloc.localize.kinds as kinds

    class Dataset:  # five validation scans with poses
        val_idx = np.arange(5)
        ranges = np.ones((5, SPEC.num_beams))
        poses = np.zeros((5, 3))

    fits: list[int] = []

    def fit(hypotheses_of, verifier, ranges, poses):
        fits.append(len(ranges))
        return ScoreCalibration.fit(np.zeros((2, 4)), np.array([0.0, 1.0])), {}

    monkeypatch.setattr(kinds, "scan_hypotheses", lambda *a, **k: (None, lambda s: None, 0.0))
    monkeypatch.setattr(kinds, "load_scan_dataset", lambda path: Dataset())
    monkeypatch.setattr(kinds, "fit_calibration", fit)
    monkeypatch.setattr(kinds, "HypothesisVerifier", lambda *a: SimpleNamespace(calibration=None))
    traj = Trajectory(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)))
    inputs = LocalizeInputs(traj, np.zeros((1, SPEC.num_beams)), Path("unused.yaml"), SPEC)
    inputs.__dict__["grid"] = None  # no map needed by the stand-in verifier
    for name in ("scanlocnet_verified", "hybrid_verified"):
        learned_hypotheses(verified_config(name), inputs)
    assert fits == [5]
    learned_hypotheses(verified_config("fewer", calibration_count=3), inputs)
    learned_hypotheses(verified_config("other_k", k=10), inputs)
    assert fits == [5, 3, 5]
    other_stage = LocalizeInputs(traj, np.zeros((1, SPEC.num_beams)), Path("unused.yaml"), SPEC)
    other_stage.__dict__["grid"] = None
    learned_hypotheses(verified_config("scanlocnet_verified"), other_stage)
    assert fits == [5, 3, 5, 5]
