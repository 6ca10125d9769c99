"""Range noise models for simulated laser scans.

The default follows the Hokuyo URG-04LX-UG01 datasheet: accuracy ±30 mm for 0.06–1 m and
±3 % of the reading for 1–4.095 m. The datasheet does not say what "±" bounds; we read it as
one standard deviation of a zero-mean Gaussian, the noisier of the two usual readings (as a
3-sigma bound it would mean 10 mm), so that learned localizers are not trained on scans
cleaner than the sensor's specification promises. Below 1 m sigma stays 30 mm, beyond
4.095 m it stays 3 %. STDR itself adds no noise (its noise settings are parsed but never
used): the `none` model reproduces that.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

NOISE_KINDS = ("none", "ug01")


@dataclass(frozen=True)
class NoNoise:
    """Ranges pass through unchanged (STDR's behaviour)."""

    kind: str = "none"

    def apply(self, ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Return a float64 copy of `ranges`; `rng` is not used."""
        return np.array(ranges, dtype=np.float64)


@dataclass(frozen=True)
class RangeGaussianNoise:
    """Zero-mean Gaussian range error, sigma = near_sigma_m below knee_m, relative_sigma x range
    from there on (continuous at 1 m with the UG01 defaults)."""

    near_sigma_m: float = 0.03
    knee_m: float = 1.0
    relative_sigma: float = 0.03
    kind: str = "ug01"

    def __post_init__(self) -> None:
        for field in _UG01_FIELDS:
            value = getattr(self, field)
            if not (isinstance(value, int | float) and np.isfinite(value) and value >= 0):
                raise ValueError(
                    f"noise field '{field}': expected a finite number >= 0, got {value!r}"
                )

    def sigma(self, ranges: np.ndarray) -> np.ndarray:
        """Standard deviation (m) at each true range."""
        ranges = np.asarray(ranges, dtype=np.float64)
        return np.where(ranges < self.knee_m, self.near_sigma_m, self.relative_sigma * ranges)

    def apply(self, ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy float64 copy of `ranges`; non-finite entries (no hit) stay as they are.

        One normal is drawn per entry, finite or not, so the stream position of each beam
        does not depend on which other beams hit something.
        """
        ranges = np.asarray(ranges, dtype=np.float64)
        z = rng.standard_normal(ranges.shape)
        finite = np.isfinite(ranges)
        sigma = self.sigma(np.where(finite, ranges, 0.0))
        return np.where(finite, ranges + sigma * z, ranges)


NoiseModel = NoNoise | RangeGaussianNoise
_UG01_FIELDS = tuple(f.name for f in fields(RangeGaussianNoise) if f.name != "kind")


def noise_from_config(cfg: Mapping[str, Any]) -> NoiseModel:
    """Build a noise model from a config mapping (conf/noise/*.yaml): `kind` plus its fields."""
    if not isinstance(cfg, Mapping):
        raise ValueError(f"noise config must be a mapping, got {type(cfg).__name__}")
    kind = cfg.get("kind")
    values = {k: v for k, v in cfg.items() if k != "kind"}
    if kind == "none":
        if values:
            raise ValueError(f"noise kind 'none' takes no fields, got {sorted(values)}")
        return NoNoise()
    if kind == "ug01":
        unknown = sorted(set(values) - set(_UG01_FIELDS))
        if unknown:
            raise ValueError(
                f"noise kind 'ug01': unknown field(s) {unknown}; expected some of "
                f"{sorted(_UG01_FIELDS)}"
            )
        return RangeGaussianNoise(**values)
    raise ValueError(f"noise field 'kind': expected one of {NOISE_KINDS}, got {kind!r}")
