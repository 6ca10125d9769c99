"""Section "The learned localizer on real scans": the laser's corruptions as measured on each
log's mapping part, the residuals of real and simulated scans against the map at the same
poses, the ablation of the training stream's corruptions and of the verification on the
held-out real scans, and the reliability of the verified hypotheses' calibrated score."""

from __future__ import annotations

import numpy as np

from scanloc.evaluate.metrics import expected_calibration_error, reliability_bins
from scanloc.io import read_json
from scanloc.pose import recall_within
from scanloc.report.artifacts import LOCALIZE_DIRS, MAPS_DIR, METRICS_DIR, TRAJECTORIES
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render import learned_figures
from scanloc.report.render.document import Para, Table
from scanloc.report.render.tables import fixed

VERIFIED = "scanlocnet_verified"
ABLATION_DIR = METRICS_DIR / "real_ablation"
# (variant file, row label): the real_ablation stage's variants, after the pipeline's model's row
ABLATION_ROWS = (
    ("none", "ablation baseline: every measured corruption"),
    ("no_return", "without no returns"),
    ("short", "without short readings"),
    ("long", "without long readings"),
    ("noise", "without the Student-t noise (noise model instead)"),
    ("all", "without any (the noise model only: before this wave)"),
)
ABLATION_COLUMNS = (
    ("top1_recall", "top-1"),
    ("top5_recall", "top-5"),
    ("top20_recall", "top-20"),
    ("verified_top1_recall", "verified top-1"),
    ("calibration_ece", "calibration error"),
)
INTRO = (
    "Beyond the paper. A real laser differs from the scans simulated in its map: it misses "
    "returns, people and furniture cut beams short, glass and open doors let them through, and "
    "its range error is heavy-tailed. The real stage measures each of these on the log's "
    "mapping part only, against the scans rendered in the built map at the same laser poses "
    "(scanloc.real.residuals; data/maps/<log>/corruptions.yaml), and the learned localizer's "
    "training stream reproduces them (scanloc.sensor.corruptions). Each hypothesis is then "
    "verified against the map: refined by scan matching on the map's distance field, scored, "
    "given a calibrated probability of being within 0.5 m and 10° (a logistic fit on the "
    "map's simulated validation scans, never on a scored scan) and re-ranked "
    "(scanloc.localize.hypothesis_verification; the `scanlocnet_verified` localizer)."
)


def _measured_table(ctx: ReportContext) -> Table | None:
    rows = []
    for log in ctx.real_logs:
        path = ctx.builder.root / METRICS_DIR / f"real_{log}.json"
        residuals = read_json(path).get("laser_residuals") if path.is_file() else None
        if not residuals:
            continue
        fit = residuals["fitted"]
        rows.append(
            [
                log,
                str(residuals["scans"]),
                fixed(residuals["within_5cm"], percent=True),
                *(
                    f"{100 * fit[k]['rate']:.1f} % ({fit[k]['mean_run']:.1f})"
                    for k in ("no_return", "short", "long")
                ),
                f"{100 * fit['noise_scale_m']:.1f} cm, ν = {fit['noise_dof']:.1f}",
            ]
        )
    if not rows:
        return None
    header = [
        "log",
        "mapping scans",
        "beams within 5 cm",
        "no return (mean run)",
        "short > 0.3 m (run)",
        "long > 0.3 m (run)",
        "other beams: Student-t",
    ]
    return Table(header, rows)


def _ablation_table(ctx: ReportContext) -> Table | None:
    rows = []
    for log in ctx.real_logs:
        real = ctx.artifacts.localization.get(f"{log}_real") or {}
        raw, verified = real.get("scanlocnet", {}), real.get(VERIFIED, {})
        full = {k: raw.get(k) for k in ("top1_recall", "top5_recall", "top20_recall")}
        full["verified_top1_recall"] = verified.get("top1_recall")
        full["calibration_ece"] = verified.get("calibration_ece")
        variants = [("the pipeline's model (every measured corruption, denser training)", full)]
        paths = [ctx.builder.root / ABLATION_DIR / f"{log}_{v}.json" for v, _ in ABLATION_ROWS]
        if any(path.is_file() for path in paths):  # a log of params.yaml real_ablation_logs
            for path, (_, label) in zip(paths, ABLATION_ROWS, strict=True):
                variants.append((label, read_json(path) if path.is_file() else {}))
        for label, figures in variants:
            cells = [
                fixed(figures.get(key), 3) if key == "calibration_ece"
                else fixed(figures.get(key), percent=True)
                for key, _ in ABLATION_COLUMNS
            ]  # fmt: skip
            rows.append([log, label, *cells])
    if not rows:
        return None
    return Table(["log", "training stream", *(title for _, title in ABLATION_COLUMNS)], rows)


