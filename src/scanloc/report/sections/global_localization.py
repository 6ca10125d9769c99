"""Section "Global localization and kidnapping": on every map, the localizers of the catalog's
global table (`global_table: true`): their success rates with Wilson 95 % intervals over the
evaluation seeds (reports/metrics/global_localization.json), then their figures on the drive
and the first kidnap trajectory."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from scanloc.evaluate.table2 import GLOBAL_NOTE
from scanloc.report.artifacts import TRAJECTORIES, estimate_tables
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render import localization_figures as figures
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.render.tables import MISSING, converge_text, fixed, recovery_text
from scanloc.trajectory.format import load_trajectory

HEADER = [
    "map",
    "localizer",
    "steps to converge (drive)",
    "steps to converge (kidnap)",
    "recovery steps (max)",
    "recovery steps (mean)",
    "kidnaps recovered",
    "tracking error mean (drive) [m]",
    "tracking heading mean (drive) [°]",
    "lost > 1 m (kidnap)",
]


SEEDS_HEADER = [
    "map",
    "localizer",
    "seeds",
    "converged in time [95 % CI]",
    "steps to converge (median / worst)",
    "kidnaps recovered ≤ 20 steps [95 % CI by run]",
    "converged in time, resolvable starts [95 % CI]",
    "kidnaps recovered, resolvable ones [95 % CI by run]",
    "recovery steps (median / worst)",
    "re-losses",
    "false convergences",
]
SEEDS_LEGEND = (
    "Over seeds: per map, the kidnap runs on the evaluation seeds of conf/seeds.yaml "
    "(<map>_kidnap and <map>_kidnap_s1 … s4, 3 kidnaps each; a real log: its one "
    "<log>_kidnap run); rates with Wilson 95 % intervals that count runs, not events: "
    "convergence has one start per seed; the kidnaps of a run share its route, scans and "
    "filter, so their pooled rate gets a cluster-robust Wilson interval (the effective "
    "count between the runs and the kidnaps, by the spread between runs; 'k / n in r runs'). "
    "A real log's kidnaps are one run's: its interval says nothing of another log. "
    "Worst = the slowest seed or "
    "kidnap, '≥' where one never converged within its stretch (a censored count); re-losses "
    "and false convergences summed over the runs ('–': no covariance to be confident with). "
    "Tuning: the hybrid's proposal and hybrid_adaptive's switch were chosen on the tune set "
    "only (<map>_tune_kidnap, with its own seed and kidnap times, conf/seeds.yaml `tune`; "
    "`python -m "
    "scanloc.stages.tune study=hybrid` and `study=hybrid_adaptive`, the figures in their "
    "conf/localizer files), never on the runs this table scores; the ablations inherit the "
    "hybrid's. The amcl baselines keep ROS's or the matched settings; the learned localizer's "
    "training keeps its defaults (not tuned)."
)


def _rate(figures: Mapping[str, Any], name: str, trials: str, runs: str | None = None) -> str:
    """'k / n = r % [low–high %]', with ' in m runs' where the events are pooled over runs."""
    rate = figures.get(name)
    if rate is None:
        return MISSING
    low, high = figures.get(f"{name}_ci95_low"), figures.get(f"{name}_ci95_high")
    count = round(rate * figures.get(trials, 0))
    pooled = f" in {figures[runs]:.0f} runs" if runs and runs in figures else ""
    return (
        f"{count} / {figures.get(trials, 0):.0f}{pooled} = {100 * rate:.0f} % "
        f"[{100 * low:.0f}–{100 * high:.0f} %]"
    )


def _spread(figures: Mapping[str, Any], name: str, censored: bool) -> str:
    median, worst = figures.get(f"{name}_median"), figures.get(f"{name}_max")
    if median is None or worst is None:
        return MISSING
    return f"{median:.0f} / {'≥ ' if censored else ''}{worst:.0f}"


def _total(figures: Mapping[str, Any], name: str) -> str:
    total = figures.get(f"{name}_total")
    return MISSING if total is None else f"{total:.0f}"


def seed_rows(
    name: str, methods: list[str], figures: Mapping[str, Mapping[str, Any]]
) -> list[list[str]]:
    """One row per localizer of the map's figures over seeds, in `methods`' order."""
    rows = []
    for method in methods:
        f = figures.get(method)
        if f is None:
            continue
        lost_kidnap = f.get("recovered_total", 0) < f.get("n_kidnaps", 0)
        rows.append(
            [
                name,
                method,
                f"{f.get('n_seeds', 0):.0f}",
                _rate(f, "convergence_success", "n_seeds"),
                _spread(f, "steps_to_converge", f.get("converged", 1) < 1),
                _rate(f, "kidnaps_recovered_frac", "n_kidnaps", "n_runs_kidnapped"),
                _rate(f, "convergence_success_resolvable", "n_starts_resolvable"),
                _rate(
                    f,
                    "kidnaps_recovered_frac_resolvable",
                    "n_kidnaps_resolvable",
                    "n_runs_kidnaps_resolvable",
                ),
                _spread(f, "recovery_steps", lost_kidnap),
                _total(f, "relosses"),
                _total(f, "false_convergences"),
            ]
        )
    return rows


SYMMETRIES_SHOWN = 3  # per map, the strongest copies named in the look-alike paragraph


def _symmetry_text(symmetry: Mapping[str, Any]) -> str:
    turns = int(symmetry["quarter_turns"])
    turn = f"a {90 * turns}° turn, then " if turns else ""
    return (
        f"{turn}a shift by ({symmetry['tx']:.2f}, {symmetry['ty']:.2f}) m "
        f"({100 * symmetry['overlap']:.0f} % of the walls onto walls)"
    )


def look_alike_text(maps: list[str], look_alikes: Mapping[str, Mapping[str, Any]] | None) -> str:
    """What the look-alike check found on each map (evaluate/look_alikes.py)."""
    if look_alikes is None:
        return "Look-alike stretches: not available (reports/metrics/look_alikes.json)."
    docs = [look_alikes[name] for name in maps if name in look_alikes]
    window = docs[0]["window"] if docs else MISSING
    threshold = f"{docs[0]['llr_threshold_nats']:.1f} nats" if docs else MISSING
    parts = []
    for name in maps:
        doc = look_alikes.get(name)
        if doc is None:
            parts.append(f"{name}: not checked.")
            continue
        strongest = doc["symmetries"][:SYMMETRIES_SHOWN]
        copies = "; ".join(_symmetry_text(s) for s in strongest) or "none"
        parts.append(
            f"{name}: {len(doc['symmetries'])} copies of the map tried, the strongest {copies}. "
            "Ambiguous: "
            f"{doc['starts_ambiguous']} of {doc['starts']} starts and "
            f"{doc['kidnaps_ambiguous']} of {doc['kidnaps']} kidnaps."
        )
    return (
        "Look-alike stretches (reports/metrics/look_alikes.json, evaluate/look_alikes.py): a "
        "start or kidnap is ambiguous when a copy of the map (a turn by a multiple of 90° and a "
        "shift that carry many walls onto walls, then posed to imitate the truth best) stays "
        f"within {threshold} of the truth over the stretch's first {window} steps: the expected "
        "log-likelihood ratio of the truth's scans, truth over copy, under the run's own range "
        "noise and every beam (ln 99: below it the truth holds less than 99 % of the two's "
        "posterior from even odds). The scans alone then cannot settle the place within the "
        "window; a localizer may still land on the truth by chance, or by what came before the "
        "kidnap. The 'resolvable' columns give the rates over the other stretches. "
        + " ".join(parts)
    )


def _rows(name: str, methods: list[str], localization: Mapping[str, Any]) -> list[list[str]]:
    drive = localization.get(f"{name}_drive", {})
    kidnap = localization.get(f"{name}_kidnap", {})
    rows = []
    for method in methods:
        d, k = drive.get(method), kidnap.get(method)
        if d is None and k is None:
            continue
        d, k = d or {}, k or {}
        rows.append(
            [
                name,
                method,
                converge_text(d),
                converge_text(k),
                recovery_text(k, "recovery_steps_max") if k.get("kidnaps") else "–",
                recovery_text(k, "recovery_steps_mean", 1) if k.get("kidnaps") else "–",
                f"{k.get('recovered', 0):.0f} / {k.get('kidnaps', 0):.0f}" if k else "–",
                fixed(d.get("tracking_pos_err_mean_m")),
                fixed(d.get("tracking_heading_err_mean_deg"), 2),
                fixed(k.get("frac_lost"), percent=True),
            ]
        )
    return rows


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    b, methods = ctx.builder, ctx.localizers.global_table()
    section = spec.section()
    section.blocks.append(
        Para(
            "Beyond the paper. Each map has a drive trajectory and a kidnap trajectory (the same "
            "route generator; at fixed fractions of the run the robot is carried to a random "
            "free pose while its odometry sees nothing). amcl tracks from the true first pose; "
            "amcl_global and amcl_recovery start without a pose (recovery off / on); "
            "scanlocnet_track and hybrid start from the learned localizer's first scan. "
            f"{GLOBAL_NOTE}"
        )
    )
    over_seeds = ctx.artifacts.global_figures
    if over_seeds is None:
        section.blocks.append(
            Para("Over seeds: not available (reports/metrics/global_localization.json).")
        )
    else:
        horizon = {f.get("converge_within_steps") for m in over_seeds.values() for f in m.values()}
        within = ", ".join(f"{h:.0f}" for h in sorted(h for h in horizon if h is not None))
        section.blocks.append(
            Para(
                f"Converged in time: within {within or MISSING} steps of the start. {SEEDS_LEGEND}"
            )
        )
        names = [*ctx.maps, *ctx.real_logs]  # a log's one kidnap run: <log>_kidnap
        seeded = [r for n in names for r in seed_rows(n, methods, over_seeds.get(n, {}))]
        section.blocks.append(Table(SEEDS_HEADER, seeded))
        section.blocks.append(Para(look_alike_text(ctx.maps, ctx.artifacts.look_alikes)))
    section.blocks.append(
        Para("Seed 0 alone (<map>_drive and <map>_kidnap, the runs the figures below show):")
    )
    rows = [row for name in ctx.maps for row in _rows(name, methods, ctx.artifacts.localization)]
    section.blocks.append(Table(HEADER, rows))
    for name in ctx.maps:
        run = f"{name}_kidnap"
        traj_dir = b.root / TRAJECTORIES / run
        tables = estimate_tables(b.root, run, methods)
        if not tables or not (traj_dir / "truth.npy").is_file():
            section.blocks.append(Para(f"{run}: no trajectory or localizer tables."))
            continue
        traj, _ = load_trajectory(traj_dir)
        kidnap_times = tuple(float(traj.times[k]) for k in traj.kidnap_steps)
        section.blocks.append(
            b.figure(
                f"kidnap_errors_{name}.png",
                f"{run}: position and heading error over time; dashed lines: kidnaps.",
                lambda p, traj=traj, tables=tables, kt=kidnap_times, run=run: (
                    figures.plot_errors_over_time(traj.truth, tables, p, kt, run)
                ),
            )
        )
    return [section]


SECTION = SectionSpec("global-localization", "Global localization and kidnapping", build)
