"""Build the reproduction report from the pipeline's artifacts: one self-contained HTML page
(figures embedded as data URIs, inline CSS, a Content-Security-Policy that forbids any request)
and a Markdown twin whose figures are PNG files under `<out_dir>/figures/`.

This module only orchestrates: load the artifacts (artifacts.py) and the localizer catalog
(localizers.py), check the paper's claims (claims.py), build every section of the registry
(sections/registry.py) in its order, render both documents (render/document.py) and return the
headline metrics (summary.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from scanloc.io import atomic_path
from scanloc.localize.catalog import CONF_DIR
from scanloc.report.artifacts import Artifacts, as_float, total_stage_seconds
from scanloc.report.claims import Verdict, check_claims
from scanloc.report.context import ReportContext
from scanloc.report.localizers import Localizers
from scanloc.report.paper import ROWS
from scanloc.report.render.document import Builder, Section, render_html, render_markdown
from scanloc.report.sections.registry import SECTIONS
from scanloc.report.summary import headline_metrics
from scanloc.report.verdicts import ClaimConfig, verdict_legend

TITLE = "scanloc: reproducing “Deep Learning Localization” (Dietrich 2017)"


def summary_line(verdicts: list[Verdict], profile: str) -> str:
    """The sentence under the title: what this is, the profile, the verdicts by kind."""
    by_verdict: dict[str, list[str]] = {}
    for claim in verdicts:
        by_verdict.setdefault(claim.verdict, []).append(str(claim.number))
    counts = "; ".join(f"{v}: {', '.join(n)}" for v, n in by_verdict.items())
    return (
        f"A reproduction of R. Dietrich's 2017 paper: neural networks regress a robot's pose "
        f"from one laser scan in a known map and are compared with Monte Carlo localization "
        f"(amcl). Profile '{profile}'. Paper claims (section Paper claims) — {counts}."
    )


def build_sections(ctx: ReportContext) -> list[Section]:
    """Every section of the registry, in its order."""
    return [section for spec in SECTIONS for section in spec.build(ctx, spec)]


def build_report(
    root: Path,
    out_dir: Path,
    context: Mapping[str, Any],
    report_cfg: Mapping[str, Any],
    localizer_conf: Path = CONF_DIR,
) -> dict[str, Any]:
    """Write <out_dir>/report.html (self-contained), <out_dir>/report.md and
    <out_dir>/figures/*.png from the artifacts under `root`; return the headline metrics.

    context: {"profile": str, "params": dict (the run's knobs), "git_commit": str | None,
    "sites": {site: kind, in params.yaml's order}};
    report_cfg: conf/report.yaml (`claims`, `seed_spread`, `inconclusive_sigmas`,
    `figure_localizers`, `site_runs`); localizer_conf: the localizer configs (conf/localizer).
    """
    root, out_dir = Path(root), Path(out_dir)
    artifacts = Artifacts.load(root)
    profile = str(context.get("profile", "?"))
    claim_config = ClaimConfig.from_config(report_cfg, profile)
    verdicts = check_claims(artifacts, claim_config)
    if "figure_localizers" not in report_cfg:
        raise KeyError("conf/report.yaml: field 'figure_localizers': missing")
    ctx = ReportContext(
        builder=Builder(root, out_dir, context),
        artifacts=artifacts,
        localizers=Localizers.load(localizer_conf),
        verdicts=verdicts,
        legend=verdict_legend(claim_config),
        run=context,
        figure_localizers=[str(name) for name in report_cfg["figure_localizers"]],
        site_runs={kind: list(runs) for kind, runs in report_cfg["site_runs"].items()},
    )
    sections = build_sections(ctx)
    b = ctx.builder
    for stale in b.figure_dir.glob("*.png"):
        if stale.name not in b.written:
            stale.unlink()
    summary = summary_line(verdicts, profile)
    with atomic_path(out_dir / "report.md") as tmp:
        tmp.write_text(render_markdown(sections, TITLE, summary), encoding="utf-8")
    with atomic_path(out_dir / "report.html") as tmp:
        tmp.write_text(render_html(sections, TITLE, summary, b.figure_dir), encoding="utf-8")
    # The metrics file's val_mae: the mean over the row's own seeds (one seed at the laptop
    # profile), as compare reads it for experiments that only train.
    table1 = {
        row: as_float(artifacts.runs[row].metrics.get("val_mae"))
        for row in ROWS
        if row in artifacts.runs
    }
    return headline_metrics(
        table1,
        artifacts.localization,
        ctx.maps,
        verdicts,
        total_stage_seconds(root),
        ctx.real_logs,
    )
