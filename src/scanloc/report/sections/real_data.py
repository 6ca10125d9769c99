"""What a CARMEN log's site section adds (report/sections/sites.py): how the log was split
into the part that built the map and the scored part, every localizer on the real run and on
its simulated twin (the same poses and odometry, scans simulated in the map built from the
log) side by side, so that the sim-to-real gap is one subtraction (stages/real.py makes both
runs), and the compared localizers over filter seeds."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from scanloc.report.artifacts import TRAJECTORIES
from scanloc.report.context import ReportContext
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.render.tables import converge_text, fixed

# (metric, column title, digits or "%"), shown for the simulated and the real run
COMPARED = (
    ("pos_err_mean_m", "pos. mean [m]", 3),
    ("pos_err_rmse_m", "pos. RMSE [m]", 3),
    ("heading_err_mean_deg", "heading mean [°]", 2),
    ("frac_gross_over_1m", "lost > 1 m", "%"),
)
REAL_STAGE = "localize"  # the stage that runs on every real log's runs


def _cell(metrics: Mapping[str, Any] | None, key: str, digits: int | str) -> str:
    if not metrics:
        return "–"
    if digits == "%":
        return fixed(metrics.get(key), percent=True)
    return fixed(metrics.get(key), int(digits))


def _gap_sentence(log: str, sim: Mapping[str, Any], real: Mapping[str, Any]) -> str:
    """The gap in plain words, from the numbers (tracking amcl and the learned model)."""
    parts = []
    amcl_sim, amcl_real = sim.get("amcl", {}), real.get("amcl", {})
    if amcl_sim.get("pos_err_rmse_m") is not None and amcl_real.get("pos_err_rmse_m") is not None:
        parts.append(
            f"tracking amcl's position RMSE is {amcl_real['pos_err_rmse_m']:.3f} m on the real "
            f"scans against {amcl_sim['pos_err_rmse_m']:.3f} m on the simulated ones"
        )
    learned_sim, learned_real = sim.get("scanlocnet", {}), real.get("scanlocnet", {})
    if learned_sim.get("top5_recall") is not None and learned_real.get("top5_recall") is not None:
        parts.append(
            f"the learned localizer, trained on simulated scans only, has the truth among its 5 "
            f"best hypotheses on {100 * learned_real['top5_recall']:.1f} % of the real scans "
            f"against {100 * learned_sim['top5_recall']:.1f} % of the simulated ones, and its "
            f"best hypothesis is more than 1 m off on "
            f"{fixed(learned_real.get('frac_gross_over_1m'), percent=True)} (real) against "
            f"{fixed(learned_sim.get('frac_gross_over_1m'), percent=True)} (simulated)"
        )
    if not parts:
        return f"{log}: no metrics to compare."
    return f"{log}: " + "; ".join(parts) + "."


def _held_out(split: Mapping[str, Any]) -> int | None:
    """The log's scans that do not build the map (the map's count over its share, less it)."""
    scans, share = split.get("map_scans"), split.get("map_share")
    if not scans or not share:
        return None
    return round(scans / share) - int(scans)


def split_sentence(log: str, meta: Mapping[str, Any]) -> str:
    """The split of the log and the share the map covers, from the run's meta.json."""
    split, cover = meta.get("split") or {}, meta.get("coverage") or {}
    if not split:
        return f"{log}: the run records no split."
    text = (
        f"{log}: split `{split.get('mode')}`: {split.get('map_scans')} scans "
        f"({fixed(split.get('map_share'), percent=True)} of the log) build the map, "
        f"{split.get('evaluation_scans')} ({fixed(split.get('evaluation_share'), percent=True)}) "
        "are localized and scored"
    )
    held_out = _held_out(split)
    if held_out is not None and held_out > split["evaluation_scans"]:
        text += (
            f": the first {split['evaluation_scans']} of its {held_out} held-out scans "
            "(the profile's `split.max_evaluation_scans`, conf/scale/<profile>/real.yaml), not "
            "the whole held-out part"
        )
    if split.get("optimistic"):
        text += " — optimistic: the map holds every scored scan"
    if cover.get("steps"):
        text += (
            f"; the map covers {cover['covered']} of the {cover['steps']} scored poses "
            f"({fixed(cover['covered'] / cover['steps'], percent=True)}: "
            f"{cover.get('outside_map', 0)} outside the map, {cover.get('unexplained', 0)} "
            "with their beams unexplained)"
        )
    return text + "."


SEEDS_NOTE = (
    "Over filter seeds (the localize_seeds stage; reports/metrics/real_seeds.json): the "
    "compared localizers on the scored part (real) and on its kidnap run, with the wheel and "
    "with the laser (scan-matched) odometry. Each cell is the mean over the seeds with its "
    "Student-t 95 % interval; 'worst' is the worst seed's share of steps more than 1 m off. "
    "A deterministic localizer (the learned one) runs once: its interval is its value. "
    "The seeds measure the filter's own randomness on this one log, no more: how a localizer "
    "fares on another log or another drive through this building is not in the interval."
)


