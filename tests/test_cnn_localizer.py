"""Single-network and ensemble localizers: circular mean, covariance on the circle, table."""

from __future__ import annotations

import sys
import types
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanloc.estimates import TABLE_COLUMNS
from scanloc.localize import cnn_localizer
from scanloc.localize.cnn_localizer import ensemble_mean_and_cov, localize_cnn
from scanloc.pose import wrap_angle


def test_circular_mean_across_pi() -> None:
    preds = np.array([[[0.0, 0.0, np.pi - 0.1]], [[2.0, 4.0, -np.pi + 0.1]]])
    mean, cov = ensemble_mean_and_cov(preds)
    np.testing.assert_allclose(mean[0, :2], [1.0, 2.0])
    assert abs(wrap_angle(mean[0, 2] - np.pi)) < 1e-12  # not 0, as an arithmetic mean would say
    # Deviations wrapped around the circular mean: ±0.1 rad, not ±(π − 0.1).
    assert cov[0, 2, 2] == pytest.approx(2 * 0.1**2 / 1)
    assert cov[0, 0, 0] == pytest.approx(2.0) and cov[0, 1, 1] == pytest.approx(8.0)
    assert cov[0, 0, 2] == pytest.approx((-1) * (-0.1) + 1 * 0.1)  # x and θ grow together


def test_covariance_matches_numpy_away_from_the_wrap() -> None:
    rng = np.random.default_rng(0)
    preds = rng.normal([3.0, 1.0, 0.2], [0.3, 0.2, 0.1], size=(7, 5, 3))
    mean, cov = ensemble_mean_and_cov(preds)
    for t in range(5):
        dev = preds[:, t] - mean[t]  # no wrap needed this far from ±π
        np.testing.assert_allclose(cov[t], dev.T @ dev / 6, atol=1e-12)
        np.testing.assert_allclose(cov[t][:2, :2], np.cov(preds[:, t, :2].T), atol=1e-12)
        assert np.all(np.linalg.eigvalsh(cov[t]) > 0)


def test_single_member_has_no_covariance() -> None:
    preds = np.array([[[1.0, 2.0, 4.0]]])
    mean, cov = ensemble_mean_and_cov(preds)
    np.testing.assert_allclose(mean, [[1.0, 2.0, wrap_angle(4.0)]])
    assert np.isnan(cov).all()
    with pytest.raises(ValueError, match="shape"):
        ensemble_mean_and_cov(np.zeros((3, 4, 2)))


finite = st.floats(-10.0, 10.0, allow_nan=False)
# Headings within ±(π/2 − 0.1) of a common direction, plus whole turns: their mean resultant
# length is at least sin(0.1) ≈ 0.1, so the circular mean is well defined in every case.
spread = st.floats(-(np.pi / 2 - 0.1), np.pi / 2 - 0.1, allow_nan=False)
member = st.tuples(finite, finite, spread, st.integers(-2, 2))


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-np.pi, np.pi, allow_nan=False),
    st.lists(member, min_size=2, max_size=9),
    st.floats(-7.0, 7.0, allow_nan=False),
)
def test_rotating_all_headings_rotates_the_mean(centre: float, members: list, delta: float) -> None:
    preds = np.array(
        [(x, y, centre + offset + 2 * np.pi * turns) for x, y, offset, turns in members]
    )[:, None, :]
    mean, cov = ensemble_mean_and_cov(preds)
    # The circular mean lies inside the arc the headings span (an arithmetic mean of the raw,
    # unwrapped headings would not).
    offsets = np.array([m[2] for m in members])
    assert offsets.min() - 1e-9 <= wrap_angle(mean[0, 2] - centre) <= offsets.max() + 1e-9
    rotated = preds.copy()
    rotated[:, :, 2] += delta
    mean_r, cov_r = ensemble_mean_and_cov(rotated)
    assert abs(wrap_angle(mean_r[0, 2] - mean[0, 2] - delta)) < 1e-7
    np.testing.assert_allclose(mean_r[:, :2], mean[:, :2])
    np.testing.assert_allclose(cov_r, cov, atol=1e-7)
    assert -np.pi < mean_r[0, 2] <= np.pi


class _FakeModel:
    def __init__(self, offset: float) -> None:
        self.offset = offset


