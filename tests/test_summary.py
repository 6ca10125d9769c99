"""The headline metrics (reports/summary.json): rounding, missing values as null, and one count
per verdict, the inconclusive one included."""

from __future__ import annotations

import math

from scanloc.report.claims import Verdict
from scanloc.report.summary import headline_metrics
from scanloc.report.verdicts import INCONCLUSIVE, NOT_TESTABLE, REPRODUCED


def _verdict(number: int, result: str) -> Verdict:
    return Verdict(number, "paper", "figure", "ours", result, "rule")


def test_headline_counts_each_verdict_and_rounds_to_4_digits() -> None:
    localization = {
        "sparse_obstacles_drive": {"amcl": {"pos_err_mean_m": 0.0421234, "frac_gross_over_1m": 0}},
        "simple_rooms_drive": {"scanlocnet": {"top5_recall": math.nan}},
    }
    verdicts = [_verdict(1, INCONCLUSIVE), _verdict(2, REPRODUCED), _verdict(3, INCONCLUSIVE)]
    out = headline_metrics(
        {"mlp": 2.345678}, localization, ["simple_rooms"], verdicts, 12.34567, ["intel"]
    )
    assert out["t1_mlp"] == 2.346 and out["t1_cnn2d"] is None
    assert out["pos_amcl"] == 0.04212 and out["lost_amcl"] == 0.0
    assert out["pos_hybrid"] is None and out["top5_simple_rooms"] is None  # NaN is missing
    assert out["real_rmse_intel"] is None
    assert out["claims_inconclusive"] == 2 and out["claims_reproduced"] == 1
    assert out[f"claims_{NOT_TESTABLE.replace(' ', '_')}"] == 0
    assert out["wall_s"] == 12.35
