"""Score any localizer's estimates on a scanloc run (scanloc.bags.score), with the evaluate
stage's metrics (Table 2, modern, convergence and recovery).

    python -m scanloc.stages.score_estimates run=data/trajectories/<name> \\
        estimates=<bag or csv> topic=/amcl_pose name=<label>

Writes reports/localize/<run>/<label>.csv (beside scanloc's own localizers, so that the next
`evaluate` lists it in Table 2) and reports/score/<run>/<label>.json, and prints the headline
metrics. A plain command line like export_bag (Hydra's conf/run/ group would claim `run=`).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from scanloc.bags.cli import parse_key_values
from scanloc.bags.score import score_estimates
from scanloc.evaluate.table2 import round_sig
from scanloc.stages._app import reporting_user_errors

DEFAULTS = {
    "run": "???",
    "estimates": "???",
    "topic": "/amcl_pose",
    "name": "???",
    "out_csv": "",
    "metrics_path": "",
}
HEADLINE = (
    "pos_err_mean_m",
    "heading_err_mean_deg",
    "x_err_mean",
    "y_err_mean",
    "theta_sin_err_mean",
    "steps_to_converge",
    "recovered",
    "frac_lost",
)


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    values = parse_key_values(
        "python -m scanloc.stages.score_estimates", __doc__ or "", argv, DEFAULTS
    )
    run, name = Path(str(values["run"])), str(values["name"])
    out_csv = values["out_csv"] or f"reports/localize/{run.name}/{name}.csv"
    metrics_path = values["metrics_path"] or f"reports/score/{run.name}/{name}.json"
    metrics = score_estimates(
        run, str(values["estimates"]), str(values["topic"]), name, out_csv, metrics_path
    )
    headline = {k: round_sig(metrics[k]) for k in HEADLINE if k in metrics}
    print(json.dumps({"name": name, "run": run.name, **headline}))
    print(f"scanloc: wrote {out_csv} and {metrics_path}", file=sys.stderr)
    return metrics


if __name__ == "__main__":
    reporting_user_errors("scanloc.stages.score_estimates", main)()
