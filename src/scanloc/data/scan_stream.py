"""Fresh training scans for every epoch, simulated in a background process.

The learned localizer trains on scans it never saw before: each epoch, `scans_per_epoch` poses
are drawn uniformly over the map's free space (with the robot's clearance) and scanned with the
same simulator and noise model as the `scans` stage. Epoch e's scans depend only on (seed, e):
poses from the stream SeedSequence(seed, spawn_key=(e, 0)), the noise of each block of
NOISE_BLOCK scans from SeedSequence(seed, spawn_key=(e, 1, block)), so the same params give
the same bytes however the work is timed.

A worker process (one numba thread, so that it leaves the cores to training) simulates epoch
e + 1 into shared memory while the trainer reads epoch e from the other buffer: the training
loop waits only if simulation is slower than an epoch of training.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
from collections.abc import Mapping
from dataclasses import dataclass
from multiprocessing import shared_memory
from typing import Any

import numpy as np

NOISE_BLOCK = 1024
_worker: dict[str, Any] = {}


@dataclass(frozen=True)
class StreamSpec:
    """Everything the worker needs to simulate an epoch (picklable).

    map_yaml: the map (ROS map_server YAML); sensor / noise: conf/sensor and conf/noise
    mappings; clearance: robot footprint radius (m) kept free; scans_per_epoch; seed.
    """

    map_yaml: str
    sensor: Mapping[str, Any]
    noise: Mapping[str, Any]
    clearance: float
    scans_per_epoch: int
    seed: int

    @property
    def num_beams(self) -> int:
        return int(self.sensor["num_beams"])


def _init_worker(spec: StreamSpec) -> None:
    import numba

    from scanloc.sensor.noise import noise_from_config
    from scanloc.sensor.simulate import ScanSimulator, laser_spec_from_config
    from scanloc.world.map_server import load_map

    numba.set_num_threads(1)
    grid = load_map(spec.map_yaml)
    sensor = dict(spec.sensor)
    simulator = ScanSimulator(
        grid,
        laser_spec_from_config(sensor),
        noise_from_config(dict(spec.noise)),
        str(sensor.get("mode", "exact")),
        bool(sensor.get("unknown_blocks", False)),
    )
    _worker.update(spec=spec, grid=grid, simulator=simulator)


def simulate_epoch(spec: StreamSpec, epoch: int, grid, simulator) -> tuple[np.ndarray, np.ndarray]:
    """Epoch `epoch`'s (ranges float32 (N, B), poses float64 (N, 3)); see the module doc."""
    from scanloc.world.free_space import sample_free_poses

    pose_rng = np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(epoch, 0)))
    poses = sample_free_poses(grid, spec.scans_per_epoch, spec.clearance, pose_rng)
    ranges = np.empty((spec.scans_per_epoch, spec.num_beams), dtype=np.float32)
    cast = simulator.cast(poses)
    for block, start in enumerate(range(0, spec.scans_per_epoch, NOISE_BLOCK)):
        stop = min(start + NOISE_BLOCK, spec.scans_per_epoch)
        rng = np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(epoch, 1, block)))
        ranges[start:stop] = simulator.finish(cast[start:stop], rng)
    return ranges, poses


def _fill(epoch: int, ranges_name: str, poses_name: str) -> int:
    spec = _worker["spec"]
    ranges, poses = simulate_epoch(spec, epoch, _worker["grid"], _worker["simulator"])
    r_shm = shared_memory.SharedMemory(name=ranges_name)
    p_shm = shared_memory.SharedMemory(name=poses_name)
    try:
        np.ndarray(ranges.shape, np.float32, buffer=r_shm.buf)[:] = ranges
        np.ndarray(poses.shape, np.float64, buffer=p_shm.buf)[:] = poses
    finally:
        r_shm.close()
        p_shm.close()
    return epoch


class ScanStream:
    """Double-buffered epochs of fresh scans from a worker process; use as a context manager.

    `epoch(e)` returns (ranges, poses) of epoch e (copied out of shared memory) and starts
    simulating epoch e + 1 into the other buffer. Epochs are best asked for in order: any other
    is simulated on demand.
    """

    def __init__(self, spec: StreamSpec) -> None:
        self.spec = spec
        n, b = spec.scans_per_epoch, spec.num_beams
        self._buffers = [
            (
                shared_memory.SharedMemory(create=True, size=n * b * 4),
                shared_memory.SharedMemory(create=True, size=n * 3 * 8),
            )
            for _ in range(2)
        ]
        self._pool = concurrent.futures.ProcessPoolExecutor(
            max_workers=1,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker,
            initargs=(spec,),
        )
        self._pending: dict[int, concurrent.futures.Future] = {}

    def _submit(self, epoch: int) -> None:
        r, p = self._buffers[epoch % 2]
        self._pending[epoch] = self._pool.submit(_fill, epoch, r.name, p.name)

    def epoch(self, epoch: int) -> tuple[np.ndarray, np.ndarray]:
        for other in [e for e in self._pending if e != epoch]:  # asked out of order
            self._pending.pop(other).result()
        if epoch not in self._pending:
            self._submit(epoch)
        self._pending.pop(epoch).result()
        self._submit(epoch + 1)
        r, p = self._buffers[epoch % 2]
        n, b = self.spec.scans_per_epoch, self.spec.num_beams
        ranges = np.ndarray((n, b), np.float32, buffer=r.buf).copy()
        poses = np.ndarray((n, 3), np.float64, buffer=p.buf).copy()
        return ranges, poses

    def close(self) -> None:
        for future in self._pending.values():
            future.cancel()
        self._pool.shutdown(wait=True, cancel_futures=True)
        for r, p in self._buffers:
            for shm in (r, p):
                shm.close()
                shm.unlink()

    def __enter__(self) -> ScanStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
