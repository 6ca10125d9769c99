"""The README's results table, generated from the committed metrics so that it cannot go stale.

`make readme` (python -m scanloc.report.readme_results README.md) rewrites the lines between
the README's two markers from reports/summary.json (the report stage's headline figures,
committed with the dvc.lock they came from); tests/test_readme_results.py fails when the
README's table differs from what the committed metrics give. Rows follow the summary's key
prefixes (report/summary.py), so a new map or real log gets its rows without an edit here.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from scanloc.report.paper import ROWS

BEGIN = "<!-- results:begin (make readme writes this table from reports/summary.json) -->"
END = "<!-- results:end -->"
SUMMARY = Path("reports/summary.json")
# Where the table says the figures' precision comes from: one of the paper's trained rows.
PRECISION_SOURCE = Path("reports/metrics/train_cnn1d_20k.json")

LOCALIZER_LABELS = {
    "amcl": "amcl",
    "cnn_ensemble": "the paper's CNN ensemble",
    "scanlocnet": "ScanLocNet",
    "hybrid": "the hybrid",
    "amcl_global": "amcl, global",
    "amcl_recovery": "amcl with recovery",
}
# (key prefix, the figure, its unit): "%" shows a share as a percentage.
PER_LOCALIZER = (
    ("pos_", "map-1 drive, mean position error", "m"),
    ("lost_", "map-1 drive, steps more than 1 m off", "%"),
    ("conv_", "map-1 drive, steps to converge without a pose", "steps"),
    ("rec_", "map-1 kidnap run, longest recovery", "steps"),
)
PER_SITE = (
    ("real_rmse_", "held-out part, wheel odometry: position RMSE, amcl at ROS's defaults", "m"),
    ("real_tuned_rmse_", "held-out part, wheel odometry: position RMSE, amcl_real", "m"),
    ("real_hybrid_rmse_", "held-out part, wheel odometry: position RMSE, hybrid_real", "m"),
    ("real_top5_", "held-out real scans: ScanLocNet top-5 recall", "%"),
    ("real_vtop1_", "held-out real scans: verified top-1 recall", "%"),
    ("real_ece_", "held-out real scans: verified score's calibration error", ""),
    ("top5_", "drive: ScanLocNet top-5 recall", "%"),
    ("vtop1_", "drive: verified top-1 recall", "%"),
    ("ece_", "drive: verified score's calibration error", ""),
)


def _value(value: Any, unit: str) -> str:
    if value is None:
        return "–"
    if unit == "%":
        return f"{100 * value:.1f} %"
    if unit == "steps":
        return f"{value:g}"
    return f"{value:g} {unit}".rstrip()


def results_rows(summary: Mapping[str, Any]) -> list[tuple[str, str, str]]:
    """(figure, value, summary key) per headline figure, in the README's order."""
    rows: list[tuple[str, str, str]] = []
    for row, label in ROWS.items():
        if f"t1_{row}" in summary:
            value = _value(summary[f"t1_{row}"], "")
            rows.append((f"Table 1, {label}: validation MAE", value, f"t1_{row}"))
    verdicts = [
        f"{value} {key[7:].replace('_', ' ')}"
        for key, value in summary.items()
        if key.startswith("claims_") and value
    ]
    rows.append(("the paper's 7 claims", ", ".join(verdicts), "claims_*"))
    for prefix, figure, unit in PER_LOCALIZER:
        for key, value in summary.items():
            if key.startswith(prefix):
                name = LOCALIZER_LABELS.get(key[len(prefix) :], key[len(prefix) :])
                rows.append((f"{figure}: {name}", _value(value, unit), key))
    for prefix, figure, unit in PER_SITE:
        for key, value in summary.items():
            if key.startswith(prefix) and not (prefix == "top5_" and key.startswith("real_")):
                rows.append((f"{key[len(prefix) :]}: {figure}", _value(value, unit), key))
    if "wall_s" in summary:
        rows.append(("the pipeline's stage time", f"{summary['wall_s'] / 60:.1f} min", "wall_s"))
    return rows


def results_table(summary: Mapping[str, Any], precision: str, profile: str) -> str:
    """The Markdown between the README's markers."""
    lines = [
        BEGIN,
        f"Profile `{profile}`, training precision `{precision}`, from `{SUMMARY}` as committed "
        "with `dvc.lock` (`dvc metrics show` lists every figure; the report explains each).",
        "",
        "| figure | value | `reports/summary.json` key |",
        "|---|---|---|",
    ]
    lines += [f"| {figure} | {value} | `{key}` |" for figure, value, key in results_rows(summary)]
    lines.append(END)
    return "\n".join(lines)


def committed_table(root: Path) -> str:
    """The table from the metrics under `root` (a checkout): the summary, the paper rows'
    precision and params.yaml's profile."""
    summary = json.loads((root / SUMMARY).read_text())
    precision = json.loads((root / PRECISION_SOURCE).read_text()).get("precision", "unknown")
    profile = "laptop"
    for line in (root / "params.yaml").read_text().splitlines():
        if line.startswith("profile:"):
            profile = line.split(":", 1)[1].split("#")[0].strip()
    return results_table(summary, precision, profile)


def readme_table(readme_text: str) -> str:
    """The README's current table, markers included ('' when it has none)."""
    start, end = readme_text.find(BEGIN), readme_text.find(END)
    if start < 0 or end < start:
        return ""
    return readme_text[start : end + len(END)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("readme", type=Path, help="the README to rewrite between its markers")
    args = parser.parse_args(argv)
    text = args.readme.read_text()
    current = readme_table(text)
    if not current:
        print(f"{args.readme}: expected the markers {BEGIN!r} and {END!r}", file=sys.stderr)
        return 2
    try:
        table = committed_table(Path.cwd())
    except FileNotFoundError as missing:
        message = f"{missing.filename}: expected the committed metrics (run `dvc repro`)"
        print(message, file=sys.stderr)
        return 2
    args.readme.write_text(text.replace(current, table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
