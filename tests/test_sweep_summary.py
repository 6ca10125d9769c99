"""The sweep summary callback: summary.csv of a real two-job multirun in which one job fails on
purpose, and the table built from hand-made job folders."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hydra.core.utils import JobReturn, JobStatus

from scanloc.io import write_json
from scanloc.sweep_summary import RECORD, job_record, summary_rows, write_summary
from synthetic_scans import write_synthetic_scans

REPO_ROOT = Path(__file__).resolve().parents[1]


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_two_job_multirun_with_a_failing_job(tmp_path: Path) -> None:
    """The README's sweep from the repository root; job 1 asks for 0 epochs, which the train
    stage rejects. Hydra then exits non-zero, and summary.csv still holds both jobs."""
    dataset = write_synthetic_scans(tmp_path / "scans", count=96)
    sweep = tmp_path / "sweep"
    env = dict(os.environ)
    env.pop("DVC_STAGE", None)
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "scanloc.stages.train",
            "-m",
            "experiment=cnn1d_20k",
            "profile=smoke",
            "experiment.samples=64",
            "experiment.epochs=1,0",
            f"dataset_dir={dataset}",
            f"checkpoint_dir={tmp_path / 'checkpoints'}",
            f"hydra.sweep.dir={sweep}",
        ],
        cwd=REPO_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode != 0, "the job with 0 epochs should have failed the sweep"
    assert "epochs must be >= 1" in result.stderr, result.stderr
    rows = read_csv(sweep / "summary.csv")
    assert [row["job"] for row in rows] == ["0", "1"], rows
    ok, failed = rows
    assert ok["status"] == "ok" and ok["error"] == ""
    assert float(ok["val_mae"]) > 0 and float(ok["epoch_s"]) > 0
    assert float(ok["job_wall_s"]) > 0
    assert (ok["experiment.epochs"], failed["experiment.epochs"]) == ("1", "0")
    assert failed["status"] == "failed"
    assert failed["error"] == "ValueError: epochs must be >= 1, got 0"
    assert failed["val_mae"] == "" and float(failed["job_wall_s"]) >= 0


def fake_job(sweep: Path, num: int, overrides: list[str], record: dict | None) -> Path:
    """A job folder as a multirun leaves it: Hydra's .hydra/ files and, unless None, the
    callback's record."""
    job = sweep / str(num)
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    (job / ".hydra" / "hydra.yaml").write_text(yaml.safe_dump({"hydra": {"job": {"num": num}}}))
    if record is not None:
        write_json(job / RECORD, {"job": num, "overrides": overrides, **record})
    return job


def test_rows_from_hand_made_job_folders(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    ok = fake_job(sweep, 0, ["model.lr=0.003", "+extra=a"], {"status": "ok", "job_wall_s": 2.5})
    write_json(ok / "reports/metrics/train_mlp.json", {"val_mae": 1.5, "device": {"cores": 2}})
    write_json(ok / "reports/metrics/other.json", {"val_mae": 1.7, "note": "text", "flag": True})
    write_json(ok / "reports/summary.json", {"t1_mlp": 1.5, "wall_s": 10.0, "pos_amcl": None})
    fake_job(sweep, 10, ["model.lr=0.006"], {"status": "failed", "error": "ValueError: bad"})
    fake_job(sweep, 2, ["model.lr=0.012"], None)  # killed before the callback's on_job_end

    path = write_summary(sweep)
    rows = read_csv(path)
    assert [r["job"] for r in rows] == ["0", "2", "10"]  # by job number, not by folder name
    header = list(rows[0])
    assert header[:3] == ["job", "status", "job_wall_s"] and header[-1] == "error"
    first, killed, failed = rows
    assert first["model.lr"] == "0.003" and first["extra"] == "a"
    # numbers only; a name that two files share is prefixed with the file's stem
    assert first["train_mlp.val_mae"] == "1.5" and first["other.val_mae"] == "1.7"
    assert first["device.cores"] == "2" and first["t1_mlp"] == "1.5" and first["wall_s"] == "10.0"
    assert not {"val_mae", "note", "flag", "pos_amcl"} & set(header)
    assert (first["status"], first["job_wall_s"], first["error"]) == ("ok", "2.5", "")
    assert (failed["status"], failed["error"]) == ("failed", "ValueError: bad")
    assert failed["model.lr"] == "0.006" and failed["train_mlp.val_mae"] == ""
    assert killed["status"] == "unfinished" and RECORD in killed["error"]
    assert len(summary_rows(sweep)) == 3


def test_bad_metrics_file_names_the_file(tmp_path: Path) -> None:
    job = fake_job(tmp_path, 0, [], {"status": "ok"})
    (job / "reports/metrics").mkdir(parents=True)
    (job / "reports/metrics/train_mlp.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"train_mlp\.json: expected a JSON object"):
        write_summary(tmp_path)


def test_record_of_a_failed_job_keeps_the_error_on_one_line() -> None:
    ret = JobReturn(overrides=["a=1"], status=JobStatus.FAILED)
    ret.return_value = RuntimeError("first line\n  second line")
    record = job_record(3, ret, 0.25)
    assert record == {
        "job": 3,
        "overrides": ["a=1"],
        "status": "failed",
        "error": "RuntimeError: first line second line",
        "job_wall_s": 0.25,
    }
    done = JobReturn(overrides=[], status=JobStatus.COMPLETED)
    done.return_value = 1.0
    assert job_record(0, done, None)["status"] == "ok"
    json.dumps(record)  # what the callback writes must be JSON
