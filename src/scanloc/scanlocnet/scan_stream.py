"""Fresh training scans for every epoch, simulated in a background process.

The learned localizer trains on scans it never saw before: each epoch, `scans_per_epoch` poses
are drawn uniformly over the map's free space (with the robot's clearance) and scanned with the
same simulator and noise model as the `scans` stage, and, for a real laser, with its measured
corruptions (scanloc.sensor.corruptions: no returns, short and long readings, heavy-tailed
noise in place of the noise model's). Epoch e's scans depend only on (seed, e): poses from the
stream SeedSequence(seed, spawn_key=(e, 0)), the noise of each block of NOISE_BLOCK scans from
SeedSequence(seed, spawn_key=(e, 1, block)), its corruptions from (e, 2, block), so the same
params give the same bytes however the work is timed, and a training resumed at epoch e needs
no state of the stream but e.

A worker process (spawned; one numba thread, so that it leaves the cores to training)
simulates epoch e + 1 into shared memory while the trainer reads epoch e from the other buffer:
the training loop waits only if simulation is slower than an epoch of training. Stopping is
prompt: the worker dies on SIGINT and SIGTERM (the default action, whatever its parent
inherited), and on the trainer's end of its pipe closing; `close` terminates it without waiting
for an epoch in progress and unlinks the shared memory.
"""

from __future__ import annotations

import multiprocessing
import signal
import traceback
from collections.abc import Mapping
from dataclasses import dataclass, field
from multiprocessing import connection, shared_memory
from typing import Any, NoReturn

import numpy as np

NOISE_BLOCK = 1024
WORKER_EXIT_S = 5.0  # how long `close` lets a terminated worker take to exit before a SIGKILL


@dataclass(frozen=True)
class StreamSpec:
    """Everything the worker needs to simulate an epoch (picklable).

    map_yaml: the map (ROS map_server YAML); sensor / noise: conf/sensor and conf/noise
    mappings; clearance: robot footprint radius (m) kept free; scans_per_epoch; seed;
    corruptions: a sensor.corruptions mapping (empty: none).
    """

    map_yaml: str
    sensor: Mapping[str, Any]
    noise: Mapping[str, Any]
    clearance: float
    scans_per_epoch: int
    seed: int
    corruptions: Mapping[str, Any] = field(default_factory=dict)

    @property
    def num_beams(self) -> int:
        return int(self.sensor["num_beams"])


def _make_simulator(spec: StreamSpec) -> tuple[Any, Any, Any]:
    """The worker's map, scan simulator and corruptions, with numba on one thread."""
    import numba

    from scanloc.sensor.corruptions import corruptions_from_config
    from scanloc.sensor.noise import NoNoise, noise_from_config
    from scanloc.sensor.simulate import ScanSimulator, laser_spec_from_config
    from scanloc.world.map_server import load_map

    numba.set_num_threads(1)
    grid = load_map(spec.map_yaml)
    sensor = dict(spec.sensor)
    corruptions = corruptions_from_config(dict(spec.corruptions), "the stream's corruptions")
    noise = NoNoise() if corruptions.adds_noise else noise_from_config(dict(spec.noise))
    simulator = ScanSimulator(
        grid,
        laser_spec_from_config(sensor),
        noise,
        str(sensor.get("mode", "exact")),
        bool(sensor.get("unknown_blocks", False)),
    )
    return grid, simulator, corruptions


def simulate_epoch(
    spec: StreamSpec, epoch: int, grid, simulator, corruptions=None
) -> tuple[np.ndarray, np.ndarray]:
    """Epoch `epoch`'s (ranges float32 (N, B), poses float64 (N, 3)); see the module doc.
    `corruptions`: the spec's, built (default: built here)."""
    from scanloc.sensor.corruptions import corruptions_from_config
    from scanloc.world.free_space import sample_free_poses

    if corruptions is None:
        corruptions = corruptions_from_config(dict(spec.corruptions), "the stream's corruptions")
    pose_rng = np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(epoch, 0)))
    poses = sample_free_poses(grid, spec.scans_per_epoch, spec.clearance, pose_rng)
    ranges = np.empty((spec.scans_per_epoch, spec.num_beams), dtype=np.float32)
    cast = simulator.cast(poses)
    for block, start in enumerate(range(0, spec.scans_per_epoch, NOISE_BLOCK)):
        stop = min(start + NOISE_BLOCK, spec.scans_per_epoch)
        exact = cast[start:stop]
        if spec.corruptions:
            seed = np.random.SeedSequence(spec.seed, spawn_key=(epoch, 2, block))
            exact = corruptions.apply(exact, np.random.default_rng(seed))
        rng = np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(epoch, 1, block)))
        ranges[start:stop] = simulator.finish(exact, rng)
    return ranges, poses


