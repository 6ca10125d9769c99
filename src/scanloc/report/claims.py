"""The paper's findings (paper-spec §6, claims 1–7) as rules checked against our numbers.

`CLAIMS` lists them once, in order: each `Claim` has the paper's words and figures and an
`evaluate` that is a pure function of the training runs, the paper drive's localization metrics
and conf/report.yaml (`claims:` thresholds, `seed_spread`), and that writes its rule out,
numbers included, beside the verdict so that a reader can redo it by hand. Verdicts and the
inconclusive rule: verdicts.py. Where a claim compares two training runs' MAE, each such
comparison uses the seed spread; epoch times (claims 3, 4) and localization errors (claim 7)
have no measured spread and are compared as they are.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from scanloc.report.artifacts import TrainingRun, as_float
from scanloc.report.verdicts import (
    INCONCLUSIVE,
    NOT_TESTABLE,
    ClaimConfig,
    SeedSpread,
    all_of,
    compare,
    verdict,
    within,
    within_factor,
)


class ClaimInputs(Protocol):
    """What the claims read (report/artifacts.py's Artifacts is one)."""

    @property
    def runs(self) -> Mapping[str, TrainingRun]: ...

    @property
    def paper_metrics(self) -> Mapping[str, Mapping[str, Any]]: ...


@dataclass(frozen=True)
class Verdict:
    """One claim checked: the paper's words and figures, what we measured, the verdict and the
    rule that gave it."""

    number: int
    paper: str
    paper_figure: str
    ours: str
    verdict: str
    rule: str


Check = Callable[["Claim", ClaimInputs, Mapping[str, Any], SeedSpread | None], Verdict]


@dataclass(frozen=True)
class Claim:
    """A finding of the paper and the rule that checks it (`check`, thresholds from
    conf/report.yaml `claims.claim<number>`)."""

    number: int
    text: str
    paper_figure: str
    check: Check

    def evaluate(self, inputs: ClaimInputs, config: ClaimConfig) -> Verdict:
        key = f"claim{self.number}"
        if key not in config.thresholds:
            raise KeyError(f"conf/report.yaml: field 'claims.{key}': missing (verdict thresholds)")
        return self.check(self, inputs, config.thresholds[key], config.spread)

    def result(self, ours: str, result: str, rule: str, spread: SeedSpread | None) -> Verdict:
        if spread is not None:
            rule += (
                f" Inconclusive where a margin between runs lies within ±{spread.band:.2f} of "
                "its threshold (the seed spread, see the legend)."
            )
        if result == INCONCLUSIVE:
            ours += "; a margin lies inside the seed spread of its threshold"
        return Verdict(self.number, self.text, self.paper_figure, ours, result, rule)

    def untestable(self, what: list[str], rule: str) -> Verdict:
        missing = f"missing: {', '.join(what)}"
        return Verdict(self.number, self.text, self.paper_figure, missing, NOT_TESTABLE, rule)


def _missing(inputs: ClaimInputs, names: tuple[str, ...]) -> list[str]:
    return [n for n in names if n not in inputs.runs]


def _finite(*values: float) -> bool:
    return all(map(math.isfinite, values))


def mlp_vs_cnns(claim: Claim, inputs: ClaimInputs, t: Mapping, spread: SeedSpread | None):
    rule = (
        f"Direction: each 1D CNN's final validation MAE is at least {t['min_margin']} below "
        f"the MLP's ('clearly': {t['min_margin']} is about twice the seed-to-seed spread of "
        f"the difference, {t['margin_source']}). Number: the MLP's final validation MAE "
        f"within ±{t['mlp_tolerance']} of {t['mlp_val_mae']}."
    )
    if missing := _missing(inputs, ("mlp", "cnn1d_20k", "cnn1d_200k")):
        return claim.untestable(missing, rule)
    mlp = inputs.runs["mlp"].val_mae
    cnns = [inputs.runs["cnn1d_20k"].val_mae, inputs.runs["cnn1d_200k"].val_mae]
    if not _finite(mlp, *cnns):
        return claim.untestable(["a final val_mae"], rule)
    ours = (
        f"final val. MAE: MLP {mlp:.3f}, 1D CNN 20k {cnns[0]:.3f}, 1D CNN 200k {cnns[1]:.3f} "
        f"(margins {mlp - cnns[0]:.3f}, {mlp - cnns[1]:.3f})"
    )
    direction = all_of(compare(mlp - c, t["min_margin"], spread) for c in cnns)
    size = within(mlp, t["mlp_val_mae"], t["mlp_tolerance"])
    return claim.result(ours, verdict(direction, [size]), rule, spread)


def cnn1d_vs_cnn2d(claim: Claim, inputs: ClaimInputs, t: Mapping, spread: SeedSpread | None):
    rule = (
        "Δ = 2D CNN − 1D CNN 20k (both on the same 20k-row data), final training and "
        "validation MAE. Direction: Δtrain > 0 and Δval > 0. Number: Δtrain ≥ "
        f"{t['min_train_gap']} and Δval ≥ {t['min_val_gap']} (the paper's 'at least')."
    )
    if missing := _missing(inputs, ("cnn2d", "cnn1d_20k")):
        return claim.untestable(missing, rule)
    cnn2d, cnn1d = inputs.runs["cnn2d"], inputs.runs["cnn1d_20k"]
    d_train, d_val = cnn2d.train_mae - cnn1d.train_mae, cnn2d.val_mae - cnn1d.val_mae
    if not _finite(d_train, d_val):
        return claim.untestable(["a final train_mae or val_mae"], rule)
    ours = f"Δtrain = {d_train:.3f}, Δval = {d_val:.3f} (2D CNN val. MAE {cnn2d.val_mae:.3f})"
    if cnn2d.epochs != cnn1d.epochs:
        ours += f"; after {cnn2d.epochs} vs {cnn1d.epochs} epochs (the profile's counts differ)"
    direction = all_of(compare(d, 0.0, spread, strict=True) for d in (d_train, d_val))
    sizes = [compare(d_train, t["min_train_gap"], spread), compare(d_val, t["min_val_gap"], spread)]
    return claim.result(ours, verdict(direction, sizes), rule, spread)


def cnn2d_epoch_time(claim: Claim, inputs: ClaimInputs, t: Mapping, spread: SeedSpread | None):
    lo, hi = t["paper_ratio"]
    rule = (
        "r = 2D CNN's epoch time per sample / 1D CNN 20k's. Direction: r > 1 and the 2D CNN's "
        "validation MAE is higher than the 1D CNN's after the same number of epochs (the "
        f"2D CNN's). Number: r within the paper's {lo}–{hi}× widened by a factor "
        f"{t['ratio_factor']} (hardware differs: the paper's GPU of 2017, ours below)."
    )
    if missing := _missing(inputs, ("cnn2d", "cnn1d_20k")):
        return claim.untestable(missing, rule)
    cnn2d, cnn1d = inputs.runs["cnn2d"], inputs.runs["cnn1d_20k"]
    ratio = (cnn2d.epoch_s / max(cnn2d.samples, 1)) / (cnn1d.epoch_s / max(cnn1d.samples, 1))
    epoch = cnn2d.epochs
    mae_2d, mae_1d = cnn2d.val_mae_at(epoch), cnn1d.val_mae_at(epoch)
    if not _finite(ratio, mae_2d, mae_1d):
        return claim.untestable(["epoch_s, or a val_mae at the 2D CNN's last epoch"], rule)
    ours = (
        f"2D CNN {cnn2d.epoch_s:.3g} s/epoch ({cnn2d.samples} samples), 1D CNN "
        f"{cnn1d.epoch_s:.3g} s/epoch ({cnn1d.samples} samples): {ratio:.1f}× per sample; "
        f"val. MAE after {epoch} epochs 2D {mae_2d:.3f} vs 1D {mae_1d:.3f}; trained on "
        f"{cnn2d.device} (2D) and {cnn1d.device} (1D)"
    )
    direction = all_of([ratio > 1, compare(mae_2d - mae_1d, 0.0, spread, strict=True)])
    size = within_factor(ratio, lo, hi, t["ratio_factor"])
    return claim.result(ours, verdict(direction, [size]), rule, spread)


def cnn1d_epoch_time(claim: Claim, inputs: ClaimInputs, t: Mapping, spread: SeedSpread | None):
    lo, hi = t["paper_ratio"]
    rule = (
        "r = 1D CNN 200k's epoch time / 1D CNN 20k's, divided by their ratio of samples "
        f"(the paper: {lo}–{hi}× the time for 10× the data, i.e. {lo / 10:g}–{hi / 10:g} per "
        f"sample). Direction: the larger data set's epoch is longer. Number: r within "
        f"{lo / 10:g}–{hi / 10:g} widened by a factor {t['ratio_factor']}."
    )
    if missing := _missing(inputs, ("cnn1d_20k", "cnn1d_200k")):
        return claim.untestable(missing, rule)
    small, large = inputs.runs["cnn1d_20k"], inputs.runs["cnn1d_200k"]
    per_sample = (large.epoch_s / max(large.samples, 1)) / (small.epoch_s / max(small.samples, 1))
    if not math.isfinite(per_sample):
        return claim.untestable(["epoch_s"], rule)
    ours = (
        f"{small.epoch_s:.3g} s/epoch ({small.samples} samples, batch "
        f"{small.config.get('batch_size', '?')}) and {large.epoch_s:.3g} s/epoch "
        f"({large.samples} samples, batch {large.config.get('batch_size', '?')}): "
        f"per-sample ratio {per_sample:.2f}; trained on {small.device} and {large.device}"
    )
    direction = large.epoch_s > small.epoch_s and large.samples > small.samples
    size = within_factor(per_sample, lo / 10, hi / 10, t["ratio_factor"])
    return claim.result(ours, verdict(direction, [size]), rule, None)


def more_data(claim: Claim, inputs: ClaimInputs, t: Mapping, spread: SeedSpread | None):
    rule = (
        f"Direction ('markedly'): the 200k 1D CNN's final validation MAE is at least "
        f"{t['min_margin']} below the 20k one's. Numbers: its validation MAE within "
        f"±{t['val_tolerance']} of {t['val_mae']} and its |val − train| gap within "
        f"±{t['gap_tolerance']} of {t['gap']}."
    )
    if missing := _missing(inputs, ("cnn1d_20k", "cnn1d_200k")):
        return claim.untestable(missing, rule)
    small, large = inputs.runs["cnn1d_20k"], inputs.runs["cnn1d_200k"]
    gap = abs(large.val_mae - large.train_mae)
    if not _finite(small.val_mae, large.val_mae, gap):
        return claim.untestable(["a final val_mae or train_mae"], rule)
    ours = (
        f"val. MAE {large.val_mae:.3f} ({large.samples} samples, {large.epochs} epochs) vs "
        f"{small.val_mae:.3f} ({small.samples} samples, {small.epochs} epochs); gap {gap:.4f}"
    )
    direction = compare(small.val_mae - large.val_mae, t["min_margin"], spread)
    sizes = [
        within(large.val_mae, t["val_mae"], t["val_tolerance"]),
        within(gap, t["gap"], t["gap_tolerance"]),
    ]
    return claim.result(ours, verdict(direction, sizes), rule, spread)


def transfer(claim: Claim, inputs: ClaimInputs, t: Mapping, spread: SeedSpread | None):
    share = t["early_share"]
    rule = (
        f"Early = the first {share:g} of the epochs. Direction: the pre-trained run's mean "
        "training AND validation MAE over the early epochs are below the random-init run's, "
        "AND the random-init map-2 run ends with a higher validation MAE than the map-1 "
        "1D CNN 20k. The paper gives no number."
    )
    if missing := _missing(inputs, ("transfer/scratch", "transfer/pretrained", "cnn1d_20k")):
        return claim.untestable(missing, rule)
    scratch, pre = inputs.runs["transfer/scratch"], inputs.runs["transfer/pretrained"]
    epochs = min(scratch.epochs, pre.epochs)
    early_epochs = max(1, math.floor(epochs * share))
    early = {
        col: (
            float(pre.history[col].iloc[:early_epochs].mean()),
            float(scratch.history[col].iloc[:early_epochs].mean()),
        )
        for col in ("train_mae", "val_mae")
    }
    map1 = inputs.runs["cnn1d_20k"].val_mae
    if not _finite(*[v for pair in early.values() for v in pair], scratch.val_mae, map1):
        return claim.untestable(["a training history or final val_mae"], rule)
    ours = (
        f"first {early_epochs} epochs, pre-trained vs random init: train "
        f"{early['train_mae'][0]:.3f} vs {early['train_mae'][1]:.3f}, val. "
        f"{early['val_mae'][0]:.3f} vs {early['val_mae'][1]:.3f}; final val. MAE map 2 "
        f"(random init) {scratch.val_mae:.3f} vs map 1 (1D CNN 20k) {map1:.3f}"
    )
    faster = [compare(s - p, 0.0, spread, strict=True) for p, s in early.values()]
    harder = compare(scratch.val_mae - map1, 0.0, spread, strict=True)
    return claim.result(ours, verdict(all_of([*faster, harder]), []), rule, spread)


def amcl_best(claim: Claim, inputs: ClaimInputs, t: Mapping, spread: SeedSpread | None):
    rule = (
        "Direction: (a) amcl's mean position error is below both CNN localizers'; (b) the "
        "ensemble has no more gross failures (> 1 m) than the single CNN and a lower "
        "95th-percentile position error. Number: single CNN − amcl mean position error "
        f"within ±{t['delta_tolerance_m']} m of {t['delta_m']} m."
    )
    metrics = inputs.paper_metrics
    names = ("amcl", "cnn_single", "cnn_ensemble")
    if missing := [m for m in names if m not in metrics]:
        return claim.untestable(missing, rule)

    def get(method: str, key: str) -> float:
        return as_float(metrics[method].get(key))

    amcl, single, ens = (get(m, "pos_err_mean_m") for m in names)
    gross = (get("cnn_single", "frac_gross_over_1m"), get("cnn_ensemble", "frac_gross_over_1m"))
    p95 = (get("cnn_single", "pos_err_p95_m"), get("cnn_ensemble", "pos_err_p95_m"))
    if not _finite(amcl, single, ens, *gross, *p95):
        return claim.untestable(["pos_err_mean_m, frac_gross_over_1m or pos_err_p95_m"], rule)
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
    return claim.result(ours, verdict(direction, [size]), rule, None)


CLAIMS: tuple[Claim, ...] = (
    Claim(
        1,
        "Both 1D CNNs clearly beat the MLP; the MLP's validation error stalls near 2.5 after "
        "about 50 epochs.",
        "MLP val. MAE ≈ 2.5; 1D CNNs far lower",
        mlp_vs_cnns,
    ),
    Claim(
        2,
        "The 1D CNNs beat the 2D CNN by at least 0.7 (training) and 0.5 (validation loss).",
        "Δtrain ≥ 0.7, Δval ≥ 0.5",
        cnn1d_vs_cnn2d,
    ),
    Claim(
        3,
        "The 2D CNN is much harder to train; one epoch took 60–100 s (20k samples).",
        "2D CNN 60–100 s/epoch vs 1D CNN ≈ 5 s (12–20× slower), GPU of 2017",
        cnn2d_epoch_time,
    ),
    Claim(
        4,
        "One 1D CNN epoch took about 5 s with 20k samples and 50–60 s with 200k samples.",
        "≈ 5 s (20k) and 50–60 s (200k) per epoch: 10–12× for 10× data",
        cnn1d_epoch_time,
    ),
    Claim(
        5,
        "Ten times more data helps markedly: the 200k 1D CNN converges to a validation MAE of "
        "about 0.15 after 400 epochs, with a train/validation gap of 0.0131.",
        "val. MAE ≈ 0.15, gap 0.0131",
        more_data,
    ),
    Claim(
        6,
        "Map 2: a 1D CNN learns it too, but to a worse loss than map 1; initialising from a 1D "
        "CNN pre-trained on map 1 makes training and validation loss fall faster, especially "
        "early.",
        "map 2 loss above map 1's; pre-trained curves below random-init ones early on",
        transfer,
    ),
    Claim(
        7,
        "amcl is clearly best (mean position error about 0.075 m lower than the single CNN's); "
        "the ensemble of CNNs is more robust than one CNN and yields a covariance.",
        "Δ mean position error (single CNN − amcl) ≈ 0.075 m; Table 2 numbers lost",
        amcl_best,
    ),
)


def check_claims(inputs: ClaimInputs, config: ClaimConfig) -> list[Verdict]:
    """Every claim of `CLAIMS`, in order."""
    return [claim.evaluate(inputs, config) for claim in CLAIMS]
