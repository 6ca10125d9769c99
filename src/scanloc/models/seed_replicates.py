"""A training row repeated over seeds: its further seeds trained together, its figures over all.

The claims' verdicts rest on margins between rows, and a margin means something only against
the rows' seed-to-seed spread on this machine at this scale. So a row with `seeds: N` trains
N − 1 further seeds beside its own (the same data, configuration and precision), and its
metrics report the mean over the N with a 95 % interval, as every figure over seeds does
(docs/design.md: `<name>`, `<name>_ci95_low/high`, `n_seeds`, `seeds/<seed>/<name>`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

# The per-seed figures a row's metrics carry over its seeds (none depends on the machine).
SEED_FIGURES = ("val_mae", "train_mae", "best_val_mae", "val_pos_err_m", "val_heading_err_deg")


def further_seed_dirs(out_dir: Path, seed: int, seeds: int) -> dict[int, Path]:
    """Where the seeds seed+1 .. seed+seeds−1 of a row go: out_dir/seeds/<seed>/."""
    return {seed + k: out_dir / "seeds" / str(seed + k) for k in range(1, seeds)}


def train_further_seeds(
    *,
    metrics: Mapping[str, Any],
    out_dir: Path,
    seed: int,
    seeds: int,
    fit_kwargs: Mapping[str, Any],
    init_from: Path | None = None,
) -> dict[str, Any]:
    """Train the row's further seeds together (scanloc.models.stacked_ensemble: each ends
    where its lone run would) and return the row's `metrics` with its figures over all seeds.
    The run of `seed` stays the row's model and its epoch time that of one lone run."""
    from scanloc.models.stacked_ensemble import fit_stacked

    if seeds <= 1:
        return dict(metrics)
    dirs = further_seed_dirs(out_dir, seed, seeds)
    results = fit_stacked(
        out_dirs=list(dirs.values()), seeds=list(dirs), init_from=init_from, **fit_kwargs
    )
    return over_seeds(metrics, {seed: metrics, **dict(zip(dirs, results, strict=True))})


def over_seeds(metrics: Mapping[str, Any], per_seed: Mapping[int, Mapping[str, Any]]) -> dict:
    """`metrics` with each of SEED_FIGURES replaced by its mean over `per_seed`, beside its
    Student-t 95 % interval, `n_seeds` and the per-seed values under `seeds`."""
    out = dict(metrics)
    for name in SEED_FIGURES:
        values = np.array([float(m[name]) for m in per_seed.values()], dtype=np.float64)
        mean = float(values.mean())
        half = 0.0
        if values.size > 1:
            half = float(stats.t.ppf(0.975, values.size - 1) * values.std(ddof=1))
            half /= math.sqrt(values.size)
        out[name] = mean
        out[f"{name}_ci95_low"], out[f"{name}_ci95_high"] = mean - half, mean + half
    out["n_seeds"] = len(per_seed)
    out["seeds"] = {str(s): {n: float(m[n]) for n in SEED_FIGURES} for s, m in per_seed.items()}
    return out
