"""The report: built from a small fabricated artifact tree, checked for structure (the
registry's sections in order, the same in HTML and Markdown), offline self-containment,
determinism, missing artifacts, the localizer catalog as the source of its lists, the
inconclusive verdict, the provenance's '+dirty', and rendered in a real headless Chromium."""

from __future__ import annotations

import base64
import html
import json
import os
import re
import select
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from scanloc.estimates import TABLE_COLUMNS
from scanloc.evaluate.seeds import global_localization
from scanloc.evaluate.table2 import evaluate_runs, nested_json
from scanloc.report.build import build_report
from scanloc.report.sections.registry import SECTIONS
from scanloc.stages.report import git_commit
from scanloc.trajectory.format import Trajectory, save_trajectory
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, OccupancyGrid

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CONTEXT = {
    "profile": "smoke",
    "params": {"profile": "smoke", "seed": 0},
    "git_commit": "abc123",
    "sites": {"sparse_obstacles": "map", "simple_rooms": "map"},
}
REPO_ROOT = Path(__file__).resolve().parents[1]
REPORT_CFG = yaml.safe_load((REPO_ROOT / "conf/report.yaml").read_text())
LOCALIZER_CONF = REPO_ROOT / "conf/localizer"
SENSOR = {"num_beams": 667, "angle_min": -2.09439510239, "angle_max": 2.09439510239}
SENSOR |= {"range_min": 0.02, "range_max": 5.6, "no_return_value": 7.0}


# ---------------------------------------------------------------- fabricated artifacts


def _grid(width: int, height: int, resolution: float, bars: list[tuple[int, int, int, int]]):
    cells = np.full((height, width), FREE, dtype=np.int8)
    cells[[0, -1], :] = OCCUPIED
    cells[:, [0, -1]] = OCCUPIED
    for c0, r0, c1, r1 in bars:
        cells[r0:r1, c0:c1] = OCCUPIED
    return OccupancyGrid(cells, resolution)


def _write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))


def _run(
    root: Path, name: str, start: float, end: float, samples: int, epoch_s: float, epochs: int = 12
):
    """A training run whose MAE decays from `start` to `end` over `epochs` epochs."""
    folder = root / "models" / name
    folder.mkdir(parents=True)
    epoch = np.arange(1, epochs + 1)
    val = end + (start - end) * np.exp(-4 * epoch / epochs)
    history = pd.DataFrame({"epoch": epoch, "train_mae": val * 0.97, "val_mae": val})
    history["val_pos_err_m"], history["val_heading_err_deg"] = val * 0.8, val * 20
    history["lr"] = 0.006
    history.to_csv(folder / "history.csv", index=False)
    metrics = {"val_mae": float(val[-1]), "best_val_mae": float(val.min()), "epoch_s": epoch_s}
    metrics_file = f"transfer_{name[9:]}" if name.startswith("transfer/") else f"train_{name}"
    metrics |= {"epochs": epochs, "samples": samples}
    _write_json(root / "reports/metrics" / f"{metrics_file}.json", metrics)
    config = {"epochs": epochs, "batch_size": 100, "lr": 0.006, "lr_decay": 0.0, "dropout": 0.1}
    _write_json(folder / "config.json", config | {"samples": samples, "dataset": "map1_small"})


def _estimates(truth: np.ndarray, noise: float, cov: bool, members: int, rng) -> pd.DataFrame:
    est = truth + rng.normal(0.0, [noise, noise, noise / 2], size=truth.shape)
    table = pd.DataFrame({"step": np.arange(len(truth)), "t": np.arange(len(truth)) * 0.1})
    table["x"], table["y"], table["theta"] = est[:, 0], est[:, 1], est[:, 2]
    for name in TABLE_COLUMNS[5:11]:
        table[name] = np.nan
    if cov:
        table["cov_xx"], table["cov_yy"], table["cov_tt"] = noise**2, noise**2, noise**2 / 4
        table["cov_xy"], table["cov_xt"], table["cov_yt"] = 0.0, 0.0, 0.0
    table["n_particles"] = members
    return table[list(TABLE_COLUMNS)]


