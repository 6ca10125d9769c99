"""The report's figures of the learned localizer on real scans: the residuals of real and
simulated scans against the map at the same poses, and the reliability diagram of the verified
hypotheses' calibrated scores (deterministic PNG bytes, as figures.py)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from scanloc.report.render.figures import PALETTE, new_figure, save_png

RESIDUAL_SERIES = (
    ("real", "real scans", "#1f5fbf"),
    ("noise_model", "simulated, noise model only (the twin)", "#7f7f7f"),
    ("corrupted", "simulated with the measured corruptions", "#d62728"),
)


def plot_residuals(histograms: Mapping[str, Mapping[str, list[float]]], path: Path) -> Path:
    """One panel per log: the share of mapped beams per residual bin (reading − the range the
    map predicts at the same pose), log scale, for each of RESIDUAL_SERIES."""
    fig = new_figure(4.2 * len(histograms), 3.2)
    axes = np.atleast_1d(fig.subplots(1, len(histograms), squeeze=False)[0])
    for ax, (log, hist) in zip(axes, histograms.items(), strict=True):
        edges = np.asarray(hist["edges_m"])
        centres = 0.5 * (edges[1:] + edges[:-1])
        for key, label, color in RESIDUAL_SERIES:
            shares = np.asarray(hist[key], dtype=float)
            ax.step(centres, np.maximum(shares, 1e-5), where="mid", color=color, label=label)
        ax.set_yscale("log")
        ax.set_xlabel("reading − map's range [m]")
        ax.set_ylabel("share of beams per 2.5 cm")
        ax.set_title(log)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper left")
    return save_png(fig, path)


def plot_reliability(
    curves: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]], path: Path
) -> Path:
    """Share of top-1 hypotheses right against their mean calibrated score, per score bin, one
    line per run (bins with fewer than 5 scans are left out); the diagonal is perfect."""
    fig = new_figure(4.6, 4.0)
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], color="black", lw=0.8, ls="--", label="perfect calibration")
    for (run, (count, confidence, accuracy)), color in zip(curves.items(), PALETTE, strict=False):
        shown = count >= 5
        ax.plot(confidence[shown], accuracy[shown], "o-", color=color, ms=3, label=run)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("calibrated score of the top-1 hypothesis")
    ax.set_ylabel("share within 0.5 m and 10° of the truth")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    return save_png(fig, path)
