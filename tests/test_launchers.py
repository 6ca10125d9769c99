"""Hydra launchers run for real: tiny training sweeps through submitit (local) and joblib, and
the train stage under DDP with two CPU processes. Each job trains one epoch on 64 random scans."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import yaml
from hydra import compose, initialize_config_dir
from hydra.plugins.launcher import Launcher
from hydra.utils import get_class
from omegaconf import OmegaConf

from scanloc.data.scan_dataset import save_scan_dataset
from scanloc.sensor.laser import LaserSpec
from scanloc.stages._app import is_rank_zero, run_folder

REPO_ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = REPO_ROOT / "conf"
LAUNCHERS = {
    "local_parallel": "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher",
    "local_submitit": "hydra_plugins.hydra_submitit_launcher.submitit_launcher.LocalLauncher",
    "slurm": "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher",
}
TINY = ("experiment=cnn1d_20k", "experiment.epochs=1", "experiment.samples=64")


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """80 random scans in the data/scans/<dataset>/ format (every 8th one for validation)."""
    spec = LaserSpec()
    rng = np.random.default_rng(0)
    count = 80
    path = tmp_path_factory.mktemp("scans") / "tiny"
    ranges = rng.uniform(spec.range_min, spec.range_max, (count, spec.num_beams))
    poses = np.column_stack(
        [rng.uniform(0, 15, count), rng.uniform(0, 15, count), rng.uniform(-np.pi, np.pi, count)]
    )
    is_val = np.arange(count) % 8 == 0
    meta = {
        "map": {"name": "random"},
        "sensor": {**asdict(spec), "mode": "exact", "unknown_blocks": False},
        "seed": 0,
    }
    return save_scan_dataset(path, ranges, poses, is_val, meta)


def run_train(
    cwd: Path, *args: str, timeout: int = 300, stage: str = "train"
) -> subprocess.CompletedProcess[str]:
    """A training stage's app as DVC or a user runs it, from `cwd` with the repository's conf/."""
    env = dict(os.environ, SCANLOC_CONF=str(CONF_DIR))
    result = subprocess.run(
        [sys.executable, "-m", f"scanloc.stages.{stage}", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert result.returncode == 0, (
        f"{stage} {' '.join(args)} failed:\n{result.stdout}\n{result.stderr}"
    )
    return result


def check_metrics(metrics_path: Path) -> None:
    """One epoch on the first 64 of the 80 scans, split as the dataset marks them (every 8th
    for validation: 56 + 8), with a real validation MAE."""
    metrics = json.loads(metrics_path.read_text())
    assert math.isfinite(metrics["val_mae"]) and metrics["val_mae"] > 0, metrics
    assert metrics["epochs"] == 1, metrics
    assert (metrics["train_samples"], metrics["val_samples"]) == (56, 8), metrics


@pytest.mark.parametrize("launcher", sorted(LAUNCHERS))
def test_launcher_config_composes(launcher: str, tmp_path: Path):
    """The plugin's schema accepts every field (a misspelt one fails here) and our settings
    override the plugin's defaults (a file in the wrong package would leave them unset)."""
    sweep = tmp_path / "sweep"
    overrides = [f"hydra/launcher={launcher}", f"hydra.sweep.dir={sweep}"]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
    assert cfg.hydra.launcher._target_ == LAUNCHERS[launcher]
    assert issubclass(get_class(cfg.hydra.launcher._target_), Launcher)  # the plugin is installed
    node = OmegaConf.to_container(cfg.hydra.launcher, resolve=False)
    ours = yaml.safe_load((CONF_DIR / "hydra" / "launcher" / f"{launcher}.yaml").read_text())
    assert isinstance(node, dict)
    for key, value in ours.items():
        if key != "defaults":
            assert node[key] == value, key
    # submitit keeps its logs beside the sweep's job folders
    if "submitit_folder" in node:
        assert Path(cfg.hydra.launcher.submitit_folder).parent.parent == sweep


