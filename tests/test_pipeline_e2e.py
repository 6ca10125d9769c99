"""End to end: the whole `dvc repro` on the smoke profile in a temporary copy of the repository,
with two generated maps added to params.yaml's `maps` beside the paper's (a user's own maps)."""

from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from PIL import Image

from scanloc.report.sections.registry import SECTIONS

pytestmark = pytest.mark.e2e  # a full smoke `dvc repro`: minutes (make test-all)

REPO_ROOT = Path(__file__).resolve().parents[1]

TABLE2_KEYS = {
    "x_err_mean",
    "x_err_std",
    "y_err_mean",
    "y_err_std",
    "theta_sin_err_mean",
    "theta_sin_err_std",
    "pos_err_mean_m",
    "pos_err_median_m",
    "heading_err_mean_deg",
}
TABLE1_ROWS = ("mlp", "cnn1d_20k", "cnn1d_200k", "cnn2d")
PAPER_MAPS = ("sparse_obstacles", "simple_rooms")
# A user's maps, added as the README says: a 50 x 25 m rooms map and a 30 x 30 m sparse one
# (both in the scans-from-scratch check, tests/test_pipeline_e2e_scans.py).
USER_MAPS = {
    "big_rooms": {
        "config": "generated_rooms",
        "overrides": "map.width=50.0 map.height=25.0 map.seed=2",
        "depends": "conf/map/generated_rooms.yaml",
    },
    "sparse30": {
        "config": "generated_sparse",
        "overrides": "map.width=30.0 map.height=30.0 map.resolution=0.05 map.seed=3",
        "depends": "conf/map/generated_sparse.yaml",
    },
}
# The smoke repro runs one site of each kind it can: the rooms map beside the paper's two, and
# the first real log (intel): a site costs the repro 16 stages, and this repro is the critical
# path of CI (tests/conftest.py); each further site of a kind takes the same code path.
EXTRA_MAPS = {"big_rooms": USER_MAPS["big_rooms"]}
SMOKE_LOGS = ("intel",)
# One tune study, on a log's tune runs: every study's config is checked without running it
# (tests/test_tune.py), a tune map's chain by the stage list (tests/test_config.py) and the
# committed dvc.lock; each site and stage costs the smoke repro CI time (its budget: 30 min).
SMOKE_STUDIES = ("amcl_real_recovery",)
# Two of a map's five scored kidnap seeds (conf/seeds.yaml `runs.map`): the run-clustered
# intervals need two runs; every localizer runs on each run of each map (a localize stage of
# 30 to 120 s at the smoke profile, where the barely trained network slows the hybrids), so the
# three seeds more would cost the smoke repro about 10 minutes of CI's 30 for the same code path.
SMOKE_MAP_RUNS = ("drive", "kidnap", "kidnap_s1", "tune_kidnap")
GLOBAL_LOCALIZERS = ("amcl_global", "amcl_recovery", "hybrid")
REAL_LOG = REPO_ROOT.parent / "shared" / "data" / "carmen" / "intel-corrected.log.gz"


def project_files() -> list[str]:
    """Tracked and untracked-but-not-ignored files: what a clean clone (plus local edits) holds."""
    out = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard"],
        cwd=REPO_ROOT,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return [f for f in out.splitlines() if (REPO_ROOT / f).is_file()]