def make_artifacts(root: Path) -> Path:
    """A complete, tiny artifact tree as the pipeline lays it out under `root`."""
    rng = np.random.default_rng(0)
    save_map(
        _grid(120, 100, 0.05, [(30, 20, 50, 30), (80, 60, 84, 90)]),
        root / "data/maps/sparse_obstacles/map.yaml",
    )
    save_map(_grid(80, 60, 0.1, [(40, 0, 42, 25)]), root / "data/maps/simple_rooms/map.yaml")
    for name, map_name in (
        ("map1_small", "sparse_obstacles"),
        ("map1_large", "sparse_obstacles"),
        ("map2_small", "simple_rooms"),
    ):
        folder = root / "data/scans" / name
        folder.mkdir(parents=True)
        ranges = rng.uniform(0.3, 5.0, size=(12, 667)).astype(np.float32)
        ranges[:, 300:340] = 7.0
        np.save(folder / "ranges.npy", ranges)
        np.save(folder / "poses.npy", np.column_stack([rng.uniform(1, 4, (12, 2)), np.zeros(12)]))
        np.save(folder / "is_val.npy", np.arange(12) >= 10)
        _write_json(
            folder / "meta.json",
            {"name": name, "map": {"name": map_name}, "count": 12, "seed": 1, "sensor": SENSOR},
        )
    # The 200k net and the 2D CNN train one epoch: 200,000 and 20,000 training scans seen
    # against the 20k net's 240,000, the paper's ratios (0.8, 0.08) within ×/÷ 2 (claims 1, 2
    # and 5 are not tested on training unlike the paper's).
    for row, (start, end, samples, epochs) in {
        "mlp": (4.0, 2.5, 20000, 12),
        "cnn1d_20k": (3.0, 0.4, 20000, 12),
        "cnn1d_200k": (3.0, 0.12, 200000, 1),
        "cnn2d": (4.0, 1.2, 20000, 1),
        "transfer/scratch": (4.0, 0.8, 20000, 12),
        "transfer/pretrained": (2.0, 0.6, 20000, 12),
    }.items():
        epoch_s = samples / 4000 * (12 if row == "cnn2d" else 1)
        _run(root, row, start, end, samples, epoch_s, epochs)
    steps = 60
    phase = np.linspace(0, 2 * np.pi, steps)
    truth = np.column_stack([3 + 1.5 * np.cos(phase), 2.5 + 1.5 * np.sin(phase), phase + np.pi / 2])
    truth[:, 2] = np.angle(np.exp(1j * truth[:, 2]))
    runs = ("sparse_obstacles_drive", "sparse_obstacles_kidnap")
    for run in runs:
        kidnaps = (30,) if run.endswith("kidnap") else ()
        traj = Trajectory(np.arange(steps) * 0.1, truth, truth.copy(), kidnap_steps=kidnaps)
        ranges = rng.uniform(0.3, 5.0, size=(steps, 667)).astype(np.float32)
        meta = {"name": run, "map": "sparse_obstacles", "sensor": SENSOR}
        save_trajectory(traj, root / "data/trajectories" / run, ranges=ranges, meta=meta)
        for method, noise, cov, members in (
            ("amcl", 0.03, True, 500),
            ("cnn_single", 0.4, False, 1),
            ("cnn_ensemble", 0.2, True, 7),
        ):
            folder = "localize_cnn" if method.startswith("cnn") else "localize"
            loc = root / "reports" / folder / run
            loc.mkdir(parents=True, exist_ok=True)
            _estimates(truth, noise, cov, members, rng).to_csv(loc / f"{method}.csv", index=False)
        timings = {m: {"time_per_scan_s": 0.001 * k} for m, k in (("amcl", 500), ("cnn_single", 1))}
        _write_json(root / "reports/localize_timing" / f"{run}.json", timings)
    metrics = evaluate_runs(
        list(runs),
        root / "data/trajectories",
        [root / "reports/localize", root / "reports/localize_cnn"],
        root / "reports/metrics/localization.json",
        root / "reports/table2",
    )
    seeds = {"sparse_obstacles": ["sparse_obstacles_kidnap"]}
    figures = nested_json(global_localization(metrics, seeds, converge_within=20))
    (root / "reports/metrics/global_localization.json").write_text(figures)
    learned = {"cells": 222, "train_s": 301.5, "samples_seen": 375000, "precision": "32-true"}
    learned |= {"val_pos_err_median_m": 0.113, "val_heading_err_median_deg": 0.63}
    learned |= {"val_frac_gross_over_1m": 0.02, "val_top1_recall": 0.97, "val_top5_recall": 0.996}
    _write_json(root / "reports/metrics/scanlocnet_sparse_obstacles.json", learned)
    history = pd.DataFrame({"epoch": [1, 2], "val_pos_err_median_m": [1.0, 0.2]})
    history["val_top5_recall"] = [0.3, 0.99]
    (root / "models/scanlocnet/sparse_obstacles").mkdir(parents=True)
    history.to_csv(root / "models/scanlocnet/sparse_obstacles/history.csv", index=False)
    for stage, wall in (("train_mlp", 12.5), ("localize_amcl", 3.25)):
        _write_json(root / "reports/timing" / f"{stage}.json", {"stage": stage, "wall_s": wall})
    return root