@pytest.mark.slow  # 15-25 s each: the launcher's processes import torch and Lightning
@pytest.mark.parametrize("launcher", ["local_submitit", "local_parallel"])
def test_sweep_runs_each_job_into_its_own_folder(launcher: str, tiny_dataset: Path, tmp_path: Path):
    sweep = tmp_path / "sweep"
    run_train(
        tmp_path,
        "-m",
        f"hydra/launcher={launcher}",
        *TINY,
        "model.lr=0.003,0.006",
        f"dataset_dir={tiny_dataset}",
        f"hydra.sweep.dir={sweep}",
    )
    metrics_files = sorted(sweep.rglob("train_cnn1d_20k.json"))
    job_dirs = sorted({p.parents[2] for p in metrics_files if p.parent.name == "metrics"})
    assert len(job_dirs) == 2, f"expected two job folders under {sweep}: {metrics_files}"
    lrs = []
    for job_dir in job_dirs:
        # the pipeline's layout, inside the job's folder
        check_metrics(job_dir / "reports/metrics/train_cnn1d_20k.json")
        model_dir = job_dir / "models/cnn1d_20k"
        assert (model_dir / "model.pt").is_file() and (model_dir / "history.csv").is_file()
        assert (job_dir / "reports/timing/train_cnn1d_20k.json").is_file()
        run_config = json.loads((model_dir / "config.json").read_text())
        job_cfg = yaml.safe_load((job_dir / ".hydra" / "config.yaml").read_text())
        assert run_config["lr"] == job_cfg["model"]["lr"]
        lrs.append(run_config["lr"])
    assert sorted(lrs) == [0.003, 0.006]
    # A sweep never writes into the pipeline's outputs (models/, the metrics under reports/).
    written = [p for d in ("models", "reports") for p in (tmp_path / d).rglob("*") if p.is_file()]
    assert not written, f"the sweep wrote pipeline outputs: {written}"


def test_transfer_sweep_writes_into_its_job_folder(tiny_dataset: Path, tmp_path: Path):
    sweep = tmp_path / "sweep"
    run_train(
        tmp_path,
        "-m",
        "init=scratch",
        "transfer.epochs=1",
        "transfer.samples=64",
        f"dataset_dir={tiny_dataset}",
        f"hydra.sweep.dir={sweep}",
        stage="transfer",
    )
    job_dir = sweep / "0"
    check_metrics(job_dir / "reports/metrics/transfer_scratch.json")
    assert (job_dir / "models/transfer/scratch/model.pt").is_file()
    assert (job_dir / "reports/timing/transfer_scratch.json").is_file()  # the stage's wall time
    written = [p for d in ("models", "reports") for p in (tmp_path / d).rglob("*") if p.is_file()]
    assert not written, f"the sweep wrote pipeline outputs: {written}"


def test_only_rank_zero_writes(monkeypatch: pytest.MonkeyPatch) -> None:
    for key in ("RANK", "LOCAL_RANK"):
        monkeypatch.delenv(key, raising=False)
    assert is_rank_zero()
    monkeypatch.setenv("LOCAL_RANK", "1")
    assert not is_rank_zero()
    monkeypatch.setenv("RANK", "0")  # the global rank decides
    assert is_rank_zero()


@pytest.mark.slow  # about 30 s: three processes import torch and Lightning
def test_ddp_two_cpu_processes(tiny_dataset: Path, tmp_path: Path):
    """conf/trainer/ddp.yaml with its device settings switched to two CPU processes."""
    out_dir, metrics = tmp_path / "model", tmp_path / "metrics.json"
    result = run_train(
        tmp_path,
        "trainer=ddp",
        "++trainer.accelerator=cpu",
        "++trainer.devices=2",
        "++trainer.strategy=ddp_spawn",
        *TINY,
        "experiment.batch_size=4",  # 2 per process; DDP drops an incomplete last batch
        f"dataset_dir={tiny_dataset}",
        f"out_dir={out_dir}",
        f"metrics_path={metrics}",
        f"checkpoint_dir={tmp_path / 'checkpoints'}",
    )
    assert "Starting with 2 processes" in result.stdout + result.stderr
    check_metrics(metrics)
    assert (out_dir / "model.pt").is_file()
    assert json.loads((out_dir / "config.json").read_text())["batch_size"] == 4


def test_a_run_by_hand_gets_a_readable_flat_folder() -> None:
    """runs/<stage>/<entry>-<hash>/: the entry's name, never the overrides' paths as folders."""
    bag = "bag=/data/robot.bag,map_yaml=/data/maps/office/map.yaml,name=office,profile=smoke"
    folder = run_folder(bag)
    assert folder.startswith("office-") and "/" not in folder and len(folder) == len("office-") + 8
    assert run_folder(bag) == folder != run_folder(bag.replace("smoke", "laptop"))
    assert run_folder("dataset=map_validation,dataset.map=intel").startswith("intel-")
    assert run_folder("log=/data/logs/aces.log.gz").startswith("aces.log.gz-")
    assert run_folder("model.lr=0.003").startswith("run-")
    assert run_folder("") == "default"
