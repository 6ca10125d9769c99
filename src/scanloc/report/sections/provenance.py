"""Section "Provenance": profile, git commit, the machine, package versions, each stage's wall
time and the resolved parameters."""

from __future__ import annotations

import importlib.metadata
import platform

import yaml

from scanloc.hardware import describe_machine
from scanloc.report.artifacts import stage_timings
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render.document import Para, Pre, Section, Table
from scanloc.report.render.tables import num

PACKAGES = ("torch", "lightning", "numpy", "hydra-core", "dvc", "numba", "matplotlib", "pandas")


def package_versions() -> list[list[str]]:
    rows = [["python", platform.python_version()]]
    for name in PACKAGES:
        try:
            rows.append([name, importlib.metadata.version(name)])
        except importlib.metadata.PackageNotFoundError:
            rows.append([name, "not installed"])
    return rows


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    section = spec.section()
    commit = ctx.run.get("git_commit") or "not recorded"
    section.blocks.append(
        Para(
            f"Profile: {ctx.profile}. Git commit: {commit}. Hardware (machine "
            f'that built this report): {describe_machine()}. Paper: R. Dietrich, "Deep Learning '
            'Localization", Oregon State University, 2017.'
        )
    )
    section.blocks.append(Table(["package", "version"], package_versions()))
    timings = stage_timings(ctx.artifacts.root)
    if timings:
        rows = [[stage, num(wall_s, 4)] for stage, wall_s in timings]
        rows.append(["total", num(sum(float(wall_s or 0.0) for _, wall_s in timings), 4)])
        section.blocks.append(Table(["stage", "wall time [s]"], rows))
    else:
        section.blocks.append(Para("No stage timings found (reports/timing/)."))
    params = ctx.run.get("params")
    if params:
        text = yaml.safe_dump(params, sort_keys=True, allow_unicode=True, default_flow_style=False)
        section.blocks.append(Pre("Resolved parameters", text))
    return [section]


SECTION = SectionSpec("provenance", "Provenance", build)