def build(root: Path, context: dict, localizer_conf: Path = LOCALIZER_CONF) -> dict:
    """The report of the artifacts under `root`, written to <root>/reports/."""
    return build_report(root, root / "reports", context, REPORT_CFG, localizer_conf)


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    root = make_artifacts(tmp_path_factory.mktemp("artifacts"))
    build(root, CONTEXT)
    return root


# ---------------------------------------------------------------- structure


def registry_headings(sites: dict[str, str]) -> list[tuple[str, str]]:
    """(id, title) of every section the registry makes for `sites`, in its order."""
    headings = []
    for spec in SECTIONS:
        for name, kind in sites.items() if "{name}" in spec.id else [("", "")]:
            names = {"name": name, "kind": kind}
            headings.append((spec.id.format(**names), spec.title.format(**names)))
    return headings


def headings(text: str) -> list[tuple[str, str]]:
    return [(i, html.unescape(t)) for i, t in re.findall(r'<h2 id="([^"]+)">([^<]*)</h2>', text)]


def test_report_shows_the_registrys_sections_in_order_in_both_renderings(built: Path) -> None:
    page = (built / "reports/report.html").read_text(encoding="utf-8")
    md = (built / "reports/report.md").read_text(encoding="utf-8")
    expected = registry_headings(CONTEXT["sites"])
    assert headings(page) == expected
    assert headings(md) == expected
    assert re.findall(r'<a href="#([^"]+)">', page) == [i for i, _ in expected]  # the nav


def test_the_registry_alone_decides_which_sections_and_in_what_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = make_artifacts(tmp_path)
    chosen = [spec for spec in SECTIONS if spec.id in ("table-2", "provenance")][::-1]
    monkeypatch.setattr("scanloc.report.build.SECTIONS", tuple(chosen))
    build(root, CONTEXT)
    page = (root / "reports/report.html").read_text(encoding="utf-8")
    assert headings(page) == [("provenance", "Provenance"), ("table-2", "Table 2")]
    assert "<img" not in page and not list((root / "reports/figures").glob("*.png"))


def test_report_embeds_every_figure_as_a_png(built: Path) -> None:
    page = (built / "reports/report.html").read_text(encoding="utf-8")
    uris = re.findall(r'<img src="data:image/png;base64,([^"]+)"', page)
    assert len(uris) >= 6 and len(uris) == page.count("<img")
    for uri in uris:
        assert base64.b64decode(uri, validate=True).startswith(PNG_MAGIC)
    assert len(uris) == len(list((built / "reports/figures").glob("*.png")))


def test_report_needs_nothing_from_outside(built: Path) -> None:
    page = (built / "reports/report.html").read_text(encoding="utf-8")
    attributes = re.findall(r'(?:src|href|action|srcset)\s*=\s*"([^"]*)"', page, flags=re.I)
    assert attributes and all(a.startswith(("data:image/png;base64,", "#")) for a in attributes)
    for forbidden in ("http://", "https://", "<script", "<link", "<iframe", "@import", "url("):
        assert forbidden not in page.lower()
    assert "default-src 'none'; img-src data:" in page  # the CSP forbids any request


