"""The paper's findings (paper-spec §6, claims 1–7) checked against our numbers.

Each check is a pure function of the training runs and localization metrics with an explicit
rule, written into the report beside the verdict, so that a reader can redo it by hand.
Verdicts: "reproduced", "partly reproduced", "not reproduced", or "not testable" when an
artifact the rule needs is missing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import pandas as pd

REPRODUCED, PARTLY, NOT_REPRODUCED, NOT_TESTABLE = (
    "reproduced",
    "partly reproduced",
    "not reproduced",
    "not testable",
)

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
RULES: dict[int, str] = {
    1: "Reproduced if both 1D CNNs' final validation MAE is below the MLP's; partly if one is.",
    2: "Δ = 2D CNN's final MAE − best 1D CNN's. Reproduced if Δval ≥ 0.5 and Δtrain ≥ 0.7; "
    "partly if both Δ > 0; otherwise not reproduced.",
    3: "Reproduced if the 2D CNN needs ≥ 5× the 1D CNN (20k)'s time per training sample AND "
    "ends with a higher validation MAE; partly if one of the two holds. Absolute seconds depend "
    "on the hardware and are not compared.",
    4: "Reproduced if the 200k run's time per training sample is within a factor 2 of the 20k "
    "run's (epoch time grows about linearly with the data, as 5 s → 50–60 s does); "
    "absolute seconds are not compared.",
    5: "Reproduced if the 200k 1D CNN's final validation MAE is below the 20k one's, ≤ 0.15, "
    "and its |val − train| gap ≤ 0.05; partly if only the first holds.",
    6: "Early = the first quarter of the epochs. Reproduced if the pre-trained run's mean "
    "training AND validation MAE over the early epochs are below the random-init run's AND "
    "the random-init map-2 run ends with a higher validation MAE than the map-1 1D CNN (20k); "
    "partly if one of the two parts holds.",
    7: "(a) amcl's mean position error is below both CNN localizers'; (b) the ensemble has no "
    "more gross failures (> 1 m) than the single CNN and a lower 95th-percentile position "
    "error. Reproduced if (a) and (b); partly if one holds.",
}


@dataclass(frozen=True)
class Run:
    """One training run's artifacts: per-epoch history, final metrics and the config as run."""

    history: pd.DataFrame
    metrics: Mapping[str, Any]
    config: Mapping[str, Any]

    @property
    def val_mae(self) -> float:
        return float(self.metrics.get("val_mae", math.nan))

    @property
    def train_mae(self) -> float:
        """Final epoch's training MAE."""
        return float(self.history["train_mae"].iloc[-1]) if len(self.history) else math.nan

    @property
    def seconds_per_sample(self) -> float:
        """Epoch time divided by the dataset size used (hardware-dependent)."""
        return float(self.metrics.get("epoch_s", math.nan)) / max(self.samples, 1)

    @property
    def samples(self) -> int:
        return int(self.config.get("samples", self.metrics.get("samples", 0)) or 0)


@dataclass(frozen=True)
class Claim:
    number: int
    paper: str
    paper_figure: str
    ours: str
    verdict: str
    rule: str


def _verdict(parts: list[bool]) -> str:
    if all(parts):
        return REPRODUCED
    return PARTLY if any(parts) else NOT_REPRODUCED


def _claim(number: int, ours: str, verdict: str) -> Claim:
    return Claim(number, PAPER_CLAIMS[number], PAPER_FIGURES[number], ours, verdict, RULES[number])


def _missing(number: int, names: list[str]) -> Claim:
    return _claim(number, f"missing: {', '.join(names)}", NOT_TESTABLE)


def _need(runs: Mapping[str, Run], names: tuple[str, ...]) -> list[str]:
    return [n for n in names if n not in runs]


def claim_1(runs: Mapping[str, Run]) -> Claim:
    if missing := _need(runs, ("mlp", "cnn1d_20k", "cnn1d_200k")):
        return _missing(1, missing)
    mlp = runs["mlp"].val_mae
    cnns = [runs["cnn1d_20k"].val_mae, runs["cnn1d_200k"].val_mae]
    ours = f"final val. MAE: MLP {mlp:.3f}, 1D CNN 20k {cnns[0]:.3f}, 1D CNN 200k {cnns[1]:.3f}"
    return _claim(1, ours, _verdict([c < mlp for c in cnns]))


def _best_1d(runs: Mapping[str, Run]) -> Run:
    return min((runs[n] for n in ("cnn1d_20k", "cnn1d_200k") if n in runs), key=lambda r: r.val_mae)


def claim_2(runs: Mapping[str, Run]) -> Claim:
    missing = _need(runs, ("cnn2d",))
    if not {"cnn1d_20k", "cnn1d_200k"} & set(runs):
        missing.append("cnn1d_20k or cnn1d_200k")
    if missing:
        return _missing(2, missing)
    best, cnn2d = _best_1d(runs), runs["cnn2d"]
    d_train, d_val = cnn2d.train_mae - best.train_mae, cnn2d.val_mae - best.val_mae
    ours = f"Δtrain = {d_train:.3f}, Δval = {d_val:.3f} (2D CNN val. MAE {cnn2d.val_mae:.3f})"
    if d_val >= 0.5 and d_train >= 0.7:
        verdict = REPRODUCED
    else:
        verdict = PARTLY if d_val > 0 and d_train > 0 else NOT_REPRODUCED
    return _claim(2, ours, verdict)


