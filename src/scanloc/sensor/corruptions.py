"""What a real laser does that a scan rendered in the map does not, measured and reproduced.

A real scan at a known pose differs from the scan the map predicts there in four ways, each
measured on real scans against the scans rendered at their poses (`measure_corruptions`):
- **no return**: the beam reports nothing (black or shiny surfaces, far walls at grazing
  angles) where the map has a wall, singly and in runs;
- **short**: the beam stops well before the mapped wall (> `OUTLIER_M` short): people,
  chairs, boxes; in runs of neighbouring beams, since an object has a width;
- **long**: the beam reads well past the mapped wall: glass, a door open since mapping;
- **range noise** on the other beams: heavy-tailed (Student's t), fitted to their residuals.

`LaserCorruptions.apply` reproduces them on noise-free ranges (+inf = no hit), so that the
learned localizer trains on scans that look like the real laser's (scanloc.scanlocnet.
scan_stream). Runs: their number per scan is Poisson with mean rate·beams / mean_run, their
lengths geometric with mean `mean_run`, their starts uniform, so that the share of beams
affected is close to `rate` (runs may overlap: slightly less). A short run reads one range,
a share of the true one drawn uniformly from [short_ratio_low, short_ratio_high] (an object's
face); a long beam reads its true range plus an exponential excess of mean `long_excess_m`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

OUTLIER_M = 0.3  # a reading this much shorter or longer than the map predicts is an outlier
KINDS = ("no_return", "short", "long")


@dataclass(frozen=True)
class RunRate:
    """A share of the beams (`rate`) affected in runs of `mean_run` beams on average."""

    rate: float = 0.0
    mean_run: float = 1.0


@dataclass(frozen=True)
class LaserCorruptions:
    """The four corruptions (module docstring); the defaults change nothing."""

    no_return: RunRate = RunRate()
    short: RunRate = RunRate()
    long: RunRate = RunRate()
    short_ratio_low: float = 0.1
    short_ratio_high: float = 0.9
    long_excess_m: float = 1.0
    noise_scale_m: float = 0.0  # Student-t scale of the other beams' range error; 0: none
    noise_dof: float = 5.0

    def __post_init__(self) -> None:
        for kind in KINDS:
            run = getattr(self, kind)
            if not (0.0 <= run.rate < 1.0 and run.mean_run >= 1.0):
                raise ValueError(
                    f"corruptions field '{kind}': expected 0 <= rate < 1 and mean_run >= 1, "
                    f"got {run}"
                )
        if not 0.0 <= self.short_ratio_low <= self.short_ratio_high <= 1.0:
            raise ValueError(
                "corruptions: expected 0 <= short_ratio_low <= short_ratio_high <= 1, got "
                f"{self.short_ratio_low}, {self.short_ratio_high}"
            )
        if self.long_excess_m < 0 or self.noise_scale_m < 0 or self.noise_dof <= 2:
            raise ValueError(
                "corruptions: expected long_excess_m >= 0, noise_scale_m >= 0 and noise_dof > 2, "
                f"got {self.long_excess_m}, {self.noise_scale_m}, {self.noise_dof}"
            )

    @property
    def adds_noise(self) -> bool:
        return self.noise_scale_m > 0

    def apply(self, ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Corrupted float64 copy of noise-free ranges (N, B) (+inf: no hit; -inf kept)."""
        out = np.array(ranges, dtype=np.float64)
        n, beams = out.shape
        hit = np.isfinite(out)
        if self.adds_noise:
            noise = self.noise_scale_m * rng.standard_t(self.noise_dof, size=out.shape)
            out = np.where(hit, out + noise, out)
        truth = np.array(ranges, dtype=np.float64)
        short = run_mask(n, beams, self.short, rng)
        ratio = rng.uniform(self.short_ratio_low, self.short_ratio_high, size=(n, beams))
        # one range per run (an object's face): the ratio and true range at the run's first
        # beam; a run starting on a beam without a hit leaves its beams alone (+inf)
        first = _run_starts(short)
        face = np.where(first, np.where(hit, ratio * truth, np.inf), np.nan)
        face = _fill_forward(face, short)
        out = np.where(short & hit, np.minimum(out, face), out)
        long = run_mask(n, beams, self.long, rng)
        excess = rng.exponential(self.long_excess_m, size=(n, beams)) if self.long_excess_m else 0
        out = np.where(long & hit & ~short, truth + excess, out)
        none = run_mask(n, beams, self.no_return, rng)
        return np.where(none, np.inf, out)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def corruptions_from_config(cfg: Mapping[str, Any] | None, source: str) -> LaserCorruptions:
    """LaserCorruptions from a mapping (a data/maps/<log>/corruptions.yaml or conf); `source`
    names it in errors. None or an empty mapping: no corruption."""
    if not cfg:
        return LaserCorruptions()
    known = {f.name for f in fields(LaserCorruptions)}
    values: dict[str, Any] = {}
    for key, value in cfg.items():
        if key not in known:
            raise ValueError(f"{source}: unknown field '{key}'; expected some of {sorted(known)}")
        if key in KINDS:
            if not isinstance(value, Mapping) or set(value) - {"rate", "mean_run"}:
                raise ValueError(
                    f"{source}: field '{key}': expected {{rate, mean_run}}, got {value}"
                )
            values[key] = RunRate(**{k: float(v) for k, v in value.items()})
        else:
            values[key] = float(value)
    try:
        return LaserCorruptions(**values)
    except ValueError as err:
        raise ValueError(f"{source}: {err}") from None


