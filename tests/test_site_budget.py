"""A site too large to train on this machine is refused up front (scanloc.stages.site_budget):
the maps stage for a map, the real stage for a CARMEN log's map, with the estimate, the limit
and the setting to change, in seconds and without a traceback."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from scanloc.stages.budget import PipelineSizes
from scanloc.stages.site_budget import (
    TrainingTooLongError,
    check_training_time,
    training_limit_minutes,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
# A real log's map at the laptop profile (conf/scale/laptop/scanlocnet.yaml: 1700 scans per cell)
REAL_LAPTOP = PipelineSizes(
    datasets={"site_val": 2000},
    num_beams=361,
    scans_per_epoch=25_000,
    epochs=12,
    val_scans=2000,
    min_samples_per_cell=1700,
)


def test_a_building_of_215_by_177_m_is_refused_with_the_estimate() -> None:
    """The building of issue 41 (its map 215 x 177 m): ~38 000 pose cells of 1 m, whose
    training would need thousands of epochs: refused, naming the estimate and the setting."""
    with pytest.raises(TrainingTooLongError) as refused:
        check_training_time("real log big (big.log)", REAL_LAPTOP, 38_000, "laptop", 30.0, True)
    message = str(refused.value)
    assert message.startswith(
        "real log big (big.log): ScanLocNet's training at profile laptop: 38000 pose cells, "
        "2584 epochs, ~"
    )
    assert "in bf16 on this CPU (2 cores), over the limit of 30 min (conf/maps.yaml: field " in (
        message
    )
    assert "'checks.max_training_min.laptop')" in message
    assert "raise checks.max_training_min.laptop in conf/maps.yaml" in message


def test_a_site_within_the_limit_gets_its_estimate_and_no_limit_means_none() -> None:
    sentence = check_training_time("intel", REAL_LAPTOP, 625, "laptop", 30.0, False)
    assert sentence.startswith("ScanLocNet's training at profile laptop: 625 pose cells, 43 epochs")
    assert sentence.endswith("in float32 on this CPU (2 cores)")
    assert check_training_time("big", REAL_LAPTOP, 38_000, "paper", None, True).startswith(
        "ScanLocNet's training at profile paper: 38000 pose cells"
    )


@pytest.mark.parametrize(
    ("limits", "error"),
    [
        ({"laptop": 30}, r"field 'checks.max_training_min.smoke': expected a limit in minutes"),
        ({"smoke": -1}, r"'checks.max_training_min.smoke': expected minutes > 0 or null, got -1"),
        ({"smoke": "soon"}, r"expected minutes > 0 or null, got 'soon'"),
        (None, r"expected a limit in minutes \(or null\) for profile 'smoke', got None"),
    ],
)
def test_a_bad_limit_names_the_field(limits: object, error: str) -> None:
    with pytest.raises(ValueError, match=error):
        training_limit_minutes({"max_training_min": limits}, "smoke")
    assert training_limit_minutes({"max_training_min": {"smoke": None}}, "smoke") is None


def stage(module: str, tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess[str]:
    """A stage by hand from the repository root, writing under tmp_path only."""
    env = {k: v for k, v in os.environ.items() if k not in ("SCANLOC_CONF", "DVC_STAGE")}
    env.pop("SCANLOC_TRACEBACK", None)
    command = [sys.executable, "-m", module, f"hydra.run.dir={tmp_path / 'run'}", *overrides]
    return subprocess.run(
        command, cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=300
    )


def hall_ranges(x: float, y: float, theta: float, angles: np.ndarray, size: tuple) -> np.ndarray:
    """Ranges from (x, y, theta) to the walls of an empty [0, w] x [0, h] hall."""
    w, h = size
    c, s = np.cos(theta + angles), np.sin(theta + angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (w - x) / c, np.where(c < 0, -x / c, np.inf))
        ty = np.where(s > 0, (h - y) / s, np.where(s < 0, -y / s, np.inf))
    return np.minimum(tx, ty)


def write_hall_log(path: Path, size: tuple[float, float], margin: float) -> Path:
    """A CARMEN log of a robot driving a loop `margin` m inside an empty hall, with a 361-beam
    180° SICK reading up to 81.9 m, every 0.5 m of the loop."""
    w, h = size
    corners = [
        (margin, margin),
        (w - margin, margin),
        (w - margin, h - margin),
        (margin, h - margin),
    ]
    angles = np.radians(np.linspace(-90.0, 90.0, 361))
    lines = ["# message formats defined: PARAM SYNC ODOM FLASER RLASER"]
    t = 0.0
    for k, (x0, y0) in enumerate(corners):
        x1, y1 = corners[(k + 1) % 4]
        theta = math.atan2(y1 - y0, x1 - x0)
        steps = int(math.hypot(x1 - x0, y1 - y0) / 0.5)
        for i in range(steps):
            x, y = x0 + (x1 - x0) * i / steps, y0 + (y1 - y0) * i / steps
            ranges = np.minimum(hall_ranges(x, y, theta, angles, size), 81.9)
            pose = f"{x:.3f} {y:.3f} {theta:.5f}"
            lines.append(f"ODOM {pose} 0 0 0 {t:.3f} host {t:.3f}")
            readings = " ".join(f"{r:.2f}" for r in ranges)
            lines.append(f"FLASER 361 {readings} {pose} {pose} {t:.3f} host {t:.3f}")
            t += 0.2
    path.write_text("\n".join(lines) + "\n")
    return path


def test_the_real_stage_refuses_a_large_building_in_seconds(tmp_path: Path) -> None:
    """A 100 x 70 m hall: its map holds thousands of 1 m pose cells, which the laptop
    profile's real-log training could not cover in 30 min; refused right after mapping, with
    the estimate, exit status 2, no traceback and nothing written."""
    log = write_hall_log(tmp_path / "hall.log", (100.0, 70.0), 15.0)
    start = time.perf_counter()
    done = stage("scanloc.stages.real", tmp_path, "log_name=hall", f"log={log}", "profile=laptop")
    elapsed = time.perf_counter() - start
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert f"scanloc.stages.real: error: real log hall ({log}): ScanLocNet's training at " in (
        done.stderr
    )
    assert "over the limit of 30 min (conf/maps.yaml: field 'checks.max_training_min.laptop')" in (
        done.stderr
    )
    assert elapsed < 30.0
    assert not (tmp_path / "run" / "data").exists()
