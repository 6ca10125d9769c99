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