def _mean_ci(figures: Mapping[str, Any], key: str, digits: int, percent: bool = False) -> str:
    mean = figures.get(key)
    if mean is None:
        return "–"
    low, high = figures.get(f"{key}_ci95_low"), figures.get(f"{key}_ci95_high")
    if low is None or high is None or low == high:
        return fixed(mean, digits, percent)
    low_text, high_text = fixed(low, digits, percent), fixed(high, digits, percent)
    return f"{fixed(mean, digits, percent)} [{low_text}, {high_text}]"


def seeds_table(runs: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> Table:
    """Rows per odometry source and localizer: the real run's tracking figures and the kidnap
    run's recovery, over filter seeds."""
    header = [
        "odometry", "localizer", "seeds", "pos. RMSE [m]", "median [m]", "heading RMSE [°]",
        "> 1 m (worst seed)", "steps to converge", "kidnaps recovered ≤ 20 steps",
    ]  # fmt: skip
    real, kidnap = runs.get("real", {}), runs.get("kidnap", {})
    rows = []
    for odometry in sorted(set(real) | set(kidnap)):
        names = sorted(set(real.get(odometry, {})) | set(kidnap.get(odometry, {})))
        for name in names:
            r = real.get(odometry, {}).get(name, {})
            k = kidnap.get(odometry, {}).get(name, {})
            rows.append([
                odometry, name, str(r.get("n_seeds", k.get("n_seeds", "–"))),
                _mean_ci(r, "pos_err_rmse_m", 3), _mean_ci(r, "pos_err_median_m", 3),
                _mean_ci(r, "heading_err_rmse_deg", 2),
                fixed(r.get("frac_gross_over_1m_max"), percent=True),
                _mean_ci(r, "steps_to_converge", 1),
                _mean_ci(k, "kidnaps_recovered_frac", 1, percent=True),
            ])  # fmt: skip
    return Table(header, rows)


def _table(methods: list[str], sim: Mapping[str, Any], real: Mapping[str, Any]) -> Table:
    header = ["localizer"]
    for _, title, _ in COMPARED:
        header += [f"{title} sim", f"{title} real"]
    header += ["steps to converge sim", "steps to converge real", "top-5 recall sim / real"]
    rows = []
    for method in methods:
        s, r = sim.get(method), real.get(method)
        if s is None and r is None:
            continue
        row = [method]
        for key, _, digits in COMPARED:
            row += [_cell(s, key, digits), _cell(r, key, digits)]
        row += [converge_text(s or {}), converge_text(r or {})]
        recall = (s or {}).get("top5_recall"), (r or {}).get("top5_recall")
        row.append(
            "–"
            if None in recall
            else f"{fixed(recall[0], percent=True)} / {fixed(recall[1], percent=True)}"
        )
        rows.append(row)
    return Table(header, rows)


LOG_NOTE = (
    "A CARMEN log with corrected poses (params.yaml `real_logs`), split in time "
    "(conf/real.yaml `split`): one part builds the map (log-odds occupancy mapping along the "
    "corrected poses), the other is localized and scored, so that no scored scan went into "
    "the map; the poses the map does not cover are counted, never dropped. The scored part "
    "gives a real run (its scans, wheel and laser odometry), a simulated twin (the same poses "
    "and odometry, scans simulated in the built map with the log's sensor and a SICK-like "
    "noise model) and a kidnap run (the part cut and reordered); the mapping part is the tune "
    "run, where settings are chosen (conf/localizer/amcl_real.yaml). The learned localizer is "
    "trained on scans simulated in the built map only. Truth is the log's corrected pose (a "
    "scan matcher's, itself accurate to a few centimetres). Real minus simulated is the "
    "sim-to-real gap."
)


def log_blocks(ctx: ReportContext, section: Section, log: str) -> bool:
    """The log's split, its real run against its simulated twin, and its runs over seeds;
    True: its runs have truth (the corrected poses), so the site section scores them."""
    section.blocks.append(Para(LOG_NOTE))
    real_dir = ctx.builder.root / TRAJECTORIES / f"{log}_real"
    if not (real_dir / "meta.json").is_file():
        section.blocks.append(Para(f"{log}: not read yet (no {TRAJECTORIES}/{log}_real)."))
        return False
    meta = json.loads((real_dir / "meta.json").read_text())
    section.blocks.append(Para(split_sentence(log, meta)))
    sim = ctx.artifacts.localization.get(f"{log}_sim") or {}
    real = ctx.artifacts.localization.get(f"{log}_real") or {}
    if real:
        section.blocks.append(_table(ctx.localizers.of_stage(REAL_STAGE), sim, real))
        section.blocks.append(Para(_gap_sentence(log, sim, real)))
    seeds = ctx.artifacts.real_seed_figures or {}
    runs = {run: seeds[f"{log}_{run}"] for run in ("real", "kidnap") if f"{log}_{run}" in seeds}
    if runs:
        section.blocks.append(Para(SEEDS_NOTE))
        section.blocks.append(seeds_table(runs))
    return True
