"""Power study of the paper's claims: at which scale does a verdict stop depending on the seed?

Trains every row a claim compares (Table 1's MLP, 1D CNNs and 2D CNN, the map-2 transfer runs)
with `--seeds` seeds at the laptop profile's configuration (the train and transfer stages'
composed config: architecture, loss, optimiser, batch, samples), for up to the study's epochs
of that row, and records every epoch's training and validation MAE. The seeds of a row train
together (scanloc.models.stacked_ensemble, loop mode: each ends bit for bit where a lone run of
that seed would). Because the learning-rate schedule and the data order depend only on the
update count and the epoch, epoch e of a longer run *is* a run of e epochs, so one training per
row gives every epoch scale up to its length.

Then, per claim and scale, the claim's verdict and margins by the report's own rule
(scanloc.report.claims: the seeds' mean of each row; the band, the Student-t quantile at
Welch's degrees of freedom × sqrt(sd_a² + sd_b²)), the smallest ratio z = |margin − threshold| /
band over its comparisons, whether the rule decides it there (a verdict neither inconclusive
nor untested), the training cost of the scale (the rows' seeds × samples × epochs at the
measured seconds per scan), and a fit of each row's mean validation MAE (a power law of the
epochs; none for a row still on its plateau) and its s.d. (a constant share of the mean) that
predicts the ratio beyond the epochs trained. A profile's scale is chosen by decidability and
cost, never by the verdict it gives.

    python benchmarks/claim_power.py            # train what is missing, then analyse
    python benchmarks/claim_power.py --analyse  # analyse the recorded histories only

Histories: runs/claim_power/<precision>/<row>/seed_<s>/ (resumable: a seed whose history is as
long as asked is not trained again). Last line: one JSON object of the figures.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
OUT = ROOT / "runs" / "claim_power"
SYNTHETIC: Path | None = None  # --quick: every row trains on this tiny synthetic dataset


@dataclass(frozen=True)
class StudyRow:
    """A row the study trains: which config, how many samples and epochs."""

    name: str
    config: str  # "train" (conf/train.yaml, experiment=name) or "transfer"
    epochs: int
    samples: int | None = None  # None: the laptop profile's
    init: str = "scratch"  # transfer only


ROWS = (
    StudyRow("mlp", "train", 60),
    StudyRow("cnn1d_20k", "train", 40),
    StudyRow("cnn1d_200k", "train", 30),
    StudyRow("cnn2d", "train", 3, samples=1000),
    StudyRow("transfer_scratch", "transfer", 20),
    StudyRow("transfer_pretrained", "transfer", 20, init="pretrained"),
)


def composed(row: StudyRow) -> dict:
    """The stage's laptop-profile config of `row` (what `dvc repro` would train)."""
    overrides = ["profile=laptop"]
    if row.config == "train":
        overrides.append(f"experiment={row.name}")
    else:
        overrides.append(f"init={row.init}")
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(row.config, overrides=overrides)
    return OmegaConf.to_container(cfg, resolve=True)


def row_dir(precision: str, row: str, seed: int) -> Path:
    return OUT / precision / row / f"seed_{seed}"


def row_seeds(cfg: Mapping, row: StudyRow, count: int) -> list[int]:
    """The row's own seed, then the next ones (cnn1d_200k's are the ensemble's members)."""
    run = cfg["experiment"] if row.config == "train" else cfg["transfer"]
    return [int(run["seed"]) + k for k in range(count)]


def history(precision: str, row: str, seed: int) -> pd.DataFrame | None:
    path = row_dir(precision, row, seed) / "history.csv"
    return pd.read_csv(path) if path.is_file() else None