def claim_verdicts(page: str) -> dict[int, str]:
    """Claim number -> verdict, read from the rows of the report's claims table."""
    section = page.split('id="paper-claims"', 1)[1].split("<h2", 1)[0]
    verdicts = {}
    for row in re.findall(r"<tr class=\"v-[a-z]+\">(.*?)</tr>", section):
        cells = re.findall(r"<td>(.*?)</td>", row)
        if len(cells) == 8:  # the claims table (the legend has two columns)
            verdicts[int(cells[0])] = cells[5]
    return verdicts


def test_report_content(built: Path) -> None:
    page = (built / "reports/report.html").read_text(encoding="utf-8")
    for text in ("1D CNN 200k paper", "×0.0024", "abc123", "train_mlp", "12.5"):
        assert text in page
    # The fabricated runs were made to give these verdicts: claim 5's 200k net is only 0.28
    # better than the 20k one (not "markedly"), claim 7's CNN is 0.45 m behind amcl, not 0.075;
    # claims 3 and 4's per-sample epoch-time ratios (12 and 1.0) lie inside their ranges but
    # within the cross-machine factor of a bound (conf/report.yaml timing_machine_factor), so
    # another CPU could flip them.
    assert claim_verdicts(page) == {
        1: "reproduced",
        2: "reproduced",
        3: "inconclusive",
        4: "inconclusive",
        5: "not reproduced",
        6: "reproduced",
        7: "direction only",
    }
    # beyond the paper: the learned localizer's figures per map, kidnaps, one section per map
    learned = page.split('id="learned-localizer"', 1)[1].split("<h2", 1)[0]
    assert "<td>sparse_obstacles</td><td>222</td><td>302</td><td>375,000</td>" in learned
    assert "<td>simple_rooms</td><td>not trained</td>" in learned
    assert (built / "reports/figures/kidnap_errors_sparse_obstacles.png").is_file()
    assert "simple_rooms_kidnap: no trajectory or localizer tables." in page
    for name in CONTEXT["sites"]:
        assert f'<h2 id="site-{name}">Site {name} (map)</h2>' in page
    md = (built / "reports/report.md").read_text(encoding="utf-8")
    images = re.findall(r"!\[[^\]]*\]\((figures/[^)]+\.png)\)", md)
    assert len(images) >= 6 and all((built / "reports" / img).is_file() for img in images)
    assert "| amcl |" in md and "| cnn_ensemble |" in md


def test_report_is_byte_deterministic(built: Path) -> None:
    first = (built / "reports/report.html").read_bytes()
    figures = {p.name: p.read_bytes() for p in (built / "reports/figures").glob("*.png")}
    build(built, CONTEXT)
    assert (built / "reports/report.html").read_bytes() == first
    assert {p.name: p.read_bytes() for p in (built / "reports/figures").glob("*.png")} == figures


def test_missing_optional_artifacts_are_reported(tmp_path: Path) -> None:
    root = make_artifacts(tmp_path)
    (root / "reports/localize_cnn/sparse_obstacles_drive/cnn_ensemble.csv").unlink()
    shutil.rmtree(root / "models/transfer")
    shutil.rmtree(root / "data/maps/simple_rooms")
    build(root, {"profile": "smoke"})
    page = (root / "reports/report.html").read_text(encoding="utf-8")
    assert "Not available: cnn_ensemble" in page
    assert "Transfer runs (models/transfer/) not available." in page
    assert "simple_rooms): not available (data/maps/simple_rooms/map.yaml)" in page
    assert claim_verdicts(page)[6] == "not testable" and "missing: transfer/scratch" in page
    assert str(tmp_path) not in page  # no absolute paths


def test_missing_required_artifacts_name_the_file(tmp_path: Path) -> None:
    root = make_artifacts(tmp_path)
    (root / "data/trajectories/sparse_obstacles_drive/truth.npy").unlink()
    with pytest.raises(FileNotFoundError, match=r"truth\.npy"):
        build(root, CONTEXT)
    root2 = make_artifacts(tmp_path / "second")
    (root2 / "reports/metrics/train_cnn2d.json").unlink()
    with pytest.raises(FileNotFoundError, match=r"train_cnn2d\.json"):
        build(root2, CONTEXT)
    amcl_csv = root2 / "reports/localize/sparse_obstacles_drive/amcl.csv"
    pd.read_csv(amcl_csv).iloc[:-1].to_csv(amcl_csv, index=False)
    (root2 / "reports/metrics/train_cnn2d.json").write_text("{}")
    with pytest.raises(ValueError, match=r"amcl\.csv"):
        build(root2, CONTEXT)


