"""The comparison page: on a hand-made multirun folder (every section, the better value marked,
nothing remote), in headless Chromium, and (slow) on two real smoke DVC experiments, where
`dvc exp show` also has to fit 120 columns."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from omegaconf import OmegaConf

from scanloc.io import write_json
from scanloc.report.compare import BEST_MARK, marked_row, write_compare
from scanloc.report.compare_runs import multirun_runs
from scanloc.stages.compare import load_runs
from test_report import _chromium, render_in_chromium

REPO_ROOT = Path(__file__).resolve().parents[1]
TRAJ = "sparse_obstacles_drive"
SECTIONS = ["params", "metrics", "curves", "errors"]


def fake_job(sweep: Path, num: int, lr: float, error_scale: float) -> Path:
    """A multirun job folder with the artifacts the page reads, small."""
    job = sweep / str(num)
    (job / ".hydra").mkdir(parents=True)
    overrides = [f"model.lr={lr}", "profile=smoke", f"seed={num}"]
    (job / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    write_json(
        job / "reports/summary.json",
        {
            "t1_mlp": 2.0 + num,
            "pos_amcl": 0.1 * error_scale,
            "top5_sparse_obstacles": 0.5 + 0.1 * num,
            "claims_reproduced": 3 - num,
            "wall_s": 100.0,
            "pos_hybrid": None,
        },
    )
    epochs = np.arange(1, 6)
    for row in ("mlp", "cnn1d_20k"):
        curve = pd.DataFrame(
            {"epoch": epochs, "train_mae": 3.0 / epochs * lr * 100, "val_mae": 3.5 / epochs}
        )
        (job / "models" / row).mkdir(parents=True)
        curve.to_csv(job / "models" / row / "history.csv", index=False)
    steps = 40
    t = np.arange(steps) * 0.5
    truth = np.column_stack([np.linspace(1, 9, steps), np.full(steps, 2.0), np.zeros(steps)])
    (job / "data/trajectories" / TRAJ).mkdir(parents=True)
    np.save(job / "data/trajectories" / TRAJ / "truth.npy", truth)
    (job / "reports/localize" / TRAJ).mkdir(parents=True)
    rng = np.random.default_rng(num)
    for k, name in enumerate(("amcl", "scanlocnet", "hybrid")):
        noise = error_scale * (k + 1) * 0.05 * rng.standard_normal((steps, 2))
        table = pd.DataFrame(
            {
                "step": np.arange(steps),
                "t": t,
                "x": truth[:, 0] + noise[:, 0],
                "y": truth[:, 1] + noise[:, 1],
                "theta": truth[:, 2],
            }
        )
        table.to_csv(job / "reports/localize" / TRAJ / f"{name}.csv", index=False)
    return job


@pytest.fixture(scope="module")
def two_jobs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("multirun")
    fake_job(folder, 0, 0.003, 1.0)
    fake_job(folder, 1, 0.006, 2.0)
    return folder


@pytest.fixture
def sweep(two_jobs: Path, tmp_path: Path) -> Path:
    """A copy of the two jobs, for a test to change."""
    return Path(shutil.copytree(two_jobs, tmp_path / "multirun"))


@pytest.fixture(scope="module")
def page(two_jobs: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("compare")
    write_compare(multirun_runs(two_jobs), out, f"the jobs of {two_jobs}")
    return out


def md_row(markdown: str, key: str) -> list[str]:
    line = next(line for line in markdown.splitlines() if line.startswith(f"| {key} |"))
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_page_has_every_section_and_marks_the_better_value(page: Path) -> None:
    html = (page / "compare.html").read_text()
    markdown = (page / "compare.md").read_text()
    for section in SECTIONS:
        assert f'<h2 id="{section}">' in html and f'<h2 id="{section}">' in markdown
    # parameters: only those that differ (profile is the same in both jobs)
    assert md_row(markdown, "model.lr") == ["model.lr", "0.003", "0.006"]
    assert md_row(markdown, "seed") == ["seed", "0", "1"]
    assert "| profile |" not in markdown
    # metrics: lower is better for t1_ / pos_, higher for top5_, claims_ unmarked, ties too
    assert md_row(markdown, "t1_mlp") == ["t1_mlp", f"2 {BEST_MARK}", "3"]
    assert md_row(markdown, "pos_amcl") == ["pos_amcl", f"0.1 {BEST_MARK}", "0.2"]
    assert md_row(markdown, "top5_sparse_obstacles")[1:] == ["0.5", f"0.6 {BEST_MARK}"]
    assert md_row(markdown, "claims_reproduced")[1:] == ["3", "2"]
    assert md_row(markdown, "wall_s")[1:] == ["100", "100"]
    assert md_row(markdown, "pos_hybrid")[1:] == ["—", "—"]
    # figures: two learning curves (mlp, cnn1d_20k), one position-error figure
    figures = sorted(p.name for p in (page / "figures").glob("*.png"))
    assert figures == ["curves_cnn1d_20k.png", "curves_mlp.png", "position_error.png"]
    for name in figures:
        assert f"](figures/{name})" in markdown
    assert html.count('src="data:image/png;base64,') == 3
    assert "cnn2d: no run has models/cnn2d/history.csv." in markdown
    assert "http://" not in html and "https://" not in html and "<script" not in html


def test_missing_artifacts_are_sentences(sweep: Path, tmp_path: Path) -> None:
    """A job that left nothing (a failed one) is a column of dashes and a sentence per section."""
    empty = sweep / "2"
    (empty / ".hydra").mkdir(parents=True)
    (empty / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(["model.lr=-1"]))
    write_compare(multirun_runs(sweep), tmp_path / "out", "test")
    markdown = (tmp_path / "out/compare.md").read_text()
    assert "No headline metrics for job 2." in markdown
    assert "Without a history: job 2." in markdown
    assert f"job 2: no data/trajectories/{TRAJ}/truth.npy" in markdown
    assert md_row(markdown, "pos_amcl") == ["pos_amcl", f"0.1 {BEST_MARK}", "0.2", "—"]


def test_runs_without_any_artifact(tmp_path: Path) -> None:
    for num in (0, 1):
        (tmp_path / "m" / str(num) / ".hydra").mkdir(parents=True)
        (tmp_path / "m" / str(num) / ".hydra" / "overrides.yaml").write_text("[]\n")
    sections = write_compare(multirun_runs(tmp_path / "m"), tmp_path / "out", "test")
    assert [s.id for s in sections] == SECTIONS
    markdown = (tmp_path / "out/compare.md").read_text()
    assert "The runs' parameters are identical." in markdown
    assert "No run has headline metrics" in markdown
    assert f"No run has estimates of amcl, scanlocnet, hybrid on {TRAJ}." in markdown
    assert not list((tmp_path / "out/figures").glob("*.png"))


def test_training_sweep_compares_table1_val_mae(tmp_path: Path) -> None:
    """A sweep of the train stage has no summary.json: Table 1's val_mae comes from the
    train metrics file."""
    for num, val in ((0, 1.25), (1, 1.5)):
        job = tmp_path / "m" / str(num)
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- model.lr={num}\n")
        write_json(job / "reports/metrics/train_cnn1d_20k.json", {"val_mae": val})
    write_compare(multirun_runs(tmp_path / "m"), tmp_path / "out", "test")
    markdown = (tmp_path / "out/compare.md").read_text()
    assert md_row(markdown, "t1_cnn1d_20k")[1:] == [f"1.25 {BEST_MARK}", "1.5"]


def test_marked_row() -> None:
    best = f"0.1 {BEST_MARK}"
    assert marked_row("lost_amcl", [0.2, 0.1, 0.1]) == ["0.2", best, best]  # ties: both
    assert marked_row("rec_hybrid", [None, 5, float("nan")]) == ["—", "5", "nan"]
    assert marked_row("something_else", [1, 2]) == ["1", "2"]


def test_bad_input_names_the_file_or_field(sweep: Path, tmp_path: Path) -> None:
    (sweep / "0/reports/summary.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"0/reports/summary\.json: not valid JSON"):
        write_compare(multirun_runs(sweep), tmp_path / "out", "test")
    (sweep / "0/reports/summary.json").write_text("{}")
    pd.DataFrame({"epoch": [1], "val_mae": [1.0]}).to_csv(sweep / "1/models/mlp/history.csv")
    with pytest.raises(ValueError, match=r"1/models/mlp/history\.csv: missing column\(s\)"):
        write_compare(multirun_runs(sweep), tmp_path / "out", "test")
    (tmp_path / "one/0/.hydra").mkdir(parents=True)
    (tmp_path / "one/0/.hydra/overrides.yaml").write_text("[]\n")
    with pytest.raises(ValueError, match="two or more job folders"):
        multirun_runs(tmp_path / "one")
    with pytest.raises(FileNotFoundError, match="no such folder"):
        multirun_runs(tmp_path / "absent")
    for experiments, multirun in (([], None), (["a", "b"], str(sweep))):
        cfg = OmegaConf.create({"experiments": experiments, "multirun": multirun, "repo": "."})
        with pytest.raises(ValueError, match="either experiments="):
            load_runs(cfg)


@pytest.mark.skipif(_chromium() is None, reason="no chromium installed (apt-get install chromium)")
def test_page_renders_offline_in_chromium(page: Path, tmp_path: Path) -> None:
    found = render_in_chromium(page / "compare.html", tmp_path / "profile")
    images = found["images"]
    assert len(images) == 3
    assert all(complete and width > 0 and height > 0 for complete, width, height, _ in images)
    assert found["sections"] == SECTIONS
    remote = [u for u in found["requests"] if not u.startswith(("file:", "data:", "about:"))]
    assert remote == []
    assert not [m for m in found["messages"] if "Content Security Policy" in m]
