"""A calibrated probability from a verified hypothesis' scores: logistic regression (Platt
scaling with several features) onto "this hypothesis is within 0.5 m and 10° of the truth".

Fitted by Newton's method (iteratively reweighted least squares) on standardised features with
a small ridge penalty, so that separable data (a map where every verified hypothesis is either
clearly right or clearly wrong) still gives finite coefficients. Fitted on scans that are never
scored: the localizer fits it on its map's validation scans (learned_localizer.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class ScoreCalibration:
    """p = σ(intercept + coefficients · (features - mean) / scale)."""

    coefficients: tuple[float, ...]
    intercept: float
    mean: tuple[float, ...]
    scale: tuple[float, ...]

    def probability(self, features: np.ndarray) -> np.ndarray:
        z = (np.asarray(features, dtype=np.float64) - self.mean) / np.asarray(self.scale)
        logit = self.intercept + z @ np.asarray(self.coefficients)
        return 1.0 / (1.0 + np.exp(-np.clip(logit, -50.0, 50.0)))

    @classmethod
    def fit(
        cls, features: np.ndarray, hits: np.ndarray, ridge: float = 1e-2, iterations: int = 50
    ) -> ScoreCalibration:
        """The maximum a-posteriori logistic fit of `hits` (N,) bool on `features` (N, F)."""
        features = np.asarray(features, dtype=np.float64)
        hits = np.asarray(hits, dtype=np.float64)
        if features.ndim != 2 or len(features) != len(hits) or len(hits) < 2:
            raise ValueError(
                f"need features (N >= 2, F) and hits (N,), got {features.shape}, {hits.shape}"
            )
        mean = features.mean(axis=0)
        scale = features.std(axis=0)
        scale[scale == 0] = 1.0
        if hits.min() == hits.max():  # all right or all wrong: nothing to separate them by
            rate = (hits.sum() + 0.5) / (len(hits) + 1.0)  # Jeffreys-smoothed base rate
            zeros = tuple(0.0 for _ in mean)
            return cls(zeros, float(np.log(rate / (1 - rate))), tuple(mean.tolist()), tuple(scale))
        x = np.hstack([np.ones((len(hits), 1)), (features - mean) / scale])
        beta = np.zeros(x.shape[1])
        penalty = ridge * len(hits) * np.eye(x.shape[1])
        penalty[0, 0] = 0.0  # the intercept is not shrunk
        for _ in range(iterations):
            p = 1.0 / (1.0 + np.exp(-np.clip(x @ beta, -50.0, 50.0)))
            gradient = x.T @ (p - hits) + penalty @ beta
            hessian = (x * (p * (1 - p))[:, None]).T @ x + penalty + 1e-9 * np.eye(x.shape[1])
            step = np.linalg.solve(hessian, gradient)
            beta -= step
            if np.max(np.abs(step)) < 1e-10:
                break
        return cls(tuple(beta[1:].tolist()), float(beta[0]), tuple(mean.tolist()), tuple(scale))

    def to_dict(self) -> dict[str, Any]:
        return {
            "coefficients": list(self.coefficients),
            "intercept": self.intercept,
            "mean": list(self.mean),
            "scale": [float(s) for s in self.scale],
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> ScoreCalibration:
        return cls(
            tuple(float(v) for v in doc["coefficients"]),
            float(doc["intercept"]),
            tuple(float(v) for v in doc["mean"]),
            tuple(float(v) for v in doc["scale"]),
        )