# ---------------------------------------------------------------- verdicts and their legend


def table_rows(section_html: str, cells: int) -> list[tuple[str, list[str]]]:
    """(row class, cells) of the rows with `cells` cells of a section's tables."""
    rows = re.findall(r'<tr class="([a-z-]+)">(.*?)</tr>', section_html)
    found = [(cls, re.findall(r"<td>(.*?)</td>", row)) for cls, row in rows]
    return [(cls, row) for cls, row in found if len(row) == cells]


def claims_section(page: str) -> str:
    return page.split('id="paper-claims"', 1)[1].split("<h2", 1)[0]


def test_each_claim_row_is_coloured_as_its_verdicts_legend_entry(built: Path) -> None:
    section = claims_section((built / "reports/report.html").read_text(encoding="utf-8"))
    legend = {row[0]: cls for cls, row in table_rows(section, 2)}
    assert len(legend) == 5 and len(set(legend.values())) == 5  # five verdicts, five colours
    claims = table_rows(section, 8)
    assert len(claims) == 7
    for cls, row in claims:
        assert legend[row[5]] == cls, row[0]


def test_a_measured_seed_spread_makes_close_margins_inconclusive(tmp_path: Path) -> None:
    root = make_artifacts(tmp_path)
    build(root, CONTEXT)
    smoke = (root / "reports/report.html").read_text(encoding="utf-8")
    # At the smoke profile no seed spread is configured: the legend says so, and no margin
    # between rows of one seed each is inconclusive (claims 3 and 4 are timing ratios, see above).
    assert "has no spread at profile &#x27;smoke&#x27;" in claims_section(smoke)
    smoke_verdicts = claim_verdicts(smoke)
    assert "inconclusive" not in [v for n, v in smoke_verdicts.items() if n not in (3, 4)]
    headline = build(root, CONTEXT | {"profile": "laptop"})
    page = (root / "reports/report.html").read_text(encoding="utf-8")
    laptop = claims_section(page)
    sd = REPORT_CFG["seed_spread"]["laptop"]["val_mae_sd"]
    band = REPORT_CFG["inconclusive_sigmas"] * sd * 2**0.5  # two rows of one seed each
    assert f"band ±{band:.2f}: one seed, the configured s.d. {sd:g}" in laptop
    # Claim 2's Δtrain 0.78 lies 0.08 from its 0.7, claim 5's margin 0.28 lies 0.12 from its
    # 0.4 and claim 6's map-2 margin 0.41 lies 0.41 from 0: all inside ±0.78. Claim 1's margins
    # (2.08, 2.36 against 0.4) lie outside and keep their verdict; claims 3, 4 and 7 compare
    # epoch times (inside the cross-machine factor, as above) and localization errors, without
    # a seed spread.
    assert claim_verdicts(page) == {
        1: "reproduced",
        2: "inconclusive",
        3: "inconclusive",
        4: "inconclusive",
        5: "inconclusive",
        6: "inconclusive",
        7: "direction only",
    }
    assert headline["claims_inconclusive"] == 5 and headline["claims_reproduced"] == 1
    assert "inconclusive: 2, 3, 4, 5, 6" in page  # the summary under the title


# ---------------------------------------------------------------- the localizer catalog


def copy_catalog(tmp_path: Path, edits: dict[str, dict]) -> Path:
    """conf/localizer copied, with `edits` ({config: {meta key: value}}) applied to the
    configs' `meta` sections."""
    conf = tmp_path / "localizer"
    shutil.copytree(LOCALIZER_CONF, conf)
    for name, changes in edits.items():
        cfg = yaml.safe_load((conf / f"{name}.yaml").read_text())
        cfg["meta"] = cfg["meta"] | changes
        (conf / f"{name}.yaml").write_text(yaml.safe_dump(cfg))
    return conf


def section_html(page: str, section_id: str) -> str:
    return page.split(f'id="{section_id}"', 1)[1].split("<h2", 1)[0]