def run_mask(n: int, beams: int, runs: RunRate, rng: np.random.Generator) -> np.ndarray:
    """(n, beams) bool: runs of beams as RunRate describes (module docstring)."""
    mask = np.zeros((n, beams), dtype=bool)
    if runs.rate <= 0:
        return mask
    counts = rng.poisson(runs.rate * beams / runs.mean_run, size=n)
    total = int(counts.sum())
    rows = np.repeat(np.arange(n), counts)
    starts = rng.integers(0, beams, size=total)
    lengths = rng.geometric(1.0 / runs.mean_run, size=total)
    # mark [start, start + length) of each run through a difference array
    diff = np.zeros((n, beams + 1), dtype=np.int32)
    np.add.at(diff, (rows, starts), 1)
    np.add.at(diff, (rows, np.minimum(starts + lengths, beams)), -1)
    return np.cumsum(diff[:, :beams], axis=1) > 0


def _run_starts(mask: np.ndarray) -> np.ndarray:
    previous = np.zeros_like(mask)
    previous[:, 1:] = mask[:, :-1]
    return mask & ~previous


def _fill_forward(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Each masked entry takes the last non-NaN value at or before it in its row."""
    index = np.where(~np.isnan(values), np.arange(values.shape[1]), 0)
    np.maximum.accumulate(index, axis=1, out=index)
    filled = np.take_along_axis(values, index, axis=1)
    return np.where(mask, filled, np.nan)


def run_lengths(mask: np.ndarray) -> np.ndarray:
    """Lengths of the runs of True along each row of a (N, B) bool array."""
    padded = np.zeros((mask.shape[0], mask.shape[1] + 2), dtype=np.int8)
    padded[:, 1:-1] = mask
    edges = np.diff(padded, axis=1)
    starts = np.nonzero(edges == 1)
    ends = np.nonzero(edges == -1)
    return ends[1] - starts[1]


def measure_corruptions(
    real: np.ndarray, rendered: np.ndarray, range_max: float
) -> tuple[LaserCorruptions, dict[str, Any]]:
    """Fit LaserCorruptions to real readings (N, B) against the noise-free ranges rendered at
    their poses (N, B; +inf: no hit); also the measurement (counts, shares, residual quantiles).

    Only beams whose rendered range hits the map within range_max take part. A real reading at
    or above range_max (or non-finite) is a no return; one more than OUTLIER_M short is short,
    more than OUTLIER_M long is long; the rest are inliers, whose residuals fit the noise.
    """
    from scipy import stats

    real = np.asarray(real, dtype=np.float64)
    rendered = np.asarray(rendered, dtype=np.float64)
    if real.shape != rendered.shape or real.ndim != 2:
        raise ValueError(f"real {real.shape} and rendered {rendered.shape} must be alike (N, B)")
    mapped = np.isfinite(rendered) & (rendered < range_max)
    returned = np.isfinite(real) & (real < range_max) & (real > 0)
    residual = np.where(mapped & returned, real - rendered, np.nan)
    classes = {
        "no_return": mapped & ~returned,
        "short": mapped & returned & (residual < -OUTLIER_M),
        "long": mapped & returned & (residual > OUTLIER_M),
    }
    inlier = mapped & returned & (np.abs(residual) <= OUTLIER_M)
    beams = int(mapped.sum())
    if beams == 0 or inlier.sum() < 10:
        raise ValueError(f"too few beams to measure: {beams} mapped, {int(inlier.sum())} inliers")
    runs = {}
    for kind, mask in classes.items():
        lengths = run_lengths(mask & mapped)
        runs[kind] = RunRate(
            float(mask.sum() / beams), float(lengths.mean()) if len(lengths) else 1.0
        )
    ratios = (real / rendered)[classes["short"]]
    excess = residual[classes["long"]]
    dof, _, scale = stats.t.fit(residual[inlier], floc=0.0)
    fitted = LaserCorruptions(
        no_return=runs["no_return"],
        short=runs["short"],
        long=runs["long"],
        short_ratio_low=float(np.quantile(ratios, 0.05)) if len(ratios) else 0.1,
        short_ratio_high=float(np.quantile(ratios, 0.95)) if len(ratios) else 0.9,
        long_excess_m=float(excess.mean()) if len(excess) else 1.0,
        noise_scale_m=float(scale),
        noise_dof=float(max(dof, 2.5)),
    )
    fitted = _rounded(fitted)
    quantiles = np.quantile(np.abs(residual[inlier]), [0.5, 0.9])
    measured = {
        "scans": int(real.shape[0]),
        "mapped_beams": beams,
        "within_5cm": _sig(float((np.abs(residual[mapped & returned]) <= 0.05).sum() / beams)),
        "inlier_abs_residual_median_m": _sig(float(quantiles[0])),
        "inlier_abs_residual_p90_m": _sig(float(quantiles[1])),
    }
    return fitted, measured


def _sig(value: float, digits: int = 4) -> float:
    """`value` to `digits` significant digits: the fit's optimiser may differ in the last bits
    between CPUs, the written config must not."""
    return float(f"{value:.{digits}g}")


def _rounded(c: LaserCorruptions) -> LaserCorruptions:
    runs = {k: RunRate(_sig(getattr(c, k).rate), _sig(getattr(c, k).mean_run)) for k in KINDS}
    scalars = {
        f.name: _sig(getattr(c, f.name)) for f in fields(LaserCorruptions) if f.name not in KINDS
    }
    return LaserCorruptions(**runs, **scalars)