def claim_3(runs: Mapping[str, Run], hardware: str) -> Claim:
    if missing := _need(runs, ("cnn2d", "cnn1d_20k")):
        return _missing(3, missing)
    cnn2d, cnn1d = runs["cnn2d"], runs["cnn1d_20k"]
    ratio = cnn2d.seconds_per_sample / cnn1d.seconds_per_sample
    ours = (
        f"2D CNN {cnn2d.metrics.get('epoch_s', math.nan):.3g} s/epoch ({cnn2d.samples} samples), "
        f"1D CNN {cnn1d.metrics.get('epoch_s', math.nan):.3g} s/epoch ({cnn1d.samples} samples): "
        f"{ratio:.1f}× per sample; val. MAE 2D {cnn2d.val_mae:.3f} vs 1D {cnn1d.val_mae:.3f}; "
        f"on {hardware}"
    )
    return _claim(3, ours, _verdict([ratio >= 5.0, cnn2d.val_mae > cnn1d.val_mae]))


def claim_4(runs: Mapping[str, Run], hardware: str) -> Claim:
    if missing := _need(runs, ("cnn1d_20k", "cnn1d_200k")):
        return _missing(4, missing)
    small, large = runs["cnn1d_20k"], runs["cnn1d_200k"]
    ratio = large.seconds_per_sample / small.seconds_per_sample
    ours = (
        f"{small.metrics.get('epoch_s', math.nan):.3g} s/epoch ({small.samples} samples) and "
        f"{large.metrics.get('epoch_s', math.nan):.3g} s/epoch ({large.samples} samples); "
        f"per-sample ratio {ratio:.2f}; on {hardware}"
    )
    return _claim(4, ours, REPRODUCED if 0.5 <= ratio <= 2.0 else NOT_REPRODUCED)


def claim_5(runs: Mapping[str, Run]) -> Claim:
    if missing := _need(runs, ("cnn1d_20k", "cnn1d_200k")):
        return _missing(5, missing)
    small, large = runs["cnn1d_20k"], runs["cnn1d_200k"]
    gap = abs(large.val_mae - large.train_mae)
    ours = (
        f"val. MAE {large.val_mae:.3f} ({large.samples} samples, "
        f"{large.config.get('epochs', '?')} epochs) vs {small.val_mae:.3f} "
        f"({small.samples} samples); gap {gap:.4f}"
    )
    better = large.val_mae < small.val_mae
    if better and large.val_mae <= 0.15 and gap <= 0.05:
        verdict = REPRODUCED
    else:
        verdict = PARTLY if better else NOT_REPRODUCED
    return _claim(5, ours, verdict)


def early_mean(history: pd.DataFrame, column: str, epochs: int) -> float:
    """Mean of a curve over its first quarter (at least one epoch) of `epochs`."""
    return float(history[column].iloc[: max(1, epochs // 4)].mean())


def claim_6(runs: Mapping[str, Run]) -> Claim:
    if missing := _need(runs, ("transfer/scratch", "transfer/pretrained", "cnn1d_20k")):
        return _missing(6, missing)
    scratch, pre = runs["transfer/scratch"], runs["transfer/pretrained"]
    epochs = min(len(scratch.history), len(pre.history))
    early = {
        col: (early_mean(pre.history, col, epochs), early_mean(scratch.history, col, epochs))
        for col in ("train_mae", "val_mae")
    }
    faster = all(p < s for p, s in early.values())
    map1 = runs["cnn1d_20k"].val_mae
    ours = (
        f"first {max(1, epochs // 4)} epochs, pre-trained vs random init: train "
        f"{early['train_mae'][0]:.3f} vs {early['train_mae'][1]:.3f}, val. "
        f"{early['val_mae'][0]:.3f} vs {early['val_mae'][1]:.3f}; final val. MAE map 2 "
        f"(random init) {scratch.val_mae:.3f} vs map 1 (1D CNN 20k) {map1:.3f}"
    )
    return _claim(6, ours, _verdict([faster, scratch.val_mae > map1]))


def claim_7(metrics: Mapping[str, Mapping[str, Any]]) -> Claim:
    if missing := [m for m in ("amcl", "cnn_single", "cnn_ensemble") if m not in metrics]:
        return _missing(7, missing)

    def get(method: str, key: str) -> float:
        value = metrics[method].get(key)
        return math.nan if value is None else float(value)

    amcl, single, ens = (get(m, "pos_err_mean_m") for m in ("amcl", "cnn_single", "cnn_ensemble"))
    gross = (get("cnn_single", "frac_gross_over_1m"), get("cnn_ensemble", "frac_gross_over_1m"))
    p95 = (get("cnn_single", "pos_err_p95_m"), get("cnn_ensemble", "pos_err_p95_m"))
    calib = get("cnn_ensemble", "calib_within_2sigma")
    ours = (
        f"mean position error amcl {amcl:.3f} m, single {single:.3f} m, ensemble {ens:.3f} m "
        f"(single − amcl = {single - amcl:.3f} m); gross failures single {100 * gross[0]:.1f} %, "
        f"ensemble {100 * gross[1]:.1f} %; 95th pct. {p95[0]:.3f} vs {p95[1]:.3f} m; "
        f"ensemble truth inside 2σ ellipse {100 * calib:.1f} % of steps (86.5 % if calibrated)"
    )
    best = amcl < single and amcl < ens
    robust = gross[1] <= gross[0] and p95[1] < p95[0]
    return _claim(7, ours, _verdict([best, robust]))


def check_claims(
    runs: Mapping[str, Run], metrics: Mapping[str, Mapping[str, Any]], hardware: str
) -> list[Claim]:
    """All seven claims, in order."""
    return [
        claim_1(runs),
        claim_2(runs),
        claim_3(runs, hardware),
        claim_4(runs, hardware),
        claim_5(runs),
        claim_6(runs),
        claim_7(metrics),
    ]