def test_notes_and_the_global_table_come_from_the_localizer_catalog(tmp_path: Path) -> None:
    root = make_artifacts(tmp_path)
    build(root, CONTEXT)
    page = (root / "reports/report.html").read_text(encoding="utf-8")
    assert "<td>sparse_obstacles</td><td>amcl</td>" in section_html(page, "global-localization")
    conf = copy_catalog(
        tmp_path, {"amcl": {"global_table": False}, "cnn_single": {"note": "a test's own note"}}
    )
    build(root, CONTEXT, conf)
    page = (root / "reports/report.html").read_text(encoding="utf-8")
    assert "<td>cnn_single</td><td>a test&#x27;s own note</td>" in section_html(
        page, "localization"
    )
    assert "<td>amcl</td>" not in section_html(page, "global-localization")


def test_the_global_table_shows_rates_with_intervals_over_seeds(tmp_path: Path) -> None:
    root = make_artifacts(tmp_path)
    build(root, CONTEXT)
    section = section_html(
        (root / "reports/report.html").read_text(encoding="utf-8"), "global-localization"
    )
    # amcl tracks from the true first pose: converged at step 0 on its one seed, and the
    # fabricated estimates follow the truth through the kidnap (truth.copy() never jumps)
    assert (
        "<td>sparse_obstacles</td><td>amcl</td><td>1</td><td>1 / 1 = 100 % [21–100 %]</td>"
        in section
    )
    assert "never on the runs this table scores" in section  # what was tuned where
    assert "Converged in time: within 20 steps of the start." in section
    assert "<td>simple_rooms</td>" not in section.split("Seed 0 alone", 1)[0]  # no figures
    (root / "reports/metrics/global_localization.json").unlink()
    build(root, CONTEXT)
    page = (root / "reports/report.html").read_text(encoding="utf-8")
    assert "Over seeds: not available (reports/metrics/global_localization.json)." in page


def test_times_per_scan_come_from_the_unhashed_timing_files(tmp_path: Path) -> None:
    root = make_artifacts(tmp_path)
    doc = json.loads((root / "reports/metrics/localization.json").read_text())
    assert "time_per_scan_s" not in doc["sparse_obstacles_drive"]["amcl"]
    build(root, CONTEXT)
    table2 = section_html((root / "reports/report.html").read_text(encoding="utf-8"), "table-2")
    assert "time per scan [ms]" in table2 and "<td>500</td>" in table2  # amcl: 0.5 s
    (root / "reports/localize_timing/sparse_obstacles_drive.json").unlink()
    build(root, CONTEXT)
    table2 = section_html((root / "reports/report.html").read_text(encoding="utf-8"), "table-2")
    assert "time per scan [ms]" in table2 and "<td>500</td>" not in table2


# ---------------------------------------------------------------- provenance: '+dirty'


def _git(repo: Path, *args: str) -> None:
    subprocess.run(["git", *args], cwd=repo, check=True, capture_output=True)


def test_dirty_means_a_changed_source_not_dvc_lock_or_outputs(tmp_path: Path) -> None:
    repo = tmp_path / "repo"
    for path in ("src/scanloc/x.py", "conf/report.yaml", "dvc.yaml", "dvc.lock", "README.md"):
        (repo / path).parent.mkdir(parents=True, exist_ok=True)
        (repo / path).write_text("one\n")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "first")
    paths = REPORT_CFG["source_paths"]
    clean = git_commit(repo, paths)
    assert clean is not None and re.fullmatch(r"[0-9a-f]{40}", clean)
    (repo / "dvc.lock").write_text("rewritten by dvc repro\n")  # as while the stage runs
    (repo / "reports").mkdir()
    (repo / "reports/report.md").write_text("an untracked DVC output\n")
    (repo / "README.md").write_text("docs do not change results\n")
    assert git_commit(repo, paths) == clean
    for source in ("src/scanloc/x.py", "conf/report.yaml", "dvc.yaml"):
        (repo / source).write_text("two\n")
        assert git_commit(repo, paths) == clean + "+dirty", source
        (repo / source).write_text("one\n")
    assert git_commit(repo, paths) == clean
    assert git_commit(tmp_path, paths) is None  # not a git checkout


# ---------------------------------------------------------------- real browser


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    return None


