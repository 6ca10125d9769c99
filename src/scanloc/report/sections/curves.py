"""Section "Learning curves": paper Fig. 7 (the Table 1 models) and Fig. 9 (the transfer runs),
with each run's final numbers."""

from __future__ import annotations

from collections.abc import Mapping

from scanloc.report.artifacts import TrainingRun
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.paper import ROWS, TRANSFER
from scanloc.report.render import figures
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.render.tables import num, seed_summary


def run_table(runs: Mapping[str, TrainingRun], names: Mapping[str, str]) -> Table:
    """One row per run of `names` that exists: its final and best MAE, errors and speed."""
    header = [
        "model",
        "final train MAE (first seed)",
        "final val. MAE (first seed)",
        "final val. MAE over its seeds",
        "best val. MAE (first seed)",
        "val. position error [m]",
        "val. heading error [°]",
        "s / epoch",
        "epochs",
        "parameters",
    ]
    rows = []
    for name, label in names.items():
        if name not in runs:
            continue
        run = runs[name]
        last = run.history.iloc[-1].to_dict() if len(run.history) else {}
        rows.append(
            [
                label,
                num(run.train_mae),
                num(run.val_mae),
                seed_summary([r.val_mae for r in run.seeds]),
                num(float(run.history["val_mae"].min()) if len(run.history) else None),
                num(last.get("val_pos_err_m")),
                num(last.get("val_heading_err_deg")),
                num(run.metrics.get("epoch_s"), 3),
                num(run.metrics.get("epochs")),
                num(run.metrics.get("params")),
            ]
        )
    return Table(header, rows)


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    b, runs = ctx.builder, ctx.artifacts.runs
    section = spec.section()
    rows = {ROWS[r]: runs[r].history for r in ROWS if r in runs}
    if rows:
        section.blocks.append(
            b.figure(
                "fig7_learning_curves.png",
                "Paper Fig. 7: training (a) and validation (b) loss (MAE over x [m], y [m], "
                "θ [rad]) of the four Table 1 models, log scale.",
                lambda p: figures.plot_learning_curves(rows, p, "Table 1 models (map 1)"),
            )
        )
        section.blocks.append(run_table(runs, ROWS))
    else:
        section.blocks.append(Para("No Table 1 training histories found under models/."))
    transfer = {TRANSFER[t]: runs[t].history for t in TRANSFER if t in runs}
    if transfer:
        section.blocks.append(
            b.figure(
                "fig9_transfer_curves.png",
                "Paper Fig. 9: training (a) and validation (b) loss of the 1D CNN on map 2, "
                "from random weights and pre-trained on map 1.",
                lambda p: figures.plot_learning_curves(transfer, p, "Transfer to map 2"),
            )
        )
        section.blocks.append(run_table(runs, TRANSFER))
    else:
        section.blocks.append(Para("Transfer runs (models/transfer/) not available."))
    return [section]


SECTION = SectionSpec("learning-curves", "Learning curves", build)
