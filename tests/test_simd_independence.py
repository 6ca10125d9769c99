"""Data outputs are the same bytes whatever the CPU's SIMD level: numpy picks AVX-512 kernels for
some float64 functions (arctan2, exp, ...) that differ in the last bits from the AVX2 (libm)
ones, so the code that writes data must not depend on them. Each case runs twice in a
subprocess, once as this CPU is and once with numpy's AVX-512 paths disabled
(NPY_DISABLE_CPU_FEATURES), and compares the bytes of what it computed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
INTEL_LOG = REPO_ROOT.parent / "shared" / "data" / "carmen" / "intel-corrected.log.gz"

# Printed first by every case: numpy's arctan2 and exp on a probe, which differ between the two
# runs exactly when disabling AVX-512 changed numpy's paths (else the comparison proves nothing).
PROBE = """
import hashlib, json, math, sys
import numpy as np

def digest(a):
    return hashlib.md5(np.ascontiguousarray(a).tobytes()).hexdigest()

x = np.random.default_rng(0).uniform(-4.0, 4.0, 20_000)
out = {"probe": digest(np.arctan2(x, x[::-1])) + digest(np.exp(x))}
"""

REAL_CASE = (
    PROBE
    + """
from scanloc.real.carmen import read_carmen_log
from scanloc.real.carmen_laser import clean_ranges
from scanloc.real.carmen_odometry import scan_odometry, wrap_logged_headings
from scanloc.real.log_mapping import build_map_from_log
from scanloc.trajectory.laser_odometry import laser_odometry

log = read_carmen_log(sys.argv[1])
stream = log.front
truth = stream.laser_poses.astype(np.float64)
truth[:, 2] = wrap_logged_headings(truth[:, 2])
out["truth"] = digest(truth)
wheel = scan_odometry(log, "front")
out["odometry"] = digest(wheel)
laser, _ = laser_odometry(stream.ranges[:300], stream.beam_angles(), 50.0, wheel[:300])
out["laser_odometry"] = digest(laser)
ranges = clean_ranges(stream.ranges[:600], 50.0)
hits = np.where(ranges < 50.0, ranges, np.float32(np.nan))
grid = build_map_from_log(truth[:600], hits, stream.beam_angles(), 50.0, 0.05, 1.0)
out["map"] = digest(grid.cells)
print(json.dumps(out))
"""
)

SIM_CASE = (
    PROBE
    + """
import yaml
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.noise import noise_from_config
from scanloc.sensor.simulate import simulate_scans
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.odometry import OdometryNoise
from scanloc.world.build import build_map

with open("conf/map/sparse_obstacles.yaml") as f:
    grid = build_map(yaml.safe_load(f))
noise = OdometryNoise(alpha1=0.0025, alpha2=0.0004, alpha3=0.0025, alpha4=0.0001,
                      trans_scale=0.005, rot_scale=0.0025)
traj = drive_trajectory(grid, num_steps=400, rate_hz=10.0, seed=7, odometry_noise=noise,
                        kidnap_steps=(200,))
with open("conf/noise/ug01.yaml") as f:
    noise_cfg = yaml.safe_load(f)
scans = simulate_scans(grid, LaserSpec(), traj.truth, noise_from_config(noise_cfg), rng_seed=8)
out.update(cells=digest(grid.cells), truth=digest(traj.truth),
           odometry=digest(traj.odometry), scans=digest(scans))
print(json.dumps(out))
"""
)


def avx512_features() -> list[str]:
    """numpy's dispatch targets beyond AVX2 that this CPU has: what the second run disables."""
    from numpy._core import _multiarray_umath as umath

    return [
        name
        for name in umath.__cpu_dispatch__
        if (name.startswith("AVX512") or name == "X86_V4") and umath.__cpu_features__.get(name)
    ]


def run_case(code: str, *args: str, disable: list[str] | None = None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    if disable:
        env["NPY_DISABLE_CPU_FEATURES"] = " ".join(disable)
    done = subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=REPO_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def same_bytes_both_ways(code: str, *args: str) -> None:
    disable = avx512_features()
    if not disable:
        pytest.skip("this CPU has no AVX-512: numpy takes the same paths either way")
    native = run_case(code, *args)
    avx2 = run_case(code, *args, disable=disable)
    if native.pop("probe") == avx2.pop("probe"):
        pytest.skip("numpy's results do not change without AVX-512 here: nothing to compare")
    differ = sorted(k for k in native if native[k] != avx2[k])
    assert not differ, f"{differ} differ with NPY_DISABLE_CPU_FEATURES={' '.join(disable)}"


@pytest.mark.skipif(not INTEL_LOG.is_file(), reason=f"{INTEL_LOG} is absent (../shared)")
def test_real_log_outputs_do_not_depend_on_avx512() -> None:
    same_bytes_both_ways(REAL_CASE, str(INTEL_LOG))


def test_simulated_run_does_not_depend_on_avx512() -> None:
    same_bytes_both_ways(SIM_CASE)


def test_the_probe_sees_numpy_change_paths() -> None:
    """Guards the comparison above: on an AVX-512 CPU, disabling it must change numpy's arctan2
    (else NPY_DISABLE_CPU_FEATURES names nothing this numpy knows, and both runs are alike)."""
    disable = avx512_features()
    if not disable:
        pytest.skip("this CPU has no AVX-512")
    code = PROBE + "print(json.dumps(out))"
    assert run_case(code)["probe"] != run_case(code, disable=disable)["probe"]
