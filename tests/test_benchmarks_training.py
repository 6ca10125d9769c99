"""The training benchmarks run (--quick) and end with their JSON figures.

Run in this process (runpy) rather than in a subprocess: importing torch and Lightning again
would take most of the time."""

from __future__ import annotations

import json
import runpy
import sys
from pathlib import Path

import pytest
import torch

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.mark.parametrize(
    ("script", "keys"),
    [
        (
            "train_throughput.py",
            {
                "samples_per_s",
                "baseline_samples_per_s",
                "speedup_vs_dataloader",
                "ceiling_fraction",
            },
        ),
        ("ensemble_train.py", {"speedup_vs_sequential", "max_param_diff"}),
        ("precision_noise.py", {"fp32_mean", "bf16_mean", "fp32_seed_std", "epoch_speedup"}),
    ],
)
def test_quick_run_prints_figures(
    script: str, keys: set[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    monkeypatch.setattr(sys, "argv", [script, "--quick", "--threads", "1"])
    threads = torch.get_num_threads()
    try:
        runpy.run_path(str(BENCHMARKS / script), run_name="__main__")
    finally:
        torch.set_num_threads(threads)
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert keys <= figures.keys()
    assert all(figures[k] > 0 for k in keys - {"max_param_diff"})
    if "max_param_diff" in figures:
        assert figures["max_param_diff"] == 0.0  # the loop mode reproduces lone training exactly


@pytest.mark.slow  # 18 trainings, the 2D CNN's among them: about a minute
def test_claim_power_quick_run_covers_every_row_and_claim(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The power study end to end on synthetic scans: every row trained over 3 seeds, each
    claim's margins at every scale of its grid, by the report's own rule."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    monkeypatch.setattr(sys, "argv", ["claim_power.py", "--quick", "--threads", "1"])
    threads = torch.get_num_threads()
    try:
        runpy.run_path(str(BENCHMARKS / "claim_power.py"), run_name="__main__")
    finally:
        torch.set_num_threads(threads)
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(figures["rows"]) == {
        "mlp",
        "cnn1d_20k",
        "cnn1d_200k",
        "cnn2d",
        "transfer_scratch",
        "transfer_pretrained",
    }
    assert set(figures["claims"]) == {"1", "2", "5", "6"}
    for claim in figures["claims"].values():
        assert len(claim["scales"]) >= 3 and all(s["cost_s"] > 0 for s in claim["scales"])
    assert figures["claim3_per_sample_ratio"] > 1  # the 2D CNN is the slower per scan