# The claims whose verdicts rest on margins between trained rows, the rows each compares, and
# the epochs of each row the study evaluates them at (every combination is a scale).
CLAIM_ROWS = {
    1: ("mlp", "cnn1d_20k", "cnn1d_200k"),
    2: ("cnn2d", "cnn1d_20k"),
    5: ("cnn1d_20k", "cnn1d_200k"),
    6: ("transfer_scratch", "transfer_pretrained", "cnn1d_20k"),
}
RUN_NAMES = {"transfer_scratch": "transfer/scratch", "transfer_pretrained": "transfer/pretrained"}
TIED = ("transfer_scratch", "transfer_pretrained")  # rows that always train the same epochs
MIN_FALL = 0.05  # a row whose mean fell less than this share over its fitted epochs: no fit
GRID_POINTS = 4  # epochs per row: its study length × 1/4, 2/4, 3/4, 4/4


@dataclass(frozen=True)
class RowCurves:
    """A row's per-seed histories from the study, its config as the stage runs it, and its
    measured training cost."""

    name: str
    histories: list[pd.DataFrame]
    config: dict
    s_per_sample_epoch: float

    @property
    def epochs(self) -> int:
        return min(len(h) for h in self.histories)

    def grid(self) -> list[int]:
        return sorted(
            {max(1, round(self.epochs * k / GRID_POINTS)) for k in range(1, GRID_POINTS + 1)}
        )

    def run(self, epochs: int):
        """The row as the report reads it after `epochs` epochs (scanloc.report.artifacts)."""
        from scanloc.report.artifacts import TrainingRun

        config = {**self.config, "epochs": epochs}
        first, *rest = (
            TrainingRun(h.iloc[:epochs].reset_index(drop=True), {}, config) for h in self.histories
        )
        return TrainingRun(first.history, {"epoch_s": self.epoch_s()}, config, tuple(rest))

    def epoch_s(self) -> float:
        return self.s_per_sample_epoch * int(self.config["samples"])

    def cost_s(self, epochs: int) -> float:
        """Seconds to train every seed of the row for `epochs` epochs on this machine."""
        return self.s_per_sample_epoch * int(self.config["samples"]) * epochs * len(self.histories)

    def mean_sd(self, epochs: int) -> tuple[float, float]:
        values = [float(h["val_mae"].iloc[epochs - 1]) for h in self.histories]
        return statistics.fmean(values), statistics.stdev(values)


def load_rows(precision: str, seeds: int) -> dict[str, RowCurves]:
    rows = {}
    for row in ROWS:
        cfg = composed(row)
        run = cfg["experiment"] if row.config == "train" else cfg["transfer"]
        found = [history(precision, row.name, s) for s in row_seeds(cfg, row, seeds)]
        cost_path = OUT / precision / row.name / "cost.json"
        if any(h is None for h in found) or not cost_path.is_file():
            continue
        cost = json.loads(cost_path.read_text())  # as trained, whatever the config says now
        config = {"samples": int(cost["samples"]), "batch_size": int(run["batch_size"])}
        rows[row.name] = RowCurves(row.name, found, config, cost["s_per_sample_epoch"])
    return rows


class _Inputs:
    """scanloc.report.claims' inputs: the study's rows at one scale."""

    def __init__(self, runs: Mapping[str, object]) -> None:
        self.runs = runs
        self.paper_metrics: Mapping = {}


def claim_config():
    from scanloc.report.verdicts import ClaimConfig

    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = OmegaConf.to_container(compose("report"), resolve=True)
    # No fallback: every row of the study has its own seeds.
    return ClaimConfig.from_config({**cfg, "seed_spread": {}}, "study")


def evaluate(number: int, rows: Mapping[str, RowCurves], scale: Mapping[str, int], config):
    """The claim's verdict and margins at `scale` (epochs per row), by the report's own rule."""
    from scanloc.report.claims import CLAIMS

    runs = {RUN_NAMES.get(name, name): rows[name].run(e) for name, e in scale.items()}
    return CLAIMS[number - 1].evaluate(_Inputs(runs), config)


