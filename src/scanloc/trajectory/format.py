"""The on-disk format of a driven run (data/trajectories/<name>/): truth, odometry, times and
ranges as .npy, meta.json and a drawing of the route. Every producer of runs (the simulator,
the real-log reader) writes it and every consumer reads it through here."""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scanloc.io import atomic_path
from scanloc.world.occupancy_grid import OccupancyGrid

FILES = ("truth.npy", "odometry.npy", "times.npy", "ranges.npy", "meta.json", "route.png")
# Optional: laser odometry (T, 3) float64, the robot base's pose by scan-to-scan registration
# (scanloc.trajectory.laser_odometry) in the same frame as odometry.npy (it starts at the true
# start pose and integrates no motion across a kidnap). Written only when the run has it.
OPTIONAL_FILES = ("laser_odometry.npy",)


@dataclass(frozen=True)
class Trajectory:
    """A driven run: times (T,), truth (T, 3) and odometry (T, 3) poses (x, y, θ ∈ (-π, π]).

    `odometry` is the wheel-odometry pose in the odometry frame, which starts at the true start
    pose. `waypoints` (K, 2) are the route's waypoints in visiting order. `kidnap_steps` are the
    steps at which the robot was carried elsewhere (truth[k] is the first pose after it).
    `laser_odometry` (T, 3), when present, is the laser (scan-matched) odometry of the same
    base, in the same frame as `odometry` (OPTIONAL_FILES).
    """

    times: np.ndarray
    truth: np.ndarray
    odometry: np.ndarray
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    kidnap_steps: tuple[int, ...] = ()
    laser_odometry: np.ndarray | None = None


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _route_png(traj: Trajectory, grid: OccupancyGrid | None) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6), dpi=100)
    if grid is not None:
        shade = np.full(grid.cells.shape, 0.7)
        shade[grid.free] = 1.0
        shade[grid.occupied] = 0.0
        w, h = grid.size_m
        extent = (grid.origin[0], grid.origin[0] + w, grid.origin[1], grid.origin[1] + h)
        ax.imshow(shade, cmap="gray", vmin=0, vmax=1, origin="lower", extent=extent)
    truth = np.insert(traj.truth[:, :2], list(traj.kidnap_steps), np.nan, axis=0)  # no jumps
    ax.plot(truth[:, 0], truth[:, 1], color="tab:blue", lw=1.2, label="truth")
    for k in traj.kidnap_steps:
        ax.plot(*traj.truth[k, :2], "*", color="tab:purple", ms=10)
    ax.plot(
        traj.odometry[:, 0],
        traj.odometry[:, 1],
        color="tab:orange",
        lw=1.0,
        ls="--",
        label="odometry",
    )
    ax.plot(*traj.truth[0, :2], "o", color="tab:green", label="start")
    if len(traj.waypoints):
        ax.plot(traj.waypoints[:, 0], traj.waypoints[:, 1], "x", color="tab:red", label="waypoints")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    kidnaps = f", kidnapped at steps {list(traj.kidnap_steps)} (stars)" if traj.kidnap_steps else ""
    ax.set_title(f"driven route: {len(traj.times)} steps{kidnaps}", fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def save_trajectory(
    traj: Trajectory,
    out_dir: str | Path,
    ranges: np.ndarray,
    meta: Mapping[str, Any],
    grid: OccupancyGrid | None = None,
) -> None:
    """Write data/trajectories/<name>/: truth, odometry, times, ranges (.npy), meta.json, route.png.

    `meta` is stored with the run's shape added (num_steps, num_beams, rate_hz, waypoints,
    odometry_frame). `grid`, when given, is drawn under the route in route.png.
    """
    out = Path(out_dir)
    ranges = np.asarray(ranges)
    steps = len(traj.times)
    if ranges.ndim != 2 or ranges.shape[0] != steps:
        raise ValueError(f"ranges must have shape (T={steps}, B), got {ranges.shape}")
    if ranges.dtype != np.float32 or np.isnan(ranges).any():
        raise ValueError(f"ranges must be float32 without NaN, got {ranges.dtype}")
    full_meta = dict(meta)
    full_meta.update(
        num_steps=steps,
        num_beams=int(ranges.shape[1]),
        rate_hz=round(float(1.0 / (traj.times[1] - traj.times[0])), 9) if steps > 1 else None,
        odometry_frame="starts at the true start pose",
        waypoints=[[round(float(a), 6) for a in w] for w in traj.waypoints],
    )
    if traj.kidnap_steps:
        full_meta["kidnap_steps"] = list(traj.kidnap_steps)
    payload = {
        "truth.npy": _npy_bytes(np.asarray(traj.truth, dtype=np.float64)),
        "odometry.npy": _npy_bytes(np.asarray(traj.odometry, dtype=np.float64)),
        "times.npy": _npy_bytes(np.asarray(traj.times, dtype=np.float64)),
        "ranges.npy": _npy_bytes(ranges),
        "meta.json": (json.dumps(full_meta, indent=2, sort_keys=True) + "\n").encode(),
        "route.png": _route_png(traj, grid),
    }
    if traj.laser_odometry is not None:
        laser = np.asarray(traj.laser_odometry, dtype=np.float64)
        if laser.shape != (steps, 3):
            raise ValueError(f"laser_odometry must have shape ({steps}, 3), got {laser.shape}")
        payload["laser_odometry.npy"] = _npy_bytes(laser)
    out.mkdir(parents=True, exist_ok=True)
    for name, data in payload.items():
        with atomic_path(out / name) as tmp:
            tmp.write_bytes(data)


def load_trajectory(directory: str | Path) -> tuple[Trajectory, np.ndarray]:
    """Read what `save_trajectory` wrote: (Trajectory, ranges float32 (T, B)); the laser
    odometry too where the run has it."""
    d = Path(directory)
    arrays = {}
    for name in ("truth", "odometry", "times", "ranges"):
        path = d / f"{name}.npy"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: file not found (expected a saved trajectory)")
        arrays[name] = np.load(path, allow_pickle=False)
    steps = arrays["times"].shape
    if len(steps) != 1:
        raise ValueError(f"{d / 'times.npy'}: expected shape (T,), got {steps}")
    for name in ("truth", "odometry"):
        if arrays[name].shape != (steps[0], 3):
            raise ValueError(
                f"{d / name}.npy: expected shape ({steps[0]}, 3), got {arrays[name].shape}"
            )
    if arrays["ranges"].ndim != 2 or arrays["ranges"].shape[0] != steps[0]:
        raise ValueError(
            f"{d / 'ranges.npy'}: expected shape ({steps[0]}, B), got {arrays['ranges'].shape}"
        )
    laser_odometry = None
    if (d / "laser_odometry.npy").is_file():
        laser_odometry = np.load(d / "laser_odometry.npy", allow_pickle=False)
        if laser_odometry.shape != (steps[0], 3):
            raise ValueError(
                f"{d / 'laser_odometry.npy'}: expected shape ({steps[0]}, 3), "
                f"got {laser_odometry.shape}"
            )
    waypoints = np.zeros((0, 2))
    kidnaps: tuple[int, ...] = ()
    meta_path = d / "meta.json"
    if meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        if meta.get("waypoints"):
            waypoints = np.asarray(meta["waypoints"], dtype=np.float64).reshape(-1, 2)
        kidnaps = tuple(int(k) for k in meta.get("kidnap_steps", ()))
    traj = Trajectory(
        times=arrays["times"],
        truth=arrays["truth"],
        odometry=arrays["odometry"],
        waypoints=waypoints,
        kidnap_steps=kidnaps,
        laser_odometry=laser_odometry,
    )
    return traj, arrays["ranges"]