def copy_project(
    dest: Path,
    profile: str,
    extra_maps: dict | None = None,
    logs: tuple[str, ...] = SMOKE_LOGS,
    tune_maps: int = 0,
    studies: tuple[str, ...] = SMOKE_STUDIES,
    map_runs: tuple[str, ...] = SMOKE_MAP_RUNS,
) -> Path:
    """A fresh copy of the project (no data, models or DVC cache) set to `profile`, with
    `extra_maps` added to params.yaml's `maps`, its first `tune_maps` tune maps, only the real
    `logs` of its `real_logs` (those present beside the repository), those of the tune
    `studies` these sites can run, and only the `map_runs` of a map's runs."""
    for rel in project_files():
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO_ROOT / rel, target)
    (dest / "dvc.lock").unlink(missing_ok=True)
    params = yaml.safe_load((dest / "params.yaml").read_text())
    params["profile"] = profile
    params["maps"] |= extra_maps or {}
    # The real logs live beside the repository (../shared): point the copy at them, or drop
    # the real-data stages where they are absent.
    present = {}
    params_logs = params.get("real_logs") or {}
    for name, entry in params_logs.items():
        log = (REPO_ROOT / entry["log"]).resolve()
        if log.is_file() and name in logs:
            present[name] = entry | {"log": str(log)}
    params["real_logs"] = present
    ablated = params.get("real_ablation_logs") or []
    params["real_ablation_logs"] = [n for n in ablated if n in present]
    params["tune_maps"] = dict(list((params.get("tune_maps") or {}).items())[:tune_maps])
    dropped_logs = set(params_logs) - set(present)
    params["tune_studies"] = [
        study for study in params.get("tune_studies") or []
        if study in studies
        and not dropped_logs & study_sites(dest / "conf" / "study" / f"{study}.yaml")
    ]  # fmt: skip
    (dest / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    seeds_file = dest / "conf" / "seeds.yaml"
    seeds = yaml.safe_load(seeds_file.read_text())
    seeds["runs"]["map"] = {
        part: [run for run in runs if run in map_runs]
        for part, runs in seeds["runs"]["map"].items()
    }  # fmt: skip
    seeds_file.write_text(yaml.safe_dump(seeds, sort_keys=False))
    # as `make repro` does: the sites and jobs of this params.yaml written down for dvc.yaml
    subprocess.run([sys.executable, "-m", "scanloc.sites"], cwd=dest, check=True)
    subprocess.run(["git", "init", "-q"], cwd=dest, check=True)
    return dest


def study_sites(study_file: Path) -> set[str]:
    """The sites a tune study's explicit run entries localize in."""
    runs = yaml.safe_load(study_file.read_text())["runs"]
    return {run["map_name"] for run in runs if "map_name" in run}


def dvc(cwd: Path, *args: str, timeout: int = 1500) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.pop("SCANLOC_CONF", None)
    result = subprocess.run(
        [str(Path(sys.executable).parent / "dvc"), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert result.returncode == 0, f"dvc {' '.join(args)} failed:\n{result.stdout}\n{result.stderr}"
    return result


def lock_outs(repo: Path, prefixes: tuple[str, ...]) -> dict[str, str]:
    """Data output path -> md5 of the stages whose names start with one of `prefixes` (the
    paper's maps and datasets only)."""
    lock = yaml.safe_load((repo / "dvc.lock").read_text())
    return {
        out["path"]: out["md5"]
        for name, stage in lock["stages"].items()
        if name.startswith(prefixes)
        for out in stage.get("outs", [])
        if out["path"].startswith("data/") and not any(m in out["path"] for m in USER_MAPS)
    }


# A user's new localizer: one YAML file in conf/localizer and nothing else (a new kind would
# add one registered class: tests/test_localize_stage.py).
DUMMY_LOCALIZER = "amcl_dummy"
DUMMY_NOTE = "a user's own amcl variant, added as one YAML file"
DUMMY_YAML = f"""defaults:
  - amcl
  - _self_
meta:
  name: {DUMMY_LOCALIZER}
  kind: particle_filter
  group: tracking
  stages: [localize]
  global_table: true
  note: "{DUMMY_NOTE}"
sensor:
  laser_max_beams: 12
"""


@pytest.fixture(scope="module")
def smoke_repo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    repo = copy_project(tmp_path_factory.mktemp("smoke") / "repo", "smoke", EXTRA_MAPS)
    (repo / "conf" / "localizer" / f"{DUMMY_LOCALIZER}.yaml").write_text(DUMMY_YAML)
    dvc(repo, "repro")
    return repo


def test_a_localizer_added_as_one_yaml_reaches_the_metrics_and_the_report(
    smoke_repo: Path,
) -> None:
    localization = json.loads((smoke_repo / "reports/metrics/localization.json").read_text())
    for name in (*PAPER_MAPS, *EXTRA_MAPS):
        for run in ("drive", "kidnap"):
            assert TABLE2_KEYS <= set(localization[f"{name}_{run}"][DUMMY_LOCALIZER]), (name, run)
    markdown = (smoke_repo / "reports/report.md").read_text()
    assert DUMMY_NOTE in markdown
    assert markdown.count(f"| {DUMMY_LOCALIZER} |") >= len(PAPER_MAPS) + len(EXTRA_MAPS)


def test_smoke_repro_is_up_to_date(smoke_repo: Path) -> None:
    status = json.loads(dvc(smoke_repo, "status", "--json").stdout)
    assert status == {}, status


def test_smoke_repro_writes_the_contract_artifacts(smoke_repo: Path) -> None:
    grid_meta = yaml.safe_load((smoke_repo / "data/maps/sparse_obstacles/map.yaml").read_text())
    assert grid_meta["resolution"] == pytest.approx(0.02)
    for name in (*PAPER_MAPS, *EXTRA_MAPS):
        assert (smoke_repo / f"data/maps/{name}/map.yaml").is_file()
        for run in ("drive", "kidnap"):
            assert (smoke_repo / f"data/trajectories/{name}_{run}/meta.json").is_file()
    big = yaml.safe_load((smoke_repo / "data/maps/big_rooms/map.yaml").read_text())
    assert big["resolution"] == pytest.approx(0.05)
    for name in ("map1_small", "map1_large", "map2_small", "big_rooms_val"):
        meta = json.loads((smoke_repo / f"data/scans/{name}/meta.json").read_text())
        assert meta["count"] > 0
    html = (smoke_repo / "reports/report.html").read_text()
    assert html.count('src="data:image/png;base64,') >= 6
    assert "http://" not in html and "https://" not in html
    markdown = (smoke_repo / "reports/report.md").read_text()
    for spec in SECTIONS:
        if "{name}" in spec.id:  # the per-site sections, checked below
            continue
        assert f'id="{spec.id}"' in html, spec.id
        assert spec.title in markdown, spec.title
    for name in (*PAPER_MAPS, *EXTRA_MAPS):  # one section per site
        assert f'<h2 id="site-{name}">Site {name} (map)</h2>' in html, name


def test_smoke_metrics_hold_every_contract_metric(smoke_repo: Path) -> None:
    shown = json.loads(dvc(smoke_repo, "metrics", "show", "--json").stdout)
    metrics: dict[str, dict] = {}
    for workspace in shown.values():
        for path, content in workspace["data"].items():
            metrics[path] = content["data"]
    for row in TABLE1_ROWS:
        assert "val_mae" in metrics[f"reports/metrics/train_{row}.json"]
        # Machine-dependent figures beside the wall time, shown but never hashed.
        timing = metrics[f"reports/timing/train_{row}.json"]
        assert timing["wall_s"] > 0 and timing["epoch_s"] > 0, row
        assert "epoch_s" not in metrics[f"reports/metrics/train_{row}.json"], row
    # The wall times are shown (dvc.yaml's top-level metrics) but never hashed into dvc.lock.
    assert metrics["reports/localize_timing/sparse_obstacles_drive.json"]["amcl"]["setup_s"] >= 0
    lock = yaml.safe_load((smoke_repo / "dvc.lock").read_text())
    hashed = [
        entry["path"]
        for stage in lock["stages"].values()
        for entry in (*stage.get("deps", []), *stage.get("outs", []))
    ]
    assert not [p for p in hashed if p.startswith(("reports/timing", "reports/localize_timing"))]
    localization = metrics["reports/metrics/localization.json"]
    for method in ("amcl", "cnn_single", "cnn_ensemble"):
        assert TABLE2_KEYS <= set(localization["sparse_obstacles_drive"][method]), method
    for name in (*PAPER_MAPS, *EXTRA_MAPS):
        for run in ("drive", "kidnap"):
            per_run = localization[f"{name}_{run}"]
            assert TABLE2_KEYS <= set(per_run["amcl"]), (name, run)
            for method in GLOBAL_LOCALIZERS:
                assert "steps_to_converge" in per_run[method], (name, run, method)
            for method in ("scanlocnet", "scanlocnet_track"):
                keys = {"pos_err_median_m", "frac_gross_over_1m", "top5_recall"}
                assert keys <= set(per_run[method]), (name, run, method)
        kidnap = localization[f"{name}_kidnap"]
        for method in GLOBAL_LOCALIZERS:
            assert {"recovery_steps_1", "recovery_steps_max", "recovered"} <= set(kidnap[method])
        assert "val_top5_recall" in metrics[f"reports/metrics/scanlocnet_{name}.json"]
        assert metrics[f"reports/timing/train_scanlocnet_{name}.json"]["epoch_s"] > 0
    if not REAL_LOG.is_file():
        return
    for run in ("real", "sim"):
        per_run = localization[f"intel_{run}"]
        for method in ("amcl", "amcl_global", "hybrid", "scanlocnet"):
            assert {"pos_err_rmse_m", "steps_to_converge"} <= set(per_run[method]), (run, method)
        assert per_run["amcl"]["n_steps"] == 50  # the middle half of smoke's first 100 scans
        assert "top5_recall" in per_run["scanlocnet"]
    # Real logs over filter seeds, both odometry sources (the seeds contract of design.md).
    seeds = metrics["reports/metrics/real_seeds.json"]
    compared = set(
        yaml.safe_load((REPO_ROOT / "conf" / "localize_seeds.yaml").read_text())["compared"]
    )
    assert {"amcl", "amcl_real", "amcl_global", "hybrid", "scanlocnet"} <= compared
    for run in ("intel_real", "intel_kidnap"):
        for odometry in ("wheel", "laser"):
            figures = seeds[run][odometry]
            assert set(figures) == compared  # every compared localizer, no other
            for name, per_localizer in figures.items():
                expected = 1 if name == "scanlocnet" else 2  # deterministic: one run
                assert per_localizer["n_seeds"] == expected, (run, odometry, name)
                for key in ("pos_err_rmse_m", "heading_err_rmse_deg", "steps_to_converge"):
                    assert {key, f"{key}_ci95_low", f"{key}_ci95_high"} <= set(per_localizer)
                assert len(per_localizer["seeds"]) == expected


@pytest.mark.skipif(not REAL_LOG.is_file(), reason="needs ../shared/data/carmen (the real logs)")
def test_smoke_repro_runs_the_real_log(smoke_repo: Path) -> None:
    assert (smoke_repo / "data/maps/intel/map.yaml").is_file()
    meta = json.loads((smoke_repo / "data/trajectories/intel_real/meta.json").read_text())
    assert meta["num_steps"] == 50 and meta["num_beams"] == 180  # the evaluated half
    html = (smoke_repo / "reports/report.html").read_text()
    log_section = html.split('<h2 id="site-intel">Site intel (log)</h2>', 1)[1].split("<h2", 1)[0]
    assert "sim-to-real" in log_section and "intel_real" in log_section


@pytest.mark.skipif(not REAL_LOG.is_file(), reason="needs ../shared/data/carmen (the real logs)")
def test_smoke_repro_records_each_tune_study_on_tune_runs_only(smoke_repo: Path) -> None:
    """Every study of tune_studies ran as a DVC stage on tune runs only, its trials a plot of
    `dvc plots show`."""
    params = yaml.safe_load((smoke_repo / "params.yaml").read_text())
    assert params["tune_studies"] == list(SMOKE_STUDIES)
    for study in params["tune_studies"]:
        record = json.loads((smoke_repo / f"reports/tuning/{study}.json").read_text())
        assert record["trials"][0]["trial"] == 0
        assert all("score" in t or "skipped" in t for t in record["trials"])
        for run in record["runs"]:
            meta_path = smoke_repo / "data/trajectories" / run.split("/")[0] / "meta.json"
            assert json.loads(meta_path.read_text())["part"] == "tune", (study, run)
    plots = json.loads(dvc(smoke_repo, "plots", "show", "--json").stdout)["data"]
    assert f"reports/tuning/{SMOKE_STUDIES[0]}.json" in plots, sorted(plots)


def test_two_experiments_compare_in_one_narrow_table(smoke_repo: Path) -> None:
    """Two DVC experiments on the smoke pipeline (last in this module: they change the
    workspace), compared by the README's command: one table of at most 120 columns, and the
    page, read from the experiments' DVC artifacts. The changed parameter is a claim tolerance,
    so that only the report stage re-runs."""
    env = dict(os.environ, GIT_AUTHOR_NAME="t", GIT_AUTHOR_EMAIL="t@t", GIT_COMMITTER_NAME="t")
    env["GIT_COMMITTER_EMAIL"] = "t@t"
    for args in (["add", "-A"], ["commit", "-qm", "smoke"]):
        subprocess.run(["git", *args], cwd=smoke_repo, env=env, check=True)
    knob = "conf/report.yaml:claims.claim7.delta_tolerance_m"
    for name, value in (("tol-low", 0.01), ("tol-high", 5.0)):
        dvc(smoke_repo, "exp", "run", "-q", "-n", name, "-S", f"{knob}={value}")
    result = subprocess.run(
        [sys.executable, "-m", "scanloc.stages.compare", "experiments=[tol-low,tol-high]"],
        cwd=smoke_repo,
        env={k: v for k, v in env.items() if k not in ("DVC_STAGE", "SCANLOC_CONF")},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert max(map(len, lines)) <= 120, max(lines, key=len)
    header = next(line for line in lines if line.startswith("metric "))
    assert "tol-low" in header and "tol-high" in header
    assert any(line.startswith("claims.claim7.delta_tolerance_m") or knob in line for line in lines)
    assert any(line.startswith("pos_amcl ") for line in lines)
    page = re.search(r"compare: wrote (\S+)compare\.html", result.stdout)
    assert page, result.stdout
    folder = smoke_repo / page.group(1)
    html = (folder / "compare.html").read_text()
    assert (folder / "compare.md").is_file()
    for section in ("params", "metrics", "curves", "errors"):
        assert f'id="{section}"' in html, section
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', html)
    assert len(images) >= 2
    for data in images:
        Image.open(io.BytesIO(base64.b64decode(data))).verify()
    assert "http://" not in html and "https://" not in html
