"""The five verdicts of the paper's claims, their legend, and the rule that makes a verdict
"inconclusive" when another seed (or another machine) could flip it.

A claim has a direction (which model is better, which epoch is slower) and, where the paper
gives one, a size (a number). Each is tested by comparisons (`Comparison`) whose outcome is
True, False or, where a margin between two training rows lies inside their seed-to-seed
spread, None (cannot tell). A row trained with several seeds (the profile's `seeds`) brings its
own spread, measured in the run; a row trained once falls back on the profile's configured s.d.
(conf/report.yaml `seed_spread`), and where there is none either, its comparisons are taken as
they are.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from scipy import stats

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
class Comparison:
    """One margin a verdict rests on: `value` (the difference of two rows' seed means, or a
    figure without a seed spread), the `threshold` it is tested against (value ≥ threshold, >
    when `strict`) and `band`: where |value − threshold| < band another seed or machine could
    flip it, and the comparison cannot tell. band None: no spread is known, the comparison is
    taken as it is. `spread` says where the band comes from."""

    label: str
    value: float
    threshold: float
    band: float | None = None
    strict: bool = False
    spread: str = ""

    @property
    def outcome(self) -> Outcome:
        if self.band is not None and abs(self.value - self.threshold) < self.band:
            return None
        return self.value > self.threshold if self.strict else self.value >= self.threshold

    @property
    def ratio(self) -> float:
        """|value − threshold| / band: ≥ 1 where the comparison decides (inf without a band)."""
        if self.band is None or self.band <= 0:
            return math.inf
        return abs(self.value - self.threshold) / self.band

    def text(self) -> str:
        """e.g. "MLP − 1D CNN 20k = 0.920 (≥ 0.4; band ±0.31: s.d. 0.150 over 3 seeds; …)"."""
        head = f"{self.label} = {self.value:.3f} ({'>' if self.strict else '≥'} {self.threshold:g}"
        if self.band is None:
            return head + "; no seed spread)"
        return head + f"; band ±{self.band:.2f}: {self.spread})"


@dataclass(frozen=True)
class RatioCheck:
    """A timing ratio (claims 3, 4) against the range [lo, hi] it is accepted in. Epoch times
    depend on the machine, not the seed: `machine` is the factor by which another CPU class
    may move the ratio (conf/report.yaml `timing_machine_factor`), so a ratio within that
    factor of a bound cannot tell (None: no such factor, the range alone decides)."""

    label: str
    value: float
    lo: float
    hi: float
    machine: float | None = None
    spread: str = ""

    @property
    def outcome(self) -> Outcome:
        if self.machine is not None and self.ratio < 1:
            return None
        return self.lo <= self.value <= self.hi

    @property
    def ratio(self) -> float:
        """The log distance to the nearer bound in units of log(machine): ≥ 1 decides."""
        if self.machine is None or self.machine <= 1 or not self.value > 0:
            return math.inf
        distance = min(abs(math.log(self.value / self.lo)), abs(math.log(self.value / self.hi)))
        return distance / math.log(self.machine)

    def text(self) -> str:
        head = f"{self.label} = {self.value:.3g} (accepted {self.lo:.3g}–{self.hi:.3g}"
        if self.machine is None:
            return head + ")"
        return head + f"; another machine may move it ×/÷ {self.machine:g}: {self.spread})"


@dataclass(frozen=True)
class ClaimConfig:
    """conf/report.yaml as the claims read it: per-claim thresholds, the band's width in
    standard deviations and, where the profile has one, the configured seed-to-seed s.d. of one
    run's final MAE that stands in for a row trained with a single seed (None: such a row has
    no spread and its comparisons are taken as they are)."""

    thresholds: Mapping[str, Mapping[str, Any]]
    sigmas: float
    fallback_sd: float | None
    fallback_source: str
    profile: str
    machine_factor: float | None = None
    machine_source: str = ""

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], profile: str) -> ClaimConfig:
        """From the report config's `claims`, `inconclusive_sigmas` and `seed_spread`."""
        if "claims" not in cfg:
            raise KeyError("conf/report.yaml: field 'claims': missing (verdict thresholds)")
        if "inconclusive_sigmas" not in cfg:
            raise KeyError("conf/report.yaml: field 'inconclusive_sigmas': missing")
        sigmas = _positive(cfg["inconclusive_sigmas"], "inconclusive_sigmas")
        configured = (cfg.get("seed_spread") or {}).get(profile)
        sd, source = None, ""
        if configured is not None:
            for key in ("val_mae_sd", "source"):
                if key not in configured:
                    raise KeyError(
                        f"conf/report.yaml: field 'seed_spread.{profile}.{key}': missing"
                    )
            sd = _positive(configured["val_mae_sd"], f"seed_spread.{profile}.val_mae_sd")
            source = str(configured["source"])
        machine, machine_source = None, ""
        if (timing := cfg.get("timing_machine_factor")) is not None:
            for key in ("factor", "source"):
                if key not in timing:
                    raise KeyError(
                        f"conf/report.yaml: field 'timing_machine_factor.{key}': missing"
                    )
            machine = _positive(timing["factor"], "timing_machine_factor.factor")
            if machine <= 1:
                raise ValueError(
                    "conf/report.yaml: field 'timing_machine_factor.factor': expected a factor "
                    f"above 1, got {machine!r}"
                )
            machine_source = str(timing["source"])
        return cls(cfg["claims"], sigmas, sd, source, profile, machine, machine_source)

    def ratio_check(
        self, label: str, value: float, lo: float, hi: float, on_cpu: bool = True
    ) -> RatioCheck:
        """`value` in [lo, hi], a timing ratio, with this config's cross-machine factor where
        the runs trained on CPUs (the factor was measured between CPU classes; on a GPU the
        range alone decides)."""
        machine = self.machine_factor if on_cpu else None
        return RatioCheck(label, value, lo, hi, machine, self.machine_source)

    def row_sd(self, values: Sequence[float]) -> tuple[float | None, int | None, str]:
        """A row's seed-to-seed s.d., the degrees of freedom of that estimate (None: a
        configured, not an estimated, s.d.) and where it comes from: measured over the row's
        seeds in this run (two or more), else the profile's configured one, else None."""
        finite = [v for v in values if math.isfinite(v)]
        if len(finite) >= 2:
            sd = statistics.stdev(finite)
            return sd, len(finite) - 1, f"s.d. {sd:.3f} over {len(finite)} seeds"
        if self.fallback_sd is None:
            return None, None, "one seed, no configured s.d."
        return self.fallback_sd, None, f"one seed, the configured s.d. {self.fallback_sd:g}"

    def between(
        self,
        label: str,
        a: Sequence[float],
        b: Sequence[float],
        threshold: float,
        strict: bool = False,
    ) -> Comparison:
        """mean(a) − mean(b) against `threshold`, a and b being two rows' per-seed values.

        band = k · sqrt(sd_a² + sd_b²): the spread of the difference of two single runs, wider
        than that of the means (by √n), so that the verdict is unlikely to flip with another
        draw of seeds, or on another machine whose precision moves a run by about a seed's
        spread (docs/benchmarks.md "Precision"). k is `sigmas` where both s.d. are configured;
        where one is estimated from a few seeds, k is the Student-t quantile of the same
        two-sided level with Welch's degrees of freedom (3 seeds estimate an s.d. poorly: with
        2 degrees of freedom k is about 4.5)."""
        value = statistics.fmean(a) - statistics.fmean(b) if a and b else math.nan
        (sd_a, dof_a, why_a), (sd_b, dof_b, why_b) = self.row_sd(a), self.row_sd(b)
        if sd_a is None or sd_b is None:
            return Comparison(label, value, threshold, None, strict, f"{why_a} and {why_b}")
        dof = welch_dof([(sd_a, dof_a), (sd_b, dof_b)])
        k = band_multiplier(self.sigmas, dof)
        if dof is not None:
            why = f"{why_a} and {why_b}; Student t {k:.2f} at {dof:.1f} degrees of freedom"
        else:
            why = f"{why_a} and {why_b}; {self.sigmas:g} σ"
        return Comparison(label, value, threshold, k * math.hypot(sd_a, sd_b), strict, why)