LOAD_S, PREDICT_S = 100.0, 0.5  # what loading and predicting take on the fake clock


def _fake_training(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A stand-in for scanloc.models.model_files: model k predicts (mean range + k, k, π − 0.1·k).

    The localizer's clock is faked too: loading a model takes LOAD_S, a predict call PREDICT_S."""
    batch_sizes: list[int] = []
    clock = [0.0]
    monkeypatch.setattr(cnn_localizer, "time", types.SimpleNamespace(perf_counter=lambda: clock[0]))

    def load_model(path: Path) -> _FakeModel:
        clock[0] += LOAD_S
        return _FakeModel(float(Path(path).stem.split("_")[-1]))

    def predict(model: _FakeModel, ranges: np.ndarray, batch_size: int) -> np.ndarray:
        clock[0] += PREDICT_S
        batch_sizes.append(batch_size)
        k = model.offset
        n = len(ranges)
        theta = np.full(n, np.pi - 0.1 * k if k % 2 == 0 else -np.pi + 0.1 * k)
        return np.stack([ranges.mean(axis=1) + k, np.full(n, k), theta], axis=1)

    module = types.ModuleType("scanloc.models.model_files")
    module.load_model, module.predict = load_model, predict
    monkeypatch.setitem(sys.modules, "scanloc.models.model_files", module)
    return batch_sizes


def test_localize_cnn_single_and_ensemble(tmp_path: Path, monkeypatch) -> None:
    batch_sizes = _fake_training(monkeypatch)
    paths = [tmp_path / f"member_{k}.pt" for k in range(3)]
    for path in paths:
        path.write_bytes(b"x")
    ranges = np.arange(12, dtype=np.float32).reshape(4, 3)
    times = np.arange(4) * 0.1

    single = localize_cnn(paths[:1], ranges, times)
    assert tuple(single.table.columns) == TABLE_COLUMNS
    np.testing.assert_allclose(single.table["x"], ranges.mean(axis=1))
    table = single.table
    assert table[["cov_xx", "cov_tt"]].isna().all().all() and (table["n_particles"] == 1).all()
    # Each scan alone, as on a robot: one predict call per scan and member; loading and the
    # warm-up inference are setup, not part of any scan's time.
    assert batch_sizes == [1] * 5
    np.testing.assert_allclose(single.scan_seconds, PREDICT_S)
    assert single.setup_s == pytest.approx(LOAD_S + PREDICT_S)
    assert single.timing()["time_per_scan_s"] == pytest.approx(PREDICT_S)

    run = localize_cnn(paths, ranges, times)
    np.testing.assert_allclose(run.scan_seconds, 3 * PREDICT_S)
    assert run.setup_s == pytest.approx(3 * (LOAD_S + PREDICT_S))
    ensemble = run.table
    np.testing.assert_allclose(ensemble["x"], ranges.mean(axis=1) + 1)
    np.testing.assert_allclose(ensemble["t"], times)
    assert (ensemble["n_particles"] == 3).all() and list(ensemble["step"]) == [0, 1, 2, 3]
    # Headings π, −π + 0.1, π − 0.2 average to about π − 0.033 on the circle.
    assert abs(wrap_angle(ensemble["theta"].iloc[0] - (np.pi - 0.1 / 3))) < 1e-3
    assert ensemble["cov_yy"].iloc[0] == pytest.approx(1.0)
    assert ensemble["cov_tt"].iloc[0] == pytest.approx((0.1**2 + 0.4**2 + 0.5**2) / 9 / 2, rel=0.01)


def test_localize_cnn_rejects_bad_input(tmp_path: Path, monkeypatch) -> None:
    _fake_training(monkeypatch)
    with pytest.raises(FileNotFoundError, match=r"nope\.pt"):
        localize_cnn([tmp_path / "nope.pt"], np.zeros((2, 3)), np.zeros(2))
    (tmp_path / "m_0.pt").write_bytes(b"x")
    with pytest.raises(ValueError, match="times"):
        localize_cnn([tmp_path / "m_0.pt"], np.zeros((2, 3)), np.zeros(3))
    with pytest.raises(ValueError, match="empty"):
        localize_cnn([], np.zeros((2, 3)), np.zeros(2))
