"""The headline metrics: the ~20 numbers a reader compares first between two runs.

reports/summary.json holds, with short keys so that a table of experiments fits a
terminal (docs/experiments.md):
- `t1_<row>`: Table 1's final validation MAE per row (mlp, cnn1d_20k, cnn1d_200k, cnn2d);
- `pos_<localizer>` / `lost_<localizer>`: mean position error [m] and share of steps more than
  1 m off on the paper's map-1 drive, for amcl, the paper's CNN ensemble, the learned localizer
  and the hybrid;
- `conv_<localizer>`: steps to converge on the map-1 drive (amcl_global, hybrid);
- `rec_<localizer>`: the longest recovery after a kidnap on the map-1 kidnap run
  (amcl_recovery, hybrid; a kidnap never recovered counts its whole stretch, see
  evaluate/metrics.py);
- `top5_<map>`: the learned localizer's top-5 recall on each map's drive; `vtop1_<map>` /
  `ece_<map>`: its verified top-1 recall (scanlocnet_verified) and that score's expected
  calibration error;
- `real_rmse_<log>` / `real_top5_<log>` / `real_vtop1_<log>` / `real_ece_<log>`: on each real
  log (params.yaml `real_logs`), on its held-out real scans with wheel odometry: amcl's position
  RMSE [m] at ROS's defaults, and the learned localizer's top-5 recall, verified top-1 recall
  and calibration error; `real_tuned_rmse_<log>` / `real_hybrid_rmse_<log>`: the position
  RMSE of `amcl_real` (chosen on the log's mapping part) and of `hybrid_real` (no initial pose);
- `claims_<verdict>`: how many of the paper's claims got each verdict;
- `wall_s`: the pipeline's total stage time (from reports/timing/).
All values are rounded to 4 significant digits; a missing one is null.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

from scanloc.report.claims import Verdict
from scanloc.report.paper import PAPER_DRIVE, PAPER_KIDNAP, ROWS
from scanloc.report.verdicts import VERDICTS

# The localizers of specific headline metrics (not "all of a group": those come from the
# localizer catalog, report/localizers.py).
HEADLINE_LOCALIZERS = ("amcl", "cnn_ensemble", "scanlocnet", "hybrid")
CONVERGING = ("amcl_global", "hybrid")
RECOVERING = ("amcl_recovery", "hybrid")


def _round(value: Any) -> float | None:
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return float(f"{value:.4g}") if math.isfinite(value) else None


def headline_metrics(
    table1: Mapping[str, float],
    localization: Mapping[str, Mapping[str, Mapping[str, Any]]],
    maps: Iterable[str],
    claims: list[Verdict],
    wall_s: float,
    real_logs: Iterable[str] = (),
) -> dict[str, float | int | None]:
    """The summary (see the module docstring) from Table 1's val_mae per row, the nested
    localization metrics {trajectory: {localizer: {metric: value}}}, the map names, the claims
    and the total stage time."""
    out: dict[str, float | int | None] = {}
    for row in ROWS:
        out[f"t1_{row}"] = _round(table1.get(row))
    drive = localization.get(PAPER_DRIVE, {})
    kidnap = localization.get(PAPER_KIDNAP, {})
    for name in HEADLINE_LOCALIZERS:
        out[f"pos_{name}"] = _round(drive.get(name, {}).get("pos_err_mean_m"))
        out[f"lost_{name}"] = _round(drive.get(name, {}).get("frac_gross_over_1m"))
    for name in CONVERGING:
        out[f"conv_{name}"] = _round(drive.get(name, {}).get("steps_to_converge"))
    for name in RECOVERING:
        out[f"rec_{name}"] = _round(kidnap.get(name, {}).get("recovery_steps_max"))
    for name in maps:
        learned = localization.get(f"{name}_drive", {}).get("scanlocnet", {})
        out[f"top5_{name}"] = _round(learned.get("top5_recall"))
        verified = localization.get(f"{name}_drive", {}).get("scanlocnet_verified", {})
        out[f"vtop1_{name}"] = _round(verified.get("top1_recall"))
        out[f"ece_{name}"] = _round(verified.get("calibration_ece"))
    for name in real_logs:
        real = localization.get(f"{name}_real", {})
        out[f"real_rmse_{name}"] = _round(real.get("amcl", {}).get("pos_err_rmse_m"))
        out[f"real_tuned_rmse_{name}"] = _round(real.get("amcl_real", {}).get("pos_err_rmse_m"))
        out[f"real_hybrid_rmse_{name}"] = _round(real.get("hybrid_real", {}).get("pos_err_rmse_m"))
        out[f"real_top5_{name}"] = _round(real.get("scanlocnet", {}).get("top5_recall"))
        verified = real.get("scanlocnet_verified", {})
        out[f"real_vtop1_{name}"] = _round(verified.get("top1_recall"))
        out[f"real_ece_{name}"] = _round(verified.get("calibration_ece"))
    for verdict in VERDICTS:
        key = "claims_" + verdict.replace(" ", "_")
        out[key] = sum(1 for claim in claims if claim.verdict == verdict)
    out["wall_s"] = _round(wall_s)
    return out