def band_multiplier(sigmas: float, dof: float | None) -> float:
    """k of a band k · √(sd₁² + sd₂²): `sigmas` where no s.d. is estimated (dof None), else the
    Student-t quantile of the same two-sided level at `dof` degrees of freedom."""
    return sigmas if dof is None else float(stats.t.ppf(stats.norm.cdf(sigmas), dof))


def welch_dof(parts: Sequence[tuple[float, int | None]]) -> float | None:
    """Welch–Satterthwaite degrees of freedom of a sum of variances sd², each estimated with
    `dof` degrees of freedom (None: known, infinitely many); None when none is estimated."""
    if all(dof is None for _, dof in parts):
        return None
    total = sum(sd**2 for sd, _ in parts)
    spread = sum(sd**4 / dof for sd, dof in parts if dof is not None)
    if spread <= 0:  # every estimated s.d. is 0: nothing left to be uncertain about
        return None
    return total**2 / spread


def _positive(value: Any, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise ValueError(
            f"conf/report.yaml: field '{field}': expected a positive number, got {value!r}"
        )
    return float(value)


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


def verdict_legend(config: ClaimConfig) -> dict[str, str]:
    """What each verdict means, in the report's words; the inconclusive entry states the rule's
    numbers and where the spread comes from."""
    fallback = (
        f"a row trained with one seed takes the configured s.d. {config.fallback_sd:g} "
        f"({config.fallback_source})"
        if config.fallback_sd is not None
        else f"a row trained with one seed has no spread at profile '{config.profile}' "
        "(conf/report.yaml `seed_spread`), and its comparisons are taken as they are"
    )
    rule = (
        "|margin − threshold| < k · √(sd₁² + sd₂²), the margin being the difference of the two "
        "rows' means over their seeds and sd₁, sd₂ their seed-to-seed standard deviations of "
        "one run, measured over the seeds trained in this run; k is the Student-t quantile "
        f"of the level of ±{config.sigmas:g} σ at Welch's degrees of freedom (a few seeds "
        f"estimate an s.d. poorly), {config.sigmas:g} where no s.d. is estimated; {fallback}. "
        "Inside that band another seed or machine could flip the verdict"
    )
    if config.machine_factor is not None:
        rule += (
            f". An epoch-time ratio (claims 3, 4) of runs trained on CPUs depends on the CPU "
            f"class, not the seed: one within ×/÷ {config.machine_factor:g} of a bound of its "
            f"range cannot tell ({config.machine_source})"
        )
    return {
        REPRODUCED: "the direction holds and every number the paper gives lies within the "
        "stated tolerance (a claim without a number is reproduced by its direction)",
        DIRECTION_ONLY: "the direction holds, but a number the paper gives lies outside the "
        "tolerance",
        NOT_REPRODUCED: "the direction does not hold",
        INCONCLUSIVE: "a margin between two training rows that the verdict rests on lies so "
        f"close to its threshold that it is inside their seed-to-seed spread: {rule}",
        NOT_TESTABLE: "an artifact or metric the rule needs is missing, or the profile trains "
        "the compared rows in other proportions than the paper did (the 'ours' column says "
        "which)",
    }
