"""The localize stage runs the localizers conf/localizer lists for it: adding one is one yaml
file (plus one registered kind for a new kind), and a listed localizer's field can be
overridden from the command line."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir

from scanloc.estimates import Localization, estimate_table
from scanloc.localize.catalog import localizer_overrides, stage_localizers
from scanloc.localize.kinds import KIND_SECTIONS, LOCALIZER_KINDS, LocalizeInputs, register_kind
from scanloc.stages.localize import run_stage
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import save_trajectory
from scanloc.world.map_server import save_map
from small_world import small_map, ug01_scans

CONF = Path(__file__).resolve().parents[1] / "conf"
DUMMY = """\
meta:
  name: dummy
  kind: dummy_offset
  group: tracking
  stages: [localize]
  note: "a test's localizer: the truth, shifted by `offset`"
shift:
  offset: [0.25, 0.0, 0.0]
"""


@pytest.fixture
def dummy_kind() -> Iterator[None]:
    """A kind registered by the test alone, reading its own section: the true poses shifted by
    the `shift` section's offset."""

    @register_kind("dummy_offset", ("shift",))
    def run_dummy(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
        traj = inputs.trajectory
        steps = len(traj.times)
        means = traj.truth + np.asarray(cfg["shift"]["offset"], dtype=np.float64)
        covs = np.tile(np.eye(3) * 0.01, (steps, 1, 1))
        table = estimate_table(np.arange(steps), traj.times, means, covs, 1)
        return Localization(table, 0.0, np.zeros(steps))

    yield
    del LOCALIZER_KINDS["dummy_offset"], KIND_SECTIONS["dummy_offset"]


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    """A copy of conf/ where only the dummy localizer lists the localize stage, a small map
    and a 20-step drive through it."""
    conf = tmp_path / "conf"
    shutil.copytree(CONF, conf)
    for path in (conf / "localizer").glob("*.yaml"):
        text = re.sub(r"^(\s*)stages: \[localize\]$", r"\1stages: []", path.read_text(), flags=re.M)
        path.write_text(text)
    (conf / "localizer" / "dummy.yaml").write_text(DUMMY)
    grid = small_map()
    save_map(grid, tmp_path / "map" / "map.yaml")
    traj = drive_trajectory(grid, 20, seed=1, clearance=0.25)
    save_trajectory(traj, tmp_path / "traj", ug01_scans(grid, traj.truth, seed=2), meta={})
    return tmp_path


def localize(run_dir: Path, monkeypatch: pytest.MonkeyPatch, *extra: str) -> Path:
    """The stage, in this process (where the dummy kind is registered), on run_dir's inputs."""
    conf = run_dir / "conf"
    monkeypatch.setenv("SCANLOC_CONF", str(conf))
    out = run_dir / "out"
    overrides = [
        "trajectory=tiny",
        f"trajectory_dir={run_dir / 'traj'}",
        f"map_yaml={run_dir / 'map' / 'map.yaml'}",
        f"out_dir={out}",
        f"timing_path={run_dir / 'timing.json'}",
        f"timing_dir={run_dir / 'timing'}",
        *extra,
    ]
    with initialize_config_dir(config_dir=str(conf), version_base=None):
        run_stage(compose("localize", overrides=overrides), "localize", overrides)
    return out


def test_a_localizer_added_as_one_yaml_file_is_run_by_the_stage(
    run_dir: Path, dummy_kind: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert stage_localizers("localize", run_dir / "conf" / "localizer") == ["dummy"]
    out = localize(run_dir, monkeypatch)
    assert sorted(p.name for p in out.iterdir()) == ["dummy.csv"]
    table = pd.read_csv(out / "dummy.csv")
    truth = np.load(run_dir / "traj" / "truth.npy")
    np.testing.assert_allclose(table.x - truth[:, 0], 0.25, atol=1e-6)
    assert (run_dir / "timing.json").read_text().count('"dummy"') == 1
    # A listed localizer's key, overridden on the command line, reaches its kind.
    localize(run_dir, monkeypatch, "++localizers.dummy.shift.offset=[0.0,-0.5,0.0]")
    table = pd.read_csv(out / "dummy.csv")
    np.testing.assert_allclose(table.x - truth[:, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(table.y - truth[:, 1], -0.5, atol=1e-6)


def test_only_must_name_a_listed_localizer(
    run_dir: Path, dummy_kind: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(ValueError, match=r"only=amcl: not one of this stage's localizers"):
        localize(run_dir, monkeypatch, "only=amcl")


def test_the_shipped_lists_hold_what_the_evaluation_and_report_need() -> None:
    """The localizers whose metrics the summary, the claims and the real-data section read must
    be listed; any other listed localizer is simply one more row (one YAML file each)."""
    listed = stage_localizers("localize", CONF / "localizer")
    needed = {"amcl", "amcl_global", "amcl_recovery", "hybrid", "scanlocnet", "scanlocnet_track"}
    assert needed <= set(listed)
    assert listed == sorted(listed)  # file-name order: the order they run and are written in
    cnn = stage_localizers("localize_cnn", CONF / "localizer")
    assert cnn == ["cnn_ekf", "cnn_ensemble", "cnn_single"]
    assert localizer_overrides("localize_cnn", CONF / "localizer")[0] == (
        "+localizer@localizers.cnn_ekf=cnn_ekf"
    )


def test_a_kind_cannot_be_registered_twice() -> None:
    with pytest.raises(ValueError, match="'particle_filter' is registered twice"):
        register_kind("particle_filter")(lambda cfg, inputs: Localization(pd.DataFrame(), 0.0, []))


def test_the_odometry_source_and_the_laser_mount_reach_the_localizers(
    run_dir: Path, dummy_kind: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`odometry=laser` hands every localizer laser_odometry.npy as its odometry, and the run's
    meta.json `laser_mount` arrives in LocalizeInputs; a run without laser odometry fails
    naming its folder."""
    seen: dict[str, Any] = {}

    @register_kind("dummy_inputs", ("shift",))
    def run_inputs(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
        seen["odometry"], seen["mount"] = inputs.trajectory.odometry, inputs.laser_mount
        steps = len(inputs.trajectory.times)
        covs = np.tile(np.eye(3), (steps, 1, 1))
        table = estimate_table(np.arange(steps), inputs.trajectory.times, seen["odometry"], covs, 1)
        return Localization(table, 0.0, np.zeros(steps))

    try:
        (run_dir / "conf" / "localizer" / "dummy.yaml").write_text(
            DUMMY.replace("dummy_offset", "dummy_inputs")
        )
        traj_dir = run_dir / "traj"
        with pytest.raises(FileNotFoundError, match=f"{traj_dir}: odometry=laser"):
            localize(run_dir, monkeypatch, "odometry=laser")
        wheel = np.load(traj_dir / "odometry.npy")
        np.save(traj_dir / "laser_odometry.npy", wheel + 0.5)
        meta = json.loads((traj_dir / "meta.json").read_text())
        meta["laser_mount"] = [0.08, 0.0, 0.0]
        (traj_dir / "meta.json").write_text(json.dumps(meta))
        localize(run_dir, monkeypatch)
        np.testing.assert_array_equal(seen["odometry"], wheel)
        assert seen["mount"] == (0.08, 0.0, 0.0)
        localize(run_dir, monkeypatch, "odometry=laser")
        np.testing.assert_array_equal(seen["odometry"], wheel + 0.5)
        with pytest.raises(ValueError, match="field 'odometry': expected one of"):
            localize(run_dir, monkeypatch, "odometry=gps")
    finally:
        del LOCALIZER_KINDS["dummy_inputs"], KIND_SECTIONS["dummy_inputs"]


def test_a_name_with_hydras_global_keyword_is_composed_whole() -> None:
    """Hydra reads `_global_` in a package path as its root package: amcl_global_matched must
    still be composed under its own key and found by its name."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF.resolve()), version_base=None):
        cfg = compose(
            config_name="localize",
            overrides=[
                "map_name=sparse_obstacles",
                *localizer_overrides("localize", CONF / "localizer"),
            ],
        )
    names = sorted(str(c.meta.name) for c in cfg.localizers.values())
    assert names == stage_localizers("localize", CONF / "localizer")
    assert "amcl_global_matched" in names