def fit_curve(row: RowCurves) -> dict | None:
    """The mean validation MAE a power law of the epochs, and its seed s.d. a constant share of
    the mean (the RMS of sd / mean), both over the second half of the row's epochs (past the
    first plateau). Three seeds give an s.d. that jumps from epoch to epoch (0.03 to 0.14 for
    the 1D CNN 20k), so a trend fitted to it would extrapolate noise; a constant share lets the
    spread shrink only as the error does."""
    epochs = np.arange(max(2, row.epochs // 2), row.epochs + 1)
    stats = np.array([row.mean_sd(int(e)) for e in epochs])
    if stats[-1, 0] > (1 - MIN_FALL) * stats[0, 0]:
        return None  # still on a plateau: a power law through it would extrapolate nothing
    mean_fit = np.polyfit(np.log(epochs), np.log(stats[:, 0]), 1)
    cv = float(np.sqrt(np.mean((stats[:, 1] / stats[:, 0]) ** 2)))
    return {
        "log_mean": mean_fit.tolist(),
        "sd_share": cv,
        "fitted_epochs": [int(epochs[0]), int(epochs[-1])],
    }


def predicted(fit: Mapping, epochs: float) -> tuple[float, float]:
    """(mean, s.d.) of the row's final validation MAE after `epochs` epochs, by its fit."""
    mean = math.exp(np.polyval(fit["log_mean"], math.log(epochs)))
    return float(mean), float(fit["sd_share"] * mean)


# The validation-MAE margins each claim rests on (row a − row b against a threshold), for the
# fitted prediction beyond the epochs trained. Claim 6's early-epoch margins are measured
# only (its prediction covers "map 2 is harder"); claim 2's training-MAE margin likewise.
PREDICTED_MARGINS = {
    1: [("mlp", "cnn1d_20k", 0.4), ("mlp", "cnn1d_200k", 0.4)],
    2: [("cnn2d", "cnn1d_20k", 0.5)],
    5: [("cnn1d_20k", "cnn1d_200k", 0.4)],
    6: [("transfer_scratch", "cnn1d_20k", 0.0)],
}
# The scale of a prediction: the 1D CNN 20k's epochs. The other rows train as the claims' rule
# compares them (scanloc.report.claims PAPER_SEEN): the 200k net and the 2D CNN see the paper's
# share of the 20k net's training scans, the map-2 run as many epochs, the MLP its studied ones
# (its validation MAE has stalled by then).
PREDICTED_EPOCHS_20K = (40, 60, 80, 120, 160, 240, 320)


def row_epochs(rows: Mapping[str, RowCurves], epochs_20k: int) -> dict[str, float]:
    from scanloc.report.claims import PAPER_SEEN

    seen_20k = epochs_20k * int(rows["cnn1d_20k"].config["samples"])
    out = {"cnn1d_20k": epochs_20k, "transfer_scratch": epochs_20k}
    for name in ("cnn1d_200k", "cnn2d"):
        if name in rows:
            share = PAPER_SEEN[name] / PAPER_SEEN["cnn1d_20k"]
            out[name] = share * seen_20k / int(rows[name].config["samples"])
    if "mlp" in rows:
        out["mlp"] = rows["mlp"].epochs
    return out


def predicted_ratio(fits: Mapping, pairs, epochs: Mapping[str, float], seeds: int, sigmas: float):
    """The smallest |margin − threshold| / band the fits predict at `epochs` per row with
    `seeds` seeds (band as the report's rule: Student t of Welch's degrees of freedom)."""
    from scanloc.report.verdicts import band_multiplier, welch_dof

    ratios = []
    for a, b, threshold in pairs:
        (mean_a, sd_a), (mean_b, sd_b) = (predicted(fits[n], epochs[n]) for n in (a, b))
        k = band_multiplier(sigmas, welch_dof([(sd_a, seeds - 1), (sd_b, seeds - 1)]))
        ratios.append(abs(mean_a - mean_b - threshold) / (k * math.hypot(sd_a, sd_b)))
    return min(ratios)


def predictions(rows: Mapping[str, RowCurves], seeds: int, sigmas: float) -> dict:
    """Per claim: the predicted ratio at each scale (3 and 5 seeds) and its training cost."""
    fits = {n: fit for n, r in rows.items() if r.epochs >= 4 and (fit := fit_curve(r))}
    out = {}
    for number, pairs in PREDICTED_MARGINS.items():
        names = {n for pair in pairs for n in pair[:2]}
        if "cnn1d_20k" not in rows or not names <= fits.keys():
            out[number] = {"missing_fit": sorted(names - fits.keys())}
            continue
        table = []
        for epochs_20k in PREDICTED_EPOCHS_20K:
            epochs = row_epochs(rows, epochs_20k)
            row = {"epochs": {n: round(epochs[n], 1) for n in sorted(names)}}
            for n_seeds in sorted({seeds, 4, 5}):  # the study's, and the desk profile's
                ratio = predicted_ratio(fits, pairs, epochs, n_seeds, sigmas)
                row[f"ratio_{n_seeds}_seeds"] = round(ratio, 3)
                per_seed = sum(rows[n].cost_s(epochs[n]) / len(rows[n].histories) for n in names)
                row[f"cost_s_{n_seeds}_seeds"] = round(per_seed * n_seeds)
            table.append(row)
        out[number] = {"scales": table}
    return out


def analyse(precision: str, seeds: int) -> dict:
    """Per claim: its margins and ratios at every scale of the grid, the cheapest decidable
    scale, and per row the fitted curves."""
    import itertools

    rows = load_rows(precision, seeds)
    config = claim_config()
    result: dict = {"precision": precision, "seeds": seeds, "rows": {}, "claims": {}}
    for name, row in rows.items():
        result["rows"][name] = {
            "epochs": row.epochs,
            "samples": row.config["samples"],
            "s_per_sample_epoch": row.s_per_sample_epoch,
            "val_mae": {e: [round(v, 4) for v in row.mean_sd(e)] for e in row.grid()},
            "fit": fit_curve(row) if row.epochs >= 4 else None,
        }
    for number, names in CLAIM_ROWS.items():
        if any(n not in rows for n in names):
            continue
        scales = []
        for combo in itertools.product(*(rows[n].grid() for n in names)):
            scale = dict(zip(names, combo, strict=True))
            if len({scale[n] for n in TIED if n in scale}) > 1:
                continue  # the transfer stage trains both inits for the same epochs
            v = evaluate(number, rows, scale, config)
            ratios = [c.ratio for c in v.comparisons]
            scales.append(
                {
                    "epochs": scale,
                    "cost_s": round(sum(rows[n].cost_s(e) for n, e in scale.items())),
                    "ratio": round(min(ratios), 3) if ratios else None,
                    "margins": {
                        c.label + f" vs {c.threshold:g}": [round(c.value, 4), round(c.band or 0, 4)]
                        for c in v.comparisons
                    },
                    "verdict": v.verdict,
                }
            )
        # Decided as the report decides: a verdict that is neither inconclusive nor untested
        # (one comparison decisively False decides, whatever the others' ratios).
        decidable = [s for s in scales if s["verdict"] not in ("inconclusive", "not testable")]
        chosen = min(decidable, key=lambda s: s["cost_s"]) if decidable else None
        result["claims"][number] = {
            "rows": names,
            "scales": scales,
            "chosen": chosen["epochs"] if chosen else None,
            "chosen_cost_s": chosen["cost_s"] if chosen else None,
        }
    result["predicted"] = predictions(rows, seeds, config.sigmas)
    # Claims 3 and 4 are timing alone: the per-sample epoch-time ratios at the paper's batches
    # (this machine's, stacked seeds: each seed's share of an epoch).
    rate = {n: r.s_per_sample_epoch for n, r in rows.items()}
    if {"cnn2d", "cnn1d_20k"} <= rate.keys():
        result["claim3_per_sample_ratio"] = round(rate["cnn2d"] / rate["cnn1d_20k"], 3)
    if {"cnn1d_200k", "cnn1d_20k"} <= rate.keys():
        result["claim4_per_sample_ratio"] = round(rate["cnn1d_200k"] / rate["cnn1d_20k"], 3)
    return result


def train_row(row: StudyRow, seeds: int, precision: str) -> None:
    """Train the seeds of `row` whose history is missing or shorter than asked."""
    from scanloc.models.stacked_ensemble import fit_stacked

    cfg = composed(row)
    run = cfg["experiment"] if row.config == "train" else cfg["transfer"]
    wanted = row_seeds(cfg, row, seeds)
    todo = [
        s for s in wanted if (h := history(precision, row.name, s)) is None or len(h) < row.epochs
    ]
    if not todo:
        return
    init_from = None
    if row.init == "pretrained":  # the study's own map-1 1D CNN, its first seed's best model
        source = composed(StudyRow("cnn1d_20k", "train", 0))
        source_row = next(r for r in ROWS if r.name == "cnn1d_20k")
        init_from = (
            row_dir(precision, "cnn1d_20k", row_seeds(source, source_row, 1)[0]) / "model.pt"
        )
        if not init_from.is_file():
            raise SystemExit(f"{init_from}: train cnn1d_20k first (it is the pretrained init)")
    start = time.perf_counter()
    fit_stacked(
        model_cfg=cfg["model"]["net"],
        dataset_dir=SYNTHETIC or ROOT / cfg["dataset_dir"],
        out_dirs=[row_dir(precision, row.name, s) for s in todo],
        seeds=todo,
        epochs=row.epochs,
        batch_size=int(run["batch_size"]),
        lr=float(cfg["model"]["lr"]),
        lr_decay=float(cfg["model"]["lr_decay"]),
        max_samples=int(row.samples or run["samples"]),
        trainer_cfg={"accelerator": "cpu", "precision": precision, "deterministic": True},
        init_from=init_from,
    )
    seconds = time.perf_counter() - start
    samples = int(row.samples or run["samples"])
    cost = {"seeds": len(todo), "epochs": row.epochs, "samples": samples, "seconds": seconds}
    cost["s_per_sample_epoch"] = seconds / (len(todo) * row.epochs * samples)
    (OUT / precision / row.name / "cost.json").write_text(json.dumps(cost, indent=1))
    print(f"{row.name}: seeds {todo}, {row.epochs} epochs, {seconds:.0f} s", flush=True)


def quick(tmp: Path, args: argparse.Namespace) -> None:
    """Every row 4 epochs of 300 synthetic scans, into `tmp`: checks the study runs end to end."""
    from train_throughput import logging_off, write_synthetic_dataset

    global OUT, ROWS, SYNTHETIC
    logging_off()
    OUT, SYNTHETIC = tmp / "runs", write_synthetic_dataset(tmp / "scans", 300)
    ROWS = tuple(replace(row, epochs=4, samples=300) for row in ROWS)
    for row in ROWS:
        train_row(row, args.seeds, args.precision)
    print(json.dumps(analyse(args.precision, args.seeds)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--precision", default="32-true", choices=["32-true", "bf16-mixed"])
    parser.add_argument("--analyse", action="store_true", help="analyse recorded histories only")
    parser.add_argument("--rows", nargs="*", default=[r.name for r in ROWS])
    parser.add_argument("--quick", action="store_true", help="tiny synthetic smoke run")
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    if args.quick:
        with tempfile.TemporaryDirectory(prefix="scanloc-claim-power-") as tmp:
            quick(Path(tmp), args)
        return
    if not args.analyse:
        from train_throughput import logging_off

        logging_off()
        for row in ROWS:
            if row.name in args.rows:
                train_row(row, args.seeds, args.precision)
    print(json.dumps(analyse(args.precision, args.seeds)))


if __name__ == "__main__":
    main()
