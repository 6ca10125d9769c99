"""Localizers over filter seeds (the localize_seeds stage) and their summary (evaluate):
seeded localizers run once per seed and differ between seeds, deterministic ones run once; the
summary follows the seeds contract (mean, 95 % interval, n_seeds, per-seed values)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from scanloc.estimates import estimate_table
from scanloc.evaluate.seeds import evaluate_filter_seeds
from scanloc.localize.kinds import with_seed
from scanloc.localize.mcl.config import MclConfig
from scanloc.stages.localize_seeds import seed_runs
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import save_trajectory
from scanloc.world.map_server import save_map
from small_world import small_map, ug01_scans

REPO = Path(__file__).resolve().parents[1]


def test_seeded_kinds_run_per_seed_and_the_others_once() -> None:
    cfg = OmegaConf.create({"filter_seeds": [3, 4, 5]})
    localizers = {
        "pf": {"meta": {"kind": "particle_filter"}},
        "net": {"meta": {"kind": "learned"}, "learned": {"model": "m.pt"}},
        "hy": {"meta": {"kind": "particle_filter"}, "proposal": {"type": "learned"}},
    }
    assert seed_runs(cfg, localizers) == [
        ("pf", 3), ("pf", 4), ("pf", 5), ("net", 3), ("hy", 3), ("hy", 4), ("hy", 5)
    ]  # fmt: skip
    with pytest.raises(ValueError, match=r"filter_seeds.*distinct"):
        seed_runs(OmegaConf.create({"filter_seeds": [1, 1]}), localizers)
    with pytest.raises(ValueError, match=r"section 'meta': key 'kind': expected one of"):
        seed_runs(cfg, {"old": {"meta": {"kind": "amcl"}}})


def test_a_seed_is_set_in_the_filter_section() -> None:
    """The seed a run uses goes where the filter reads it, beside the section's other keys,
    and the config it came from is left alone."""
    cfg = {"meta": {"name": "amcl", "kind": "particle_filter"}, "filter": {"max_particles": 300}}
    seeded = with_seed(cfg, 4)
    assert seeded["filter"] == {"max_particles": 300, "seed": 4}
    assert seeded["meta"] == cfg["meta"] and "seed" not in cfg["filter"]
    assert MclConfig.from_sections(seeded, "amcl.yaml").filter.seed == 4
    assert with_seed({"meta": cfg["meta"]}, 2)["filter"] == {"seed": 2}
    # a deterministic kind has no `filter` section to put a seed in: its config stays as it is
    learned = {"meta": {"name": "scanlocnet", "kind": "learned"}, "learned": {"model": "m.pt"}}
    assert with_seed(learned, 4) == learned


@pytest.fixture(scope="module")
def small_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("seeds")
    grid = small_map()
    save_map(grid, root / "map" / "map.yaml")
    traj = drive_trajectory(grid, 30, seed=1, clearance=0.25)
    save_trajectory(traj, root / "run", ug01_scans(grid, traj.truth, seed=2), meta={})
    return root


def test_the_stage_writes_one_table_per_seed(small_run: Path) -> None:
    out = small_run / "out"
    cmd = [sys.executable, "-m", "scanloc.stages.localize_seeds", "trajectory=tiny"]
    cmd += [f"trajectory_dir={small_run / 'run'}", f"map_yaml={small_run / 'map' / 'map.yaml'}"]
    cmd += ["compared=[amcl]", "filter_seeds=[0,1,2]"]
    cmd += ["++localizers.amcl.filter.max_particles=300", f"out_dir={out}"]
    cmd += [f"timing_path={small_run / 'timing.json'}", f"timing_dir={small_run / 'timing'}"]
    cmd += [f"hydra.run.dir={small_run / 'hydra'}"]
    env = os.environ | {"PYTHONPATH": str(REPO / "src")}
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    tables = [pd.read_csv(out / f"s{seed}" / "amcl.csv") for seed in range(3)]
    assert not tables[0][["x", "y"]].equals(tables[1][["x", "y"]])  # the seed reaches the filter
    summary = evaluate_filter_seeds(small_run / "run", out)["amcl"]
    assert summary["n_seeds"] == 3 and sorted(summary["seeds"]) == ["0", "1", "2"]


def test_the_summary_follows_the_seeds_contract(small_run: Path, tmp_path: Path) -> None:
    truth = np.load(small_run / "run" / "truth.npy")
    steps = len(truth)
    offsets = {0: 0.1, 1: 0.2, 2: 0.3}  # constant position errors: the RMSE is the offset
    for seed, dx in offsets.items():
        means = truth + np.array([dx, 0.0, 0.0])
        table = estimate_table(np.arange(steps), np.arange(steps) * 0.1, means, None, 1)
        (tmp_path / f"s{seed}").mkdir()
        table.to_csv(tmp_path / f"s{seed}" / "pf.csv", index=False)
    (tmp_path / "s0" / "net.csv").write_text((tmp_path / "s0" / "pf.csv").read_text())
    figures = evaluate_filter_seeds(small_run / "run", tmp_path)
    pf = figures["pf"]
    assert pf["n_seeds"] == 3
    assert pf["pos_err_rmse_m"] == pytest.approx(0.2)
    assert pf["pos_err_rmse_m_max"] == pytest.approx(0.3)
    half = 4.302652729911275 * 0.1 / np.sqrt(3)  # Student t(2) 97.5 % × s / √n
    assert pf["pos_err_rmse_m_ci95_low"] == pytest.approx(max(0.0, 0.2 - half))
    assert pf["pos_err_rmse_m_ci95_high"] == pytest.approx(0.2 + half)
    assert pf["seeds"]["1"]["pos_err_rmse_m"] == pytest.approx(0.2)
    net = figures["net"]  # deterministic: one seed, the interval is its value
    assert net["n_seeds"] == 1
    assert net["pos_err_rmse_m_ci95_low"] == net["pos_err_rmse_m"] == pytest.approx(0.1)
