"""The paper's findings (paper-spec §6, claims 1–7) as rules checked against our numbers.

`CLAIMS` lists them once, in order: each `Claim` has the paper's words and figures, the scale at
which the `paper` profile tests it, and a check that is a pure function of the training runs,
the paper drive's localization metrics and conf/report.yaml (`claims:` thresholds), and that
writes its rule out, numbers included, beside the verdict so that a reader can redo it by hand.
Verdicts and the inconclusive rule: verdicts.py. Where a claim compares two training rows'
MAE, the margin is the difference of the rows' means over their seeds and its band comes from
their seed-to-seed spread, measured in the run (`ClaimConfig.between`). Epoch times (claims 3,
4) are timing alone, as the paper measured them, and localization errors (claim 7) have no
seed spread: both are compared as they are.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from scanloc.report.artifacts import TrainingRun, as_float
from scanloc.report.render.tables import seed_summary
from scanloc.report.verdicts import (
    NOT_TESTABLE,
    ClaimConfig,
    Comparison,
    RatioCheck,
    all_of,
    verdict,
    within,
)


class ClaimInputs(Protocol):
    """What the claims read (report/artifacts.py's Artifacts is one)."""

    @property
    def runs(self) -> Mapping[str, TrainingRun]: ...

    @property
    def paper_metrics(self) -> Mapping[str, Mapping[str, Any]]: ...


@dataclass(frozen=True)
class Verdict:
    """One claim checked: the paper's words and figures, what we measured, the verdict, the rule
    that gave it, the margins it rests on and the scale at which the paper profile tests it."""

    number: int
    paper: str
    paper_figure: str
    ours: str
    verdict: str
    rule: str
    comparisons: tuple[Comparison | RatioCheck, ...] = ()
    paper_scale: str = ""


Check = Callable[["Claim", ClaimInputs, Mapping[str, Any], ClaimConfig], Verdict]


@dataclass(frozen=True)
class Claim:
    """A finding of the paper and the rule that checks it (`check`, thresholds from
    conf/report.yaml `claims.claim<number>`)."""

    number: int
    text: str
    paper_figure: str
    paper_scale: str
    check: Check

    def evaluate(self, inputs: ClaimInputs, config: ClaimConfig) -> Verdict:
        key = f"claim{self.number}"
        if key not in config.thresholds:
            raise KeyError(f"conf/report.yaml: field 'claims.{key}': missing (verdict thresholds)")
        return self.check(self, inputs, config.thresholds[key], config)

    def result(
        self,
        ours: str,
        result: str,
        rule: str,
        comparisons: Sequence[Comparison | RatioCheck] = (),
    ) -> Verdict:
        if any(getattr(c, "band", None) is not None for c in comparisons):
            rule += (
                " Inconclusive where a margin between rows lies within its band of its "
                "threshold (the rows' seed spread, see the legend)."
            )
        return Verdict(
            self.number,
            self.text,
            self.paper_figure,
            ours,
            result,
            rule,
            tuple(comparisons),
            self.paper_scale,
        )

    def untestable(self, what: list[str], rule: str) -> Verdict:
        return self.not_tested(f"missing: {', '.join(what)}", rule)

    def not_tested(self, why: str, rule: str) -> Verdict:
        return Verdict(
            self.number,
            self.text,
            self.paper_figure,
            why,
            NOT_TESTABLE,
            rule,
            (),
            self.paper_scale,
        )


def _missing(inputs: ClaimInputs, names: tuple[str, ...]) -> list[str]:
    return [n for n in names if n not in inputs.runs]


def _finite(*values: float) -> bool:
    return all(map(math.isfinite, values))


def _val(run: TrainingRun) -> list[float]:
    """The row's final validation MAE, one per seed."""
    return [r.val_mae for r in run.seeds]


def _train(run: TrainingRun) -> list[float]:
    """The row's final training MAE, one per seed."""
    return [r.train_mae for r in run.seeds]


# The scans each row saw in training (samples × epochs) in the paper, relative to the 1D CNN
# 20k's 5000 × 20k = 100 M: the 200k net 400 × 200k = 80 M, the 2D CNN 400 × 20k = 8 M. About
# 7 hours of training each on the paper's GPU: rows compared after equal training time.
PAPER_SEEN = {"cnn1d_20k": 20000 * 5000, "cnn1d_200k": 200000 * 400, "cnn2d": 20000 * 400}


def unequal_training(
    reference: TrainingRun, other: TrainingRun, other_name: str, t: Mapping
) -> str | None:
    """Why a row cannot be compared with the 1D CNN 20k at this profile: the scans each saw in
    training (samples × epochs) stand in a ratio more than `seen_ratio_factor` from the
    paper's, so a margin between them would measure how long each trained rather than what
    the claim is about. None: comparable."""
    ours = (other.samples * other.epochs) / max(reference.samples * reference.epochs, 1)
    paper = PAPER_SEEN[other_name] / PAPER_SEEN["cnn1d_20k"]
    factor = t["seen_ratio_factor"]
    if paper / factor <= ours <= paper * factor:
        return None
    return (
        f"not tested at this profile: the 1D CNN 20k saw {reference.samples * reference.epochs:,}"
        f" scans in training ({reference.epochs} epochs) and the {other_name} "
        f"{other.samples * other.epochs:,} ({other.epochs} epochs), a ratio {ours:.3g} against "
        f"the paper's {paper:.3g} (accepted within ×/÷ {factor:g}): a margin would measure "
        "training time; the desk and paper profiles test it"
    )


def mlp_vs_cnns(claim: Claim, inputs: ClaimInputs, t: Mapping, config: ClaimConfig):
    rule = (
        f"Direction: each 1D CNN's final validation MAE (mean over its seeds) is at least "
        f"{t['min_margin']} below the MLP's ('clearly'). Number: the MLP's final validation MAE "
        f"within ±{t['mlp_tolerance']} of {t['mlp_val_mae']}. Tested only where the two 1D "
        f"CNNs saw as many training scans as the paper's (100 M and 80 M, within ×/÷ "
        f"{t['seen_ratio_factor']})."
    )
    if missing := _missing(inputs, ("mlp", "cnn1d_20k", "cnn1d_200k")):
        return claim.untestable(missing, rule)
    if why := unequal_training(
        inputs.runs["cnn1d_20k"], inputs.runs["cnn1d_200k"], "cnn1d_200k", t
    ):
        return claim.not_tested(why, rule)
    mlp, small, large = (_val(inputs.runs[n]) for n in ("mlp", "cnn1d_20k", "cnn1d_200k"))
    if not _finite(*mlp, *small, *large):
        return claim.untestable(["a final val_mae"], rule)
    margins = [
        config.between("MLP − 1D CNN 20k", mlp, small, t["min_margin"]),
        config.between("MLP − 1D CNN 200k", mlp, large, t["min_margin"]),
    ]
    ours = (
        f"final val. MAE: MLP {seed_summary(mlp)}, 1D CNN 20k {seed_summary(small)}, 1D CNN 200k "
        f"{seed_summary(large)}"
    )
    direction = all_of(c.outcome for c in margins)
    size = within(statistics.fmean(mlp), t["mlp_val_mae"], t["mlp_tolerance"])
    return claim.result(ours, verdict(direction, [size]), rule, margins)


def cnn1d_vs_cnn2d(claim: Claim, inputs: ClaimInputs, t: Mapping, config: ClaimConfig):
    rule = (
        "Δ = 2D CNN − 1D CNN 20k (both on the same 20k-row data), final training and "
        "validation MAE, means over seeds. Direction: Δtrain > 0 and Δval > 0. Number: Δtrain "
        f"≥ {t['min_train_gap']} and Δval ≥ {t['min_val_gap']} (the paper's 'at least'). "
        "Tested only where the 2D CNN saw about as large a share of the 1D CNN's training "
        f"scans as in the paper (8 M of 100 M, within ×/÷ {t['seen_ratio_factor']})."
    )
    if missing := _missing(inputs, ("cnn2d", "cnn1d_20k")):
        return claim.untestable(missing, rule)
    cnn2d, cnn1d = inputs.runs["cnn2d"], inputs.runs["cnn1d_20k"]
    if why := unequal_training(cnn1d, cnn2d, "cnn2d", t):
        return claim.not_tested(why, rule)
    if not _finite(*_val(cnn2d), *_val(cnn1d), *_train(cnn2d), *_train(cnn1d)):
        return claim.untestable(["a final train_mae or val_mae"], rule)

    def delta(label: str, values: Callable[[TrainingRun], list[float]], gap: float, strict: bool):
        return config.between(label, values(cnn2d), values(cnn1d), gap, strict)

    direction = [delta("Δtrain", _train, 0.0, True), delta("Δval", _val, 0.0, True)]
    sizes = [
        delta("Δtrain", _train, t["min_train_gap"], False),
        delta("Δval", _val, t["min_val_gap"], False),
    ]
    ours = (
        f"final train / val. MAE: 2D CNN {seed_summary(_train(cnn2d))} / "
        f"{seed_summary(_val(cnn2d))}, 1D CNN 20k {seed_summary(_train(cnn1d))} / "
        f"{seed_summary(_val(cnn1d))}"
    )
    ours += (
        f"; the 2D CNN after {cnn2d.epochs} epochs on {cnn2d.samples} samples, the 1D CNN "
        f"after {cnn1d.epochs} on {cnn1d.samples}"
    )
    result = verdict(all_of(c.outcome for c in direction), [c.outcome for c in sizes])
    return claim.result(ours, result, rule, [*direction, *sizes])


def _on_cpu(*runs: TrainingRun) -> bool:
    """Whether the runs trained on CPUs (or on a device not recorded): where the cross-machine
    factor of epoch times applies."""
    return all((r.metrics.get("device") or {}).get("type", "cpu") == "cpu" for r in runs)


def _per_sample_s(run: TrainingRun) -> float:
    return run.epoch_s / max(run.samples, 1)


def cnn2d_epoch_time(claim: Claim, inputs: ClaimInputs, t: Mapping, config: ClaimConfig):
    lo, hi = t["paper_ratio"]
    rule = (
        "r = the 2D CNN's epoch time per sample / the 1D CNN 20k's, both at the paper's batch "
        f"(100): timing alone, as the paper measured it. Direction: r > 1. Number: r within "
        f"the paper's {lo}–{hi}× widened by a factor {t['ratio_factor']} (hardware differs: "
        "the paper's GPU of 2017, ours below). Inconclusive where r lies within the "
        "cross-machine factor of a bound (see the legend)."
    )
    if missing := _missing(inputs, ("cnn2d", "cnn1d_20k")):
        return claim.untestable(missing, rule)
    cnn2d, cnn1d = inputs.runs["cnn2d"], inputs.runs["cnn1d_20k"]
    ratio = _per_sample_s(cnn2d) / _per_sample_s(cnn1d)
    if not math.isfinite(ratio):
        return claim.untestable(["epoch_s (reports/timing)"], rule)
    ours = (
        f"2D CNN {cnn2d.epoch_s:.3g} s/epoch ({cnn2d.samples} samples, batch "
        f"{cnn2d.config.get('batch_size', '?')}), 1D CNN {cnn1d.epoch_s:.3g} s/epoch "
        f"({cnn1d.samples} samples, batch {cnn1d.config.get('batch_size', '?')}): {ratio:.1f}× "
        f"per sample; trained on {cnn2d.device} (2D) and {cnn1d.device} (1D)"
    )
    factor = t["ratio_factor"]
    size = config.ratio_check("r", ratio, lo / factor, hi * factor, _on_cpu(cnn2d, cnn1d))
    timing = Comparison("r", ratio, 1.0, strict=True)
    return claim.result(ours, verdict(timing.outcome, [size.outcome]), rule, [timing, size])


def cnn1d_epoch_time(claim: Claim, inputs: ClaimInputs, t: Mapping, config: ClaimConfig):
    lo, hi = t["paper_ratio"]
    rule = (
        "r = the 1D CNN 200k's epoch time / the 1D CNN 20k's, divided by their ratio of samples, "
        "each at the paper's batch (400 and 100): timing alone. The paper: "
        f"{lo}–{hi}× the time for 10× the data, i.e. {lo / 10:g}–{hi / 10:g} per sample. "
        "Direction: the larger data set's epoch is longer. Number: r within "
        f"{lo / 10:g}–{hi / 10:g} widened by a factor {t['ratio_factor']}; inconclusive where "
        "it lies within the cross-machine factor of a bound (see the legend)."
    )
    if missing := _missing(inputs, ("cnn1d_20k", "cnn1d_200k")):
        return claim.untestable(missing, rule)
    small, large = inputs.runs["cnn1d_20k"], inputs.runs["cnn1d_200k"]
    per_sample = _per_sample_s(large) / _per_sample_s(small)
    if not math.isfinite(per_sample):
        return claim.untestable(["epoch_s (reports/timing)"], rule)
    ours = (
        f"{small.epoch_s:.3g} s/epoch ({small.samples} samples, batch "
        f"{small.config.get('batch_size', '?')}) and {large.epoch_s:.3g} s/epoch "
        f"({large.samples} samples, batch {large.config.get('batch_size', '?')}): "
        f"per-sample ratio {per_sample:.2f}; trained on {small.device} and {large.device}"
    )
    direction = large.epoch_s > small.epoch_s and large.samples > small.samples
    factor = t["ratio_factor"]
    size = config.ratio_check(
        "per-sample ratio", per_sample, lo / 10 / factor, hi / 10 * factor, _on_cpu(small, large)
    )
    return claim.result(ours, verdict(direction, [size.outcome]), rule, [size])


def more_data(claim: Claim, inputs: ClaimInputs, t: Mapping, config: ClaimConfig):
    rule = (
        f"Direction ('markedly'): the 200k 1D CNN's final validation MAE is at least "
        f"{t['min_margin']} below the 20k one's (means over seeds). Numbers: its validation MAE "
        f"within ±{t['val_tolerance']} of {t['val_mae']} and its |val − train| gap within "
        f"±{t['gap_tolerance']} of {t['gap']}. Tested only where the two saw as many training "
        f"scans as the paper's did (within ×/÷ {t['seen_ratio_factor']})."
    )
    if missing := _missing(inputs, ("cnn1d_20k", "cnn1d_200k")):
        return claim.untestable(missing, rule)
    small, large = inputs.runs["cnn1d_20k"], inputs.runs["cnn1d_200k"]
    if why := unequal_training(small, large, "cnn1d_200k", t):
        return claim.not_tested(why, rule)
    gaps = [abs(r.val_mae - r.train_mae) for r in large.seeds]
    if not _finite(*_val(small), *_val(large), *gaps):
        return claim.untestable(["a final val_mae or train_mae"], rule)
    margin = config.between("20k − 200k", _val(small), _val(large), t["min_margin"])
    ours = (
        f"val. MAE {seed_summary(_val(large))} ({large.samples} samples, {large.epochs} epochs) vs "
        f"{seed_summary(_val(small))} ({small.samples} samples, {small.epochs} epochs); gap "
        f"{statistics.fmean(gaps):.4f}"
    )
    sizes = [
        within(statistics.fmean(_val(large)), t["val_mae"], t["val_tolerance"]),
        within(statistics.fmean(gaps), t["gap"], t["gap_tolerance"]),
    ]
    return claim.result(ours, verdict(margin.outcome, sizes), rule, [margin])


def transfer(claim: Claim, inputs: ClaimInputs, t: Mapping, config: ClaimConfig):
    share = t["early_share"]
    rule = (
        f"Early = the first {share:g} of the epochs. Direction: the pre-trained runs' mean "
        "training AND validation MAE over the early epochs are below the random-init runs' "
        "(means over seeds), AND the random-init map-2 run ends with a higher validation MAE "
        "than the map-1 1D CNN 20k after the same number of epochs (the same configuration on "
        "the other map). The paper gives no number."
    )
    if missing := _missing(inputs, ("transfer/scratch", "transfer/pretrained", "cnn1d_20k")):
        return claim.untestable(missing, rule)
    scratch, pre = inputs.runs["transfer/scratch"], inputs.runs["transfer/pretrained"]
    map1 = inputs.runs["cnn1d_20k"]
    epochs = min(scratch.epochs, pre.epochs)
    early_epochs = max(1, math.floor(epochs * share))
    same = min(scratch.epochs, map1.epochs)

    def early(run: TrainingRun, col: str) -> list[float]:
        return [float(r.history[col].iloc[:early_epochs].mean()) for r in run.seeds]

    faster = [
        config.between(
            f"early {col}: random init − pre-trained",
            early(scratch, col),
            early(pre, col),
            0.0,
            strict=True,
        )
        for col in ("train_mae", "val_mae")
    ]
    map2 = [r.val_mae_at(same) for r in scratch.seeds]
    map1_values = [r.val_mae_at(same) for r in map1.seeds]
    if not _finite(*[c.value for c in faster], *map2, *map1_values):
        return claim.untestable(["a training history or final val_mae"], rule)
    harder = config.between(
        f"map 2 − map 1 val. MAE after {same} epochs", map2, map1_values, 0.0, strict=True
    )
    ours = (
        f"mean MAE over the first {early_epochs} of {epochs} epochs, random init vs "
        f"pre-trained: train {seed_summary(early(scratch, 'train_mae'))} vs "
        f"{seed_summary(early(pre, 'train_mae'))}, val. "
        f"{seed_summary(early(scratch, 'val_mae'))} vs {seed_summary(early(pre, 'val_mae'))}; "
        f"val. MAE after {same} epochs, map 2 (random init) {seed_summary(map2)} vs map 1 "
        f"(1D CNN 20k) {seed_summary(map1_values)}"
    )
    comparisons = [*faster, harder]
    return claim.result(
        ours, verdict(all_of(c.outcome for c in comparisons), []), rule, comparisons
    )


def amcl_best(claim: Claim, inputs: ClaimInputs, t: Mapping, config: ClaimConfig):
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
    return claim.result(ours, verdict(direction, [size]), rule)


CLAIMS: tuple[Claim, ...] = (
    Claim(
        1,
        "Both 1D CNNs clearly beat the MLP; the MLP's validation error stalls near 2.5 after "
        "about 50 epochs.",
        "MLP val. MAE ≈ 2.5; 1D CNNs far lower",
        "MLP 20k samples × 2000 epochs, 1D CNN 20k × 5000, 1D CNN 200k × 400; one seed each",
        mlp_vs_cnns,
    ),
    Claim(
        2,
        "The 1D CNNs beat the 2D CNN by at least 0.7 (training) and 0.5 (validation loss).",
        "Δtrain ≥ 0.7, Δval ≥ 0.5",
        "2D CNN and 1D CNN, 20k samples × 400 and 5000 epochs; one seed each",
        cnn1d_vs_cnn2d,
    ),
    Claim(
        3,
        "The 2D CNN is much harder to train; one epoch took 60–100 s (20k samples).",
        "2D CNN 60–100 s/epoch vs 1D CNN ≈ 5 s (12–20× slower), GPU of 2017",
        "epoch times of the 2D and 1D CNN at batch 100, 20k samples (timing alone)",
        cnn2d_epoch_time,
    ),
    Claim(
        4,
        "One 1D CNN epoch took about 5 s with 20k samples and 50–60 s with 200k samples.",
        "≈ 5 s (20k) and 50–60 s (200k) per epoch: 10–12× for 10× data",
        "epoch times of the 1D CNN, 20k samples at batch 100 and 200k at 400 (timing alone)",
        cnn1d_epoch_time,
    ),
    Claim(
        5,
        "Ten times more data helps markedly: the 200k 1D CNN converges to a validation MAE of "
        "about 0.15 after 400 epochs, with a train/validation gap of 0.0131.",
        "val. MAE ≈ 0.15, gap 0.0131",
        "1D CNN 20k × 5000 epochs vs 200k × 400; one seed each",
        more_data,
    ),
    Claim(
        6,
        "Map 2: a 1D CNN learns it too, but to a worse loss than map 1; initialising from a 1D "
        "CNN pre-trained on map 1 makes training and validation loss fall faster, especially "
        "early.",
        "map 2 loss above map 1's; pre-trained curves below random-init ones early on",
        "1D CNN on map 2, 20k samples × 400 epochs, random init and pre-trained; one seed each",
        transfer,
    ),
    Claim(
        7,
        "amcl is clearly best (mean position error about 0.075 m lower than the single CNN's); "
        "the ensemble of CNNs is more robust than one CNN and yields a covariance.",
        "Δ mean position error (single CNN − amcl) ≈ 0.075 m; Table 2 numbers lost",
        "the 1500-step drive through map 1; single CNN and 7-member ensemble at 200k × 400",
        amcl_best,
    ),
)


def check_claims(inputs: ClaimInputs, config: ClaimConfig) -> list[Verdict]:
    """Every claim of `CLAIMS`, in order."""
    return [claim.evaluate(inputs, config) for claim in CLAIMS]
