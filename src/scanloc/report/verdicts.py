"""The five verdicts of the paper's claims, their legend, and the rule that makes a verdict
"inconclusive" when another seed (or another machine) could flip it.

A claim has a direction (which model is better, which epoch is slower) and, where the paper
gives one, a size (a number). Each is tested by comparisons whose outcome is True, False or,
where a comparison of two training runs lies inside their seed-to-seed spread, None (cannot
tell). The spread is measured, per profile, in conf/report.yaml (`seed_spread`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

REPRODUCED, DIRECTION_ONLY, NOT_REPRODUCED, INCONCLUSIVE, NOT_TESTABLE = (
    "reproduced",
    "direction only",
    "not reproduced",
    "inconclusive",
    "not testable",
)
VERDICTS = (REPRODUCED, DIRECTION_ONLY, NOT_REPRODUCED, INCONCLUSIVE, NOT_TESTABLE)
# The table row class of each verdict (render/document.py's CSS colours them).
VERDICT_CLASSES = {
    REPRODUCED: "v-reproduced",
    DIRECTION_ONLY: "v-direction",
    NOT_REPRODUCED: "v-not",
    INCONCLUSIVE: "v-inconclusive",
    NOT_TESTABLE: "v-untestable",
}
Outcome = bool | None  # None: inside the seed spread, the comparison cannot tell


@dataclass(frozen=True)
class SeedSpread:
    """The measured seed-to-seed standard deviation `sd` of one training run's final MAE and
    the rule's width in standard deviations: a margin between two runs (standard deviation
    sd·√2) within `sigmas`·sd·√2 of its threshold is inside the spread."""

    sd: float
    sigmas: float
    source: str

    @property
    def band(self) -> float:
        return self.sigmas * self.sd * math.sqrt(2.0)


@dataclass(frozen=True)
class ClaimConfig:
    """conf/report.yaml as the claims read it: per-claim thresholds and, where the profile has
    a measured one, the seed spread (None: no claim can be inconclusive)."""

    thresholds: Mapping[str, Mapping[str, Any]]
    spread: SeedSpread | None
    profile: str

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], profile: str) -> ClaimConfig:
        """From the report config's `claims`, `seed_spread` and `inconclusive_sigmas`."""
        if "claims" not in cfg:
            raise KeyError("conf/report.yaml: field 'claims': missing (verdict thresholds)")
        measured = (cfg.get("seed_spread") or {}).get(profile)
        spread = None
        if measured is not None:
            where = f"conf/report.yaml: field 'seed_spread.{profile}"
            for key in ("val_mae_sd", "source"):
                if key not in measured:
                    raise KeyError(f"{where}.{key}': missing")
            sd = measured["val_mae_sd"]
            if isinstance(sd, bool) or not isinstance(sd, (int, float)) or not sd > 0:
                raise ValueError(f"{where}.val_mae_sd': expected a positive number, got {sd!r}")
            if "inconclusive_sigmas" not in cfg:
                raise KeyError("conf/report.yaml: field 'inconclusive_sigmas': missing")
            spread = SeedSpread(float(sd), float(cfg["inconclusive_sigmas"]), measured["source"])
        return cls(cfg["claims"], spread, profile)


def compare(value: float, threshold: float, spread: SeedSpread | None, strict: bool = False):
    """value ≥ threshold (> when `strict`) for a margin between two training runs; None when
    it lies inside the seed spread of the threshold."""
    holds = value > threshold if strict else value >= threshold
    if spread is not None and abs(value - threshold) < spread.band:
        return None
    return holds


def all_of(outcomes: Iterable[Outcome]) -> Outcome:
    """Three-valued AND: False if any is False, else None if any cannot tell, else True."""
    outcomes = list(outcomes)
    if any(o is False for o in outcomes):
        return False
    return None if any(o is None for o in outcomes) else True


def verdict(direction: Outcome, sizes: list[Outcome]) -> str:
    """The verdict of a claim whose direction test gave `direction` and whose number tests
    (one per number the paper gives; none for a purely directional claim) gave `sizes`."""
    if direction is False:
        return NOT_REPRODUCED
    size = all_of(sizes)
    if direction is None or size is None:
        return INCONCLUSIVE
    return REPRODUCED if size else DIRECTION_ONLY


def within(value: float, target: float, tolerance: float) -> bool:
    """|value − target| ≤ tolerance."""
    return abs(value - target) <= tolerance


def within_factor(value: float, lo: float, hi: float, factor: float) -> bool:
    """value in [lo / factor, hi · factor]: a range the paper gives, widened by a factor."""
    return lo / factor <= value <= hi * factor


def verdict_legend(config: ClaimConfig) -> dict[str, str]:
    """What each verdict means, in the report's words; the inconclusive entry states the
    measured spread and the rule's numbers (or that this profile has none)."""
    if config.spread is None:
        rule = (
            "|margin − threshold| < k · σ_seed · √2; no σ_seed is measured for profile "
            f"'{config.profile}' (conf/report.yaml `seed_spread`), so no claim is inconclusive here"
        )
    else:
        s = config.spread
        rule = (
            f"|margin − threshold| < {s.sigmas:g} · {s.sd:g} · √2 = {s.band:.2f}, {s.sd:g} being "
            f"the seed-to-seed standard deviation of one run's final MAE ({s.source}); another "
            "seed or machine could flip the verdict"
        )
    return {
        REPRODUCED: "the direction holds and every number the paper gives lies within the "
        "stated tolerance (a claim without a number is reproduced by its direction)",
        DIRECTION_ONLY: "the direction holds, but a number the paper gives lies outside the "
        "tolerance",
        NOT_REPRODUCED: "the direction does not hold",
        INCONCLUSIVE: "a margin between two training runs that the verdict rests on lies so "
        f"close to its threshold that it is inside their seed-to-seed spread: {rule}",
        NOT_TESTABLE: "an artifact or metric the rule needs is missing",
    }
