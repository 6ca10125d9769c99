"""The paper's findings (paper-spec §6, claims 1–7) checked against our numbers.

Each check is a pure function of the training runs, the localization metrics and the
thresholds in conf/report.yaml (`claims:`), with its rule written out, numbers included, beside
the verdict, so that a reader can redo it by hand. A claim has a direction (which model is
better, which epoch is slower) and, where the paper gives one, a size (a number):

- **reproduced**: the direction holds and every number the paper gives lies within the stated
  tolerance (a claim without a number is reproduced by its direction);
- **direction only**: the direction holds, a number the paper gives does not;
- **not reproduced**: the direction does not hold;
- **not testable**: an artifact or a metric the rule needs is missing (or not finite).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import pandas as pd

from scanloc.hardware import device_sentence

REPRODUCED, DIRECTION_ONLY, NOT_REPRODUCED, NOT_TESTABLE = (
    "reproduced",
    "direction only",
    "not reproduced",
    "not testable",
)
VERDICT_LEGEND: dict[str, str] = {
    REPRODUCED: "the direction holds and every number the paper gives lies within the stated "
    "tolerance (a claim without a number is reproduced by its direction)",
    DIRECTION_ONLY: "the direction holds, but a number the paper gives lies outside the tolerance",
    NOT_REPRODUCED: "the direction does not hold",
    NOT_TESTABLE: "an artifact or metric the rule needs is missing",
}

PAPER_CLAIMS: dict[int, str] = {
    1: "Both 1D CNNs clearly beat the MLP; the MLP's validation error stalls near 2.5 after "
    "about 50 epochs.",
    2: "The 1D CNNs beat the 2D CNN by at least 0.7 (training) and 0.5 (validation loss).",
    3: "The 2D CNN is much harder to train; one epoch took 60–100 s (20k samples).",
    4: "One 1D CNN epoch took about 5 s with 20k samples and 50–60 s with 200k samples.",
    5: "Ten times more data helps markedly: the 200k 1D CNN converges to a validation MAE of "
    "about 0.15 after 400 epochs, with a train/validation gap of 0.0131.",
    6: "Map 2: a 1D CNN learns it too, but to a worse loss than map 1; initialising from a 1D "
    "CNN pre-trained on map 1 makes training and validation loss fall faster, especially early.",
    7: "amcl is clearly best (mean position error about 0.075 m lower than the single CNN's); "
    "the ensemble of CNNs is more robust than one CNN and yields a covariance.",
}
PAPER_FIGURES: dict[int, str] = {
    1: "MLP val. MAE ≈ 2.5; 1D CNNs far lower",
    2: "Δtrain ≥ 0.7, Δval ≥ 0.5",
    3: "2D CNN 60–100 s/epoch vs 1D CNN ≈ 5 s (12–20× slower), GPU of 2017",
    4: "≈ 5 s (20k) and 50–60 s (200k) per epoch: 10–12× for 10× data",
    5: "val. MAE ≈ 0.15, gap 0.0131",
    6: "map 2 loss above map 1's; pre-trained curves below random-init ones early on",
    7: "Δ mean position error (single CNN − amcl) ≈ 0.075 m; Table 2 numbers lost",
}


@dataclass(frozen=True)
class Run:
    """One training run's artifacts: per-epoch history, final metrics and the config as run."""

    history: pd.DataFrame
    metrics: Mapping[str, Any]
    config: Mapping[str, Any]

    @property
    def val_mae(self) -> float:
        return _float(self.metrics.get("val_mae"))

    @property
    def train_mae(self) -> float:
        """Final epoch's training MAE."""
        return float(self.history["train_mae"].iloc[-1]) if len(self.history) else math.nan

    @property
    def epoch_s(self) -> float:
        return _float(self.metrics.get("epoch_s"))

    @property
    def samples(self) -> int:
        return int(self.config.get("samples", self.metrics.get("samples", 0)) or 0)

    @property
    def epochs(self) -> int:
        return len(self.history)

    def val_mae_at(self, epoch: int) -> float:
        """Validation MAE after `epoch` epochs (NaN if the run is shorter)."""
        rows = self.history[self.history["epoch"] == epoch]
        return float(rows["val_mae"].iloc[0]) if len(rows) else math.nan

    @property
    def device(self) -> str:
        return device_sentence(self.metrics.get("device"))


@dataclass(frozen=True)
class Claim:
    number: int
    paper: str
    paper_figure: str
    ours: str
    verdict: str
    rule: str


def _float(value: Any) -> float:
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return math.nan
    return float(value)