def _verified_runs(ctx: ReportContext) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{run: (top-1 calibrated scores, top-1 right)} of the verified localizer on each map's
    drive and each real log's held-out run."""
    root = ctx.builder.root
    runs = [f"{m}_drive" for m in ctx.maps] + [f"{log}_real" for log in ctx.real_logs]
    found = {}
    for run in runs:
        truth_path = root / TRAJECTORIES / run / "truth.npy"
        for folder in LOCALIZE_DIRS:
            path = root / folder / run / f"{VERIFIED}_hypotheses.npz"
            if path.is_file() and truth_path.is_file():
                with np.load(path) as data:
                    poses, scores = data["poses"], data["scores"]
                right = recall_within(poses[:, :1], np.load(truth_path))
                found[run] = (scores[:, 0], right)
    return found


def build(ctx: ReportContext, spec: SectionSpec) -> list:
    b = ctx.builder
    section = spec.section()
    section.blocks.append(Para(INTRO))
    measured = _measured_table(ctx)
    if measured is not None:
        section.blocks.append(Para("The laser as measured on each log's mapping part:"))
        section.blocks.append(measured)
    histograms = {}
    for log in ctx.real_logs:
        path = b.root / MAPS_DIR / log / "residuals.json"
        if path.is_file():
            histograms[log] = read_json(path)["histogram"]
    if histograms:
        section.blocks.append(
            b.figure(
                "real_residuals.png",
                "Reading minus the range the map predicts at the same laser pose, on each log's "
                "mapping part: real scans, scans simulated with the noise model alone (what the "
                "learned localizer trained on before) and with the measured corruptions.",
                lambda p: learned_figures.plot_residuals(histograms, p),
            )
        )
    ablation = _ablation_table(ctx)
    if ablation is not None:
        section.blocks.append(
            Para(
                "Ablation on the held-out real scans (the evaluation part of each log): the "
                "pipeline's model, then the real_ablation stage's trainings, with every "
                "measured corruption (the ablation's baseline) and without each one, all at "
                "the simulated maps' density of training scans per cell, so that its rows "
                "differ in their corruption alone (conf/real_ablation.yaml; on the logs of "
                "params.yaml `real_ablation_logs`, the others show the pipeline's model "
                "only). Top-K: "
                "the truth within 0.5 m and 10° of one of the K best hypotheses; verified "
                "top-1: the best after verification; calibration error: the expected "
                "calibration error of its score (10 bins)."
            )
        )
        section.blocks.append(ablation)
    verified = _verified_runs(ctx)
    if verified:
        curves = {run: reliability_bins(s, r) for run, (s, r) in verified.items()}
        rows = [
            [
                run,
                str(len(s)),
                fixed(float(r.mean()), percent=True),
                fixed(float(s.mean()), percent=True),
                fixed(expected_calibration_error(s, r), 3),
            ]
            for run, (s, r) in verified.items()
        ]
        header = ["run", "scans", "verified top-1 right", "mean score", "calibration error"]
        section.blocks.append(Table(header, rows))
        section.blocks.append(
            b.figure(
                "verified_reliability.png",
                "Reliability of the verified top-1 hypothesis' calibrated score: the share "
                "right per score bin against the bin's mean score (the diagonal is perfect).",
                lambda p: learned_figures.plot_reliability(curves, p),
            )
        )
    return [section]


SECTION = SectionSpec("real-learned", "The learned localizer on real scans", build)
