"""The report's "learned localizer on real scans" section: the measured corruptions, the
residual figure, the ablation rows from the real_ablation stage's files and the reliability of
the verified hypotheses' score, read from a fabricated artifact tree (test_report's)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scanloc.evaluate.metrics import expected_calibration_error
from scanloc.report.sections.real_data import split_sentence
from test_report import CONTEXT, build, make_artifacts

HISTOGRAM = {
    "edges_m": np.linspace(-1, 1, 81).round(6).tolist(),
    "real": [0.01] * 80,
    "noise_model": [0.005] * 80,
    "corrupted": [0.009] * 80,
}
FITTED = {
    "no_return": {"rate": 0.031, "mean_run": 3.7},
    "short": {"rate": 0.024, "mean_run": 1.5},
    "long": {"rate": 0.036, "mean_run": 1.7},
    "noise_scale_m": 0.043,
    "noise_dof": 3.8,
}


def write(path: Path, doc: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))


@pytest.fixture(scope="module")
def report_md(tmp_path_factory) -> tuple[str, float]:
    root = make_artifacts(tmp_path_factory.mktemp("artifacts"))
    write(root / "data/maps/intel/residuals.json", {"histogram": HISTOGRAM})
    measured = {"scans": 456, "within_5cm": 0.634, "fitted": FITTED}
    write(root / "reports/metrics/real_intel.json", {"laser_residuals": measured})
    write(
        root / "reports/metrics/real_ablation/intel_all.json",
        {"top1_recall": 0.185, "top5_recall": 0.262, "verified_top1_recall": 0.341},
    )
    truth = np.load(root / "data/trajectories/sparse_obstacles_drive/truth.npy")
    poses = np.repeat(truth[:, None], 2, axis=1)
    poses[::3, 0, 0] += 2.0  # every third top-1 is wrong
    scores = np.tile([[0.8, 0.1]], (len(truth), 1))
    np.savez(
        root / "reports/localize/sparse_obstacles_drive/scanlocnet_verified_hypotheses.npz",
        poses=poses,
        scores=scores,
    )
    right = np.arange(len(truth)) % 3 != 0
    sites = CONTEXT["sites"] | {"intel": "log", "fr079": "log"}
    build(root, CONTEXT | {"sites": sites})  # fr079: no ablation files
    text = (root / "reports/report.md").read_text()
    return text, expected_calibration_error(scores[:, 0], right)


def test_the_section_shows_the_measured_laser_and_the_residuals(report_md) -> None:
    text, _ = report_md
    assert ">The learned localizer on real scans</h2>" in text
    row = "| intel | 456 | 63.4 % | 3.1 % (3.7) | 2.4 % (1.5) | 3.6 % (1.7) | 4.3 cm, ν = 3.8 |"
    assert row in text
    assert "real_residuals.png" in text


def test_the_ablation_rows_come_from_the_ablation_files(report_md) -> None:
    text, _ = report_md
    label = "without any (the noise model only: before this wave)"
    row = f"| intel | {label} | 18.5 % | 26.2 % | – | 34.1 % | – |"
    assert row in text
    assert "| intel | without short readings | – | – | – | – | – |" in text  # not run: dashes
    # a log outside real_ablation_logs shows its model's row only
    assert "| intel | ablation baseline: every measured corruption | – |" in text
    assert "| fr079 | the pipeline's model (every measured corruption, denser training) |" in text
    assert "| fr079 | without" not in text


def test_the_reliability_of_the_verified_score_is_measured(report_md) -> None:
    text, ece = report_md
    assert ece == pytest.approx(abs(2 / 3 - 0.8))
    assert f"| sparse_obstacles_drive | 60 | 66.7 % | 80.0 % | {ece:.3f} |" in text
    assert "verified_reliability.png" in text


def test_the_split_sentence_says_which_share_of_the_held_out_part_is_scored() -> None:
    """A profile that caps the scored scans (fr079 at laptop: 600 of 2395) says so; a log
    scored whole does not."""
    capped = {"mode": "window", "map_scans": 2396, "map_share": 0.5001, "evaluation_scans": 600}
    capped["evaluation_share"] = 0.1252
    text = split_sentence("fr079", {"split": capped})
    assert "the first 600 of its 2395 held-out scans" in text
    whole = {"mode": "window", "map_scans": 456, "map_share": 0.5011, "evaluation_scans": 454}
    whole["evaluation_share"] = 0.4989
    assert "held-out scans" not in split_sentence("intel", {"split": whole})