def verdict(direction: bool, sizes: list[bool]) -> str:
    """The verdict of a claim whose direction test gave `direction` and whose number tests
    (one per number the paper gives; none for a purely directional claim) gave `sizes`."""
    if not direction:
        return NOT_REPRODUCED
    return REPRODUCED if all(sizes) else DIRECTION_ONLY


def within(value: float, target: float, tolerance: float) -> bool:
    """|value − target| ≤ tolerance."""
    return abs(value - target) <= tolerance


def within_factor(value: float, lo: float, hi: float, factor: float) -> bool:
    """value in [lo / factor, hi · factor]: a range the paper gives, widened by a factor."""
    return lo / factor <= value <= hi * factor


class _Checker:
    """The claims as functions of the artifacts, thresholds from conf/report.yaml `claims:`."""

    def __init__(
        self,
        runs: Mapping[str, Run],
        metrics: Mapping[str, Mapping[str, Any]],
        thresholds: Mapping[str, Mapping[str, Any]],
    ) -> None:
        self.runs, self.metrics, self.thresholds = runs, metrics, thresholds

    def t(self, number: int) -> Mapping[str, Any]:
        key = f"claim{number}"
        if key not in self.thresholds:
            raise KeyError(f"conf/report.yaml: field 'claims.{key}': missing (verdict thresholds)")
        return self.thresholds[key]

    def claim(self, number: int, ours: str, result: str, rule: str) -> Claim:
        return Claim(number, PAPER_CLAIMS[number], PAPER_FIGURES[number], ours, result, rule)

    def untestable(self, number: int, what: list[str], rule: str) -> Claim:
        return self.claim(number, f"missing: {', '.join(what)}", NOT_TESTABLE, rule)

    def need_runs(self, names: tuple[str, ...]) -> list[str]:
        return [n for n in names if n not in self.runs]

    def claim_1(self) -> Claim:
        t = self.t(1)
        rule = (
            f"Direction: each 1D CNN's final validation MAE is at least {t['min_margin']} below "
            f"the MLP's ('clearly': {t['min_margin']} is about twice the seed-to-seed spread of "
            f"the difference, {t['margin_source']}). Number: the MLP's final validation MAE "
            f"within ±{t['mlp_tolerance']} of {t['mlp_val_mae']}."
        )
        if missing := self.need_runs(("mlp", "cnn1d_20k", "cnn1d_200k")):
            return self.untestable(1, missing, rule)
        mlp = self.runs["mlp"].val_mae
        cnns = [self.runs["cnn1d_20k"].val_mae, self.runs["cnn1d_200k"].val_mae]
        if not all(map(math.isfinite, [mlp, *cnns])):
            return self.untestable(1, ["a final val_mae"], rule)
        ours = (
            f"final val. MAE: MLP {mlp:.3f}, 1D CNN 20k {cnns[0]:.3f}, 1D CNN 200k {cnns[1]:.3f} "
            f"(margins {mlp - cnns[0]:.3f}, {mlp - cnns[1]:.3f})"
        )
        direction = all(mlp - c >= t["min_margin"] for c in cnns)
        size = within(mlp, t["mlp_val_mae"], t["mlp_tolerance"])
        return self.claim(1, ours, verdict(direction, [size]), rule)

    def claim_2(self) -> Claim:
        t = self.t(2)
        rule = (
            "Δ = 2D CNN − 1D CNN 20k (both on the same 20k-row data), final training and "
            "validation MAE. Direction: Δtrain > 0 and Δval > 0. Number: Δtrain ≥ "
            f"{t['min_train_gap']} and Δval ≥ {t['min_val_gap']} (the paper's 'at least')."
        )
        if missing := self.need_runs(("cnn2d", "cnn1d_20k")):
            return self.untestable(2, missing, rule)
        cnn2d, cnn1d = self.runs["cnn2d"], self.runs["cnn1d_20k"]
        d_train, d_val = cnn2d.train_mae - cnn1d.train_mae, cnn2d.val_mae - cnn1d.val_mae
        if not (math.isfinite(d_train) and math.isfinite(d_val)):
            return self.untestable(2, ["a final train_mae or val_mae"], rule)
        ours = f"Δtrain = {d_train:.3f}, Δval = {d_val:.3f} (2D CNN val. MAE {cnn2d.val_mae:.3f})"
        if cnn2d.epochs != cnn1d.epochs:
            ours += f"; after {cnn2d.epochs} vs {cnn1d.epochs} epochs (the profile's counts differ)"
        direction = d_train > 0 and d_val > 0
        sizes = [d_train >= t["min_train_gap"], d_val >= t["min_val_gap"]]
        return self.claim(2, ours, verdict(direction, sizes), rule)

    def claim_3(self) -> Claim:
        t = self.t(3)
        lo, hi = t["paper_ratio"]
        rule = (
            "r = 2D CNN's epoch time per sample / 1D CNN 20k's. Direction: r > 1 and the 2D CNN's "
            "validation MAE is higher than the 1D CNN's after the same number of epochs (the "
            f"2D CNN's). Number: r within the paper's {lo}–{hi}× widened by a factor "
            f"{t['ratio_factor']} (hardware differs: the paper's GPU of 2017, ours below)."
        )
        if missing := self.need_runs(("cnn2d", "cnn1d_20k")):
            return self.untestable(3, missing, rule)
        cnn2d, cnn1d = self.runs["cnn2d"], self.runs["cnn1d_20k"]
        ratio = (cnn2d.epoch_s / max(cnn2d.samples, 1)) / (cnn1d.epoch_s / max(cnn1d.samples, 1))
        epoch = cnn2d.epochs
        mae_2d, mae_1d = cnn2d.val_mae_at(epoch), cnn1d.val_mae_at(epoch)
        if not all(map(math.isfinite, (ratio, mae_2d, mae_1d))):
            return self.untestable(3, ["epoch_s, or a val_mae at the 2D CNN's last epoch"], rule)
        ours = (
            f"2D CNN {cnn2d.epoch_s:.3g} s/epoch ({cnn2d.samples} samples), 1D CNN "
            f"{cnn1d.epoch_s:.3g} s/epoch ({cnn1d.samples} samples): {ratio:.1f}× per sample; "
            f"val. MAE after {epoch} epochs 2D {mae_2d:.3f} vs 1D {mae_1d:.3f}; trained on "
            f"{cnn2d.device} (2D) and {cnn1d.device} (1D)"
        )
        direction = ratio > 1 and mae_2d > mae_1d
        size = within_factor(ratio, lo, hi, t["ratio_factor"])
        return self.claim(3, ours, verdict(direction, [size]), rule)

    def claim_4(self) -> Claim:
        t = self.t(4)
        lo, hi = t["paper_ratio"]
        rule = (
            "r = 1D CNN 200k's epoch time / 1D CNN 20k's, divided by their ratio of samples "
            f"(the paper: {lo}–{hi}× the time for 10× the data, i.e. {lo / 10:g}–{hi / 10:g} per "
            f"sample). Direction: the larger data set's epoch is longer. Number: r within "
            f"{lo / 10:g}–{hi / 10:g} widened by a factor {t['ratio_factor']}."
        )
        if missing := self.need_runs(("cnn1d_20k", "cnn1d_200k")):
            return self.untestable(4, missing, rule)
        small, large = self.runs["cnn1d_20k"], self.runs["cnn1d_200k"]
        per_sample = (large.epoch_s / max(large.samples, 1)) / (
            small.epoch_s / max(small.samples, 1)
        )
        if not math.isfinite(per_sample):
            return self.untestable(4, ["epoch_s"], rule)
        ours = (
            f"{small.epoch_s:.3g} s/epoch ({small.samples} samples, batch "
            f"{small.config.get('batch_size', '?')}) and {large.epoch_s:.3g} s/epoch "
            f"({large.samples} samples, batch {large.config.get('batch_size', '?')}): "
            f"per-sample ratio {per_sample:.2f}; trained on {small.device} and {large.device}"
        )
        direction = large.epoch_s > small.epoch_s and large.samples > small.samples
        size = within_factor(per_sample, lo / 10, hi / 10, t["ratio_factor"])
        return self.claim(4, ours, verdict(direction, [size]), rule)

    def claim_5(self) -> Claim:
        t = self.t(5)
        rule = (
            f"Direction ('markedly'): the 200k 1D CNN's final validation MAE is at least "
            f"{t['min_margin']} below the 20k one's. Numbers: its validation MAE within "
            f"±{t['val_tolerance']} of {t['val_mae']} and its |val − train| gap within "
            f"±{t['gap_tolerance']} of {t['gap']}."
        )
        if missing := self.need_runs(("cnn1d_20k", "cnn1d_200k")):
            return self.untestable(5, missing, rule)
        small, large = self.runs["cnn1d_20k"], self.runs["cnn1d_200k"]
        gap = abs(large.val_mae - large.train_mae)
        if not all(map(math.isfinite, (small.val_mae, large.val_mae, gap))):
            return self.untestable(5, ["a final val_mae or train_mae"], rule)
        ours = (
            f"val. MAE {large.val_mae:.3f} ({large.samples} samples, {large.epochs} epochs) vs "
            f"{small.val_mae:.3f} ({small.samples} samples, {small.epochs} epochs); gap {gap:.4f}"
        )
        direction = small.val_mae - large.val_mae >= t["min_margin"]
        sizes = [
            within(large.val_mae, t["val_mae"], t["val_tolerance"]),
            within(gap, t["gap"], t["gap_tolerance"]),
        ]
        return self.claim(5, ours, verdict(direction, sizes), rule)

    def claim_6(self) -> Claim:
        t = self.t(6)
        share = t["early_share"]
        rule = (
            f"Early = the first {share:g} of the epochs. Direction: the pre-trained run's mean "
            "training AND validation MAE over the early epochs are below the random-init run's, "
            "AND the random-init map-2 run ends with a higher validation MAE than the map-1 "
            "1D CNN 20k. The paper gives no number."
        )
        if missing := self.need_runs(("transfer/scratch", "transfer/pretrained", "cnn1d_20k")):
            return self.untestable(6, missing, rule)
        scratch, pre = self.runs["transfer/scratch"], self.runs["transfer/pretrained"]
        epochs = min(scratch.epochs, pre.epochs)
        early_epochs = max(1, math.floor(epochs * share))
        early = {
            col: (
                float(pre.history[col].iloc[:early_epochs].mean()),
                float(scratch.history[col].iloc[:early_epochs].mean()),
            )
            for col in ("train_mae", "val_mae")
        }
        map1 = self.runs["cnn1d_20k"].val_mae
        values = [v for pair in early.values() for v in pair] + [scratch.val_mae, map1]
        if not all(map(math.isfinite, values)):
            return self.untestable(6, ["a training history or final val_mae"], rule)
        ours = (
            f"first {early_epochs} epochs, pre-trained vs random init: train "
            f"{early['train_mae'][0]:.3f} vs {early['train_mae'][1]:.3f}, val. "
            f"{early['val_mae'][0]:.3f} vs {early['val_mae'][1]:.3f}; final val. MAE map 2 "
            f"(random init) {scratch.val_mae:.3f} vs map 1 (1D CNN 20k) {map1:.3f}"
        )
        faster = all(p < s for p, s in early.values())
        return self.claim(6, ours, verdict(faster and scratch.val_mae > map1, []), rule)

    def claim_7(self) -> Claim:
        t = self.t(7)
        rule = (
            "Direction: (a) amcl's mean position error is below both CNN localizers'; (b) the "
            "ensemble has no more gross failures (> 1 m) than the single CNN and a lower "
            "95th-percentile position error. Number: single CNN − amcl mean position error "
            f"within ±{t['delta_tolerance_m']} m of {t['delta_m']} m."
        )
        names = ("amcl", "cnn_single", "cnn_ensemble")
        if missing := [m for m in names if m not in self.metrics]:
            return self.untestable(7, missing, rule)

        def get(method: str, key: str) -> float:
            return _float(self.metrics[method].get(key))

        amcl, single, ens = (get(m, "pos_err_mean_m") for m in names)
        gross = (get("cnn_single", "frac_gross_over_1m"), get("cnn_ensemble", "frac_gross_over_1m"))
        p95 = (get("cnn_single", "pos_err_p95_m"), get("cnn_ensemble", "pos_err_p95_m"))
        if not all(map(math.isfinite, (amcl, single, ens, *gross, *p95))):
            return self.untestable(7, ["pos_err_mean_m, frac_gross_over_1m or pos_err_p95_m"], rule)
        calib = get("cnn_ensemble", "calib_within_2sigma")
        ours = (
            f"mean position error amcl {amcl:.3f} m, single {single:.3f} m, ensemble {ens:.3f} m "
            f"(single − amcl = {single - amcl:.3f} m); gross failures single {100 * gross[0]:.1f} "
            f"%, ensemble {100 * gross[1]:.1f} %; 95th pct. {p95[0]:.3f} vs {p95[1]:.3f} m"
        )
        if math.isfinite(calib):
            ours += f"; ensemble truth inside its 2σ ellipse {100 * calib:.1f} % of steps (86.5 %)"
        direction = amcl < single and amcl < ens and gross[1] <= gross[0] and p95[1] < p95[0]
        size = within(single - amcl, t["delta_m"], t["delta_tolerance_m"])
        return self.claim(7, ours, verdict(direction, [size]), rule)


CLAIM_NUMBERS = tuple(range(1, 8))


def check_claims(
    runs: Mapping[str, Run],
    metrics: Mapping[str, Mapping[str, Any]],
    thresholds: Mapping[str, Mapping[str, Any]],
) -> list[Claim]:
    """All seven claims, in order; `thresholds` is conf/report.yaml's `claims` node."""
    checker = _Checker(runs, metrics, thresholds)
    checks: list[Callable[[], Claim]] = [getattr(checker, f"claim_{n}") for n in CLAIM_NUMBERS]
    return [check() for check in checks]