def _serve(spec: StreamSpec, buffer_names: list[tuple[str, str]], conn: Any) -> None:
    """The worker: for each epoch number received, simulate it into buffer epoch % 2 and reply
    (epoch, None), or (epoch, traceback) when it fails, until terminated (ScanStream.close)
    or the trainer's end of the pipe closes (the trainer died)."""
    for stop in (signal.SIGINT, signal.SIGTERM):
        signal.signal(stop, signal.SIG_DFL)  # die at once, even inside numba code
    buffers = [tuple(shared_memory.SharedMemory(name=n) for n in pair) for pair in buffer_names]
    try:
        grid, simulator, corruptions = _make_simulator(spec)
    except Exception:
        conn.send((None, traceback.format_exc()))
        return
    try:
        while True:
            epoch = conn.recv()
            try:
                ranges, poses = simulate_epoch(spec, epoch, grid, simulator, corruptions)
                r_shm, p_shm = buffers[epoch % 2]
                np.ndarray(ranges.shape, np.float32, buffer=r_shm.buf)[:] = ranges
                np.ndarray(poses.shape, np.float64, buffer=p_shm.buf)[:] = poses
                reply = (epoch, None)
            except Exception:
                reply = (epoch, traceback.format_exc())
            conn.send(reply)
    except (EOFError, BrokenPipeError):
        return  # the trainer is gone


class ScanStream:
    """Double-buffered epochs of fresh scans from a worker process; use as a context manager.

    `epoch(e)` returns (ranges, poses) of epoch e (copied out of shared memory) and starts
    simulating epoch e + 1 into the other buffer. Epochs are best asked for in order: any other
    is simulated on demand. The worker handles one request at a time, in order.
    """

    def __init__(self, spec: StreamSpec) -> None:
        self.spec = spec
        n, b = spec.scans_per_epoch, spec.num_beams
        self._buffers: list[tuple[shared_memory.SharedMemory, ...]] = []
        self._pending: list[int] = []  # epochs requested from the worker, not yet answered
        try:
            for _ in range(2):
                self._buffers.append(
                    (
                        shared_memory.SharedMemory(create=True, size=n * b * 4),
                        shared_memory.SharedMemory(create=True, size=n * 3 * 8),
                    )
                )
            context = multiprocessing.get_context("spawn")
            self._conn, worker_end = context.Pipe()
            names = [(r.name, p.name) for r, p in self._buffers]
            self._worker = context.Process(
                target=_serve,
                args=(spec, names, worker_end),
                name="scanloc-scan-stream",
                daemon=True,
            )
            self._worker.start()
            worker_end.close()
        except BaseException:
            self._unlink()
            raise

    def _request(self, epoch: int) -> None:
        self._pending.append(epoch)
        try:
            self._conn.send(epoch)
        except (BrokenPipeError, ConnectionResetError):
            self._worker_stopped()

    def _worker_stopped(self) -> NoReturn:
        self._worker.join(WORKER_EXIT_S)  # its exit code
        raise RuntimeError(
            f"the scan simulation worker stopped (exit code {self._worker.exitcode}) "
            f"while simulating epoch {self._pending[0]} of {self.spec.map_yaml}"
        )

    def _receive(self) -> int:
        """Wait for the worker's next answer (or its death) and return the epoch it finished;
        an answer sent before it died is still read."""
        ready = connection.wait([self._conn, self._worker.sentinel])
        if self._conn not in ready:
            self._worker_stopped()
        try:
            epoch, error = self._conn.recv()
        except (EOFError, ConnectionResetError):
            self._worker_stopped()
        if error is not None:
            what = "starting" if epoch is None else f"simulating epoch {epoch}"
            raise RuntimeError(f"the scan simulation worker failed {what}:\n{error}")
        self._pending.remove(epoch)
        return epoch

    def epoch(self, epoch: int) -> tuple[np.ndarray, np.ndarray]:
        if epoch not in self._pending:
            self._request(epoch)
        while self._receive() != epoch:  # epochs asked for before, out of order: dropped
            pass
        self._request(epoch + 1)
        r, p = self._buffers[epoch % 2]
        n, b = self.spec.scans_per_epoch, self.spec.num_beams
        ranges = np.ndarray((n, b), np.float32, buffer=r.buf).copy()
        poses = np.ndarray((n, 3), np.float64, buffer=p.buf).copy()
        return ranges, poses

    def close(self) -> None:
        """Stop the worker without waiting for an epoch in progress; free the shared memory."""
        try:
            if self._worker.is_alive():
                self._worker.terminate()
                self._worker.join(WORKER_EXIT_S)
            if self._worker.is_alive():
                self._worker.kill()
                self._worker.join()
            self._conn.close()
        finally:
            self._unlink()

    def _unlink(self) -> None:
        for shm in (shm for pair in self._buffers for shm in pair):
            shm.close()
            shm.unlink()
        self._buffers = []

    def __enter__(self) -> ScanStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
