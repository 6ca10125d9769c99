"""Section "Table 1": the paper's training parameters beside ours as run, and the transfer
runs of §4.3."""

from __future__ import annotations

from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.paper import PAPER_PRECISION, PAPER_TABLE1, ROWS, TABLE1_PARAMS, TRANSFER
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.render.tables import num, scale


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    runs = ctx.artifacts.runs
    section = spec.section()
    present = [r for r in ROWS if r in runs]
    if not present:
        section.blocks.append(Para("No Table 1 models found under models/."))
        return [section]
    section.blocks.append(
        Para(
            f"The paper's Table 1 beside the parameters as run in profile '{ctx.profile}' "
            "(models/<row>/config.json). The profile scales epochs and samples down to fit "
            "its time budget; the scale rows give the factor. The seeds row counts the runs "
            "of each row in this run (the 1D CNN 200k's further seeds are the ensemble's "
            "members): their spread is what the claims' verdicts measure margins against. "
            "Precision bf16-mixed is bf16 "
            "autocast with a float32 output layer (trainer precision auto, on CPUs with bf16 "
            "instructions). What was measured (docs/benchmarks.md, Precision): 4 seeds in "
            "each precision, where a Welch test found no significant difference of the mean "
            "validation MAE (|t| < 2); that is an absence of evidence at that sample size, "
            "not a proof that the two are equivalent."
        )
    )
    header = ["parameter"]
    for row in present:
        header += [f"{ROWS[row]} paper", f"{ROWS[row]} ours"]
    rows = []
    for key, title in TABLE1_PARAMS:
        line = [title]
        for row in present:
            line += [num(PAPER_TABLE1[row][key]), num(runs[row].config.get(key))]
        rows.append(line)
    for key, title in (("epochs", "epochs scale"), ("samples", "samples scale")):
        line = [title]
        for row in present:
            line += ["", scale(runs[row].config.get(key), PAPER_TABLE1[row][key])]
        rows.append(line)
    for key in ("dataset", "model"):
        line = [key]
        for row in present:
            line += ["", str(runs[row].config.get(key, "–"))]
        rows.append(line)
    line = ["seeds"]  # the paper trained each row once; ours: the seeds its spread comes from
    for row in present:
        line += ["1", str(len(runs[row].seeds))]
    rows.append(line)
    line = ["precision"]
    for row in present:
        line += [PAPER_PRECISION, str(runs[row].metrics.get("precision", "–"))]
    rows.append(line)
    section.blocks.append(Table(header, rows))
    transfer = [t for t in TRANSFER if t in runs]
    if transfer:
        section.blocks.append(
            Para(
                "Transfer to map 2 (paper §4.3): the same 1D CNN trained on map 2 from random "
                "weights and from the weights of the map-1 1D CNN (the paper pre-trained "
                "2000 epochs on 20k samples)."
            )
        )
        keys = ("dataset", "samples", "epochs", "batch_size", "lr", "lr_decay", "dropout")
        section.blocks.append(
            Table(
                ["run", *keys, "seeds"],
                [
                    [TRANSFER[t]]
                    + [num(runs[t].config.get(k)) for k in keys]
                    + [str(len(runs[t].seeds))]
                    for t in transfer
                ],
            )
        )
    return [section]


SECTION = SectionSpec("table-1", "Table 1: training parameters", build)