class _DevTools:
    """A minimal Chrome DevTools Protocol client over --remote-debugging-pipe (fds 3 and 4)."""

    def __init__(self, exe: str, profile_dir: Path) -> None:
        to_child, self._out = os.pipe()
        self._in, from_child = os.pipe()
        flags = [
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-extensions",
            "--remote-debugging-pipe",
            f"--user-data-dir={profile_dir}",
            "about:blank",
        ]
        self.proc = subprocess.Popen(
            # bash, not sh: dash cannot redirect file descriptors above 9.
            ["bash", "-c", f'exec "$0" "$@" 3<&{to_child} 4>&{from_child}', exe, *flags],
            pass_fds=(to_child, from_child),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        os.close(to_child)
        os.close(from_child)
        self._buffer, self._next_id, self.events = b"", 0, []

    def _message(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            ready, _, _ = select.select([self._in], [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                raise TimeoutError("no answer from Chromium")
            chunk = os.read(self._in, 1 << 20)
            if not chunk:
                raise EOFError("Chromium closed the DevTools pipe")
            self._buffer += chunk
        raw, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, session: str | None = None, timeout: float = 20.0, **params):
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self._out, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._message(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]
            self.events.append(reply)

    def wait_for(self, method: str, timeout: float = 20.0) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            for event in self.events:
                if event.get("method") == method:
                    return event
            self.events.append(self._message(deadline))

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout=5.0)
        except (OSError, EOFError, TimeoutError, RuntimeError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._in)
        os.close(self._out)


def render_in_chromium(page: Path, profile_dir: Path, screenshot: Path | None = None) -> dict:
    """Open `page` in headless Chromium at a laptop's window size; report the images' decoded
    sizes, the URLs the page requested, console/CSP messages and the section ids."""
    exe = _chromium()
    assert exe is not None
    browser = _DevTools(exe, profile_dir)
    try:
        target = browser.call("Target.createTarget", url="about:blank")["targetId"]
        session = browser.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Page", "Network", "Log", "Runtime"):
            browser.call(f"{domain}.enable", session)
        browser.call(
            "Emulation.setDeviceMetricsOverride",
            session,
            width=1366,
            height=768,
            deviceScaleFactor=1,
            mobile=False,
        )
        browser.call("Page.navigate", session, url=page.resolve().as_uri())
        browser.wait_for("Page.loadEventFired")
        probe = (
            "JSON.stringify({images: Array.from(document.images).map(i => [i.complete, "
            "i.naturalWidth, i.naturalHeight, i.getBoundingClientRect().width]), "
            "sections: Array.from(document.querySelectorAll('h2')).map(h => h.id), "
            "scrollWidth: document.documentElement.scrollWidth})"
        )
        result = browser.call("Runtime.evaluate", session, expression=probe, returnByValue=True)
        found = json.loads(result["result"]["value"])
        if screenshot is not None:
            shot = browser.call("Page.captureScreenshot", session, format="png")
            screenshot.write_bytes(base64.b64decode(shot["data"]))
    finally:
        browser.close()
    found["requests"] = [
        e["params"]["request"]["url"]
        for e in browser.events
        if e.get("method") == "Network.requestWillBeSent"
    ]
    found["messages"] = [
        e["params"]["entry"]["text"] for e in browser.events if e.get("method") == "Log.entryAdded"
    ]
    return found


@pytest.mark.skipif(_chromium() is None, reason="no chromium installed (apt-get install chromium)")
def test_report_renders_offline_in_chromium(built: Path, tmp_path: Path) -> None:
    found = render_in_chromium(built / "reports/report.html", tmp_path / "profile")
    images = found["images"]
    assert len(images) >= 6
    assert all(complete and width > 0 and height > 0 for complete, width, height, _ in images)
    assert all(shown <= 1100 for *_, shown in images)  # scaled to the column, no overflow
    assert found["scrollWidth"] <= 1366  # no horizontal scrolling on a laptop screen
    assert found["sections"] == [i for i, _ in registry_headings(CONTEXT["sites"])]
    remote = [u for u in found["requests"] if not u.startswith(("file:", "data:", "about:"))]
    assert remote == []
    assert not [m for m in found["messages"] if "Content Security Policy" in m]
