"""`report` stage: the HTML and Markdown report, built only from the pipeline's artifacts."""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig

from scanloc.io import write_json
from scanloc.report.build import build_report
from scanloc.stages._app import stage_main, timed_stage, to_dict


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(
        ["git", *args], cwd=repo, capture_output=True, text=True, check=True
    ).stdout.strip()


def git_commit(repo: Path, source_paths: Sequence[str]) -> str | None:
    """The checked-out commit, with '+dirty' when a tracked file under `source_paths` differs
    from HEAD (the pipeline's code and config: dvc.lock and DVC outputs, which `dvc repro`
    rewrites while this stage runs, do not count); None outside a git checkout."""
    try:
        commit = _git(repo, "rev-parse", "HEAD")
        changed = _git(repo, "status", "--porcelain", "--untracked-files=no", "--", *source_paths)
    except (OSError, subprocess.CalledProcessError):
        return None
    return commit + ("+dirty" if changed else "")


def run_params(profile: str, sites: dict[str, str]) -> dict[str, Any]:
    """The run's knobs: its sites and profile, and what the profile's conf/scale files change."""
    params: dict[str, Any] = {"sites": sites, "profile": profile}
    for path in sorted(Path("conf/scale", profile).glob("*.yaml")):
        params[str(path)] = yaml.safe_load(path.read_text())
    return params


@stage_main("report")
def main(cfg: DictConfig) -> None:
    with timed_stage("report", cfg.timing_dir):
        profile = str(cfg.profile.name)
        sites: dict[str, str] = dict(cfg.sites or {})
        if not sites:  # dvc.yaml passes them; by hand: sites={name: kind, ...}
            raise ValueError(
                "conf/report.yaml: field 'sites': expected {name: kind} of at least one site "
                "(dvc.yaml passes sites.yaml's `site_list`)"
            )
        context = {
            "profile": profile,
            "params": run_params(profile, sites),
            "git_commit": git_commit(Path("."), [str(p) for p in cfg.source_paths]),
            "sites": sites,
        }
        headline = build_report(Path("."), Path(cfg.out_dir), context, to_dict(cfg))
        write_json(Path(cfg.summary_path), headline)


if __name__ == "__main__":
    main()
