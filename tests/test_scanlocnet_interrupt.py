"""Stopping ScanLocNet's training and resuming it: a stop signal ends the training at once with
nothing written, and the re-run resumes from the last finished epoch to the bytes of an
uninterrupted run (scanloc.scanlocnet.resume, the stage's exit status and message)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from scanloc.data.scan_dataset import generate_scan_dataset
from scanloc.scanlocnet.pose_grid import PoseGrid
from scanloc.scanlocnet.resume import TrainingStopped
from scanloc.scanlocnet.scan_stream import StreamSpec
from scanloc.scanlocnet.training import ScanLocModule, fit_scanlocnet
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import OccupancyGrid

REPO = Path(__file__).resolve().parents[1]
SENSOR = OmegaConf.to_container(OmegaConf.load(REPO / "conf/sensor/urg04lx.yaml"))
NOISE = OmegaConf.to_container(OmegaConf.load(REPO / "conf/noise/ug01.yaml"))
# A small network: the test is about stopping and resuming, not about learning.
TINY_NET = {
    "channels": [8, 16, 16],
    "kernels": [5, 3, 3],
    "features": 64,
    "cell_embedding": 8,
    "hidden": 32,
}
pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory, room: OccupancyGrid) -> dict[str, Path]:
    """The room's map and 64 validation scans with the pipeline's sensor and noise."""
    folder = tmp_path_factory.mktemp("inputs")
    save_map(room, folder / "map.yaml")
    spec = laser_spec_from_config(SENSOR)
    generate_scan_dataset(folder / "val", room, spec, NOISE, 64, 77, 0.15, 1.0, "room")
    return {"map": folder / "map.yaml", "val": folder / "val"}


def _fit(inputs: dict[str, Path], room: OccupancyGrid, out_dir: Path, checkpoints: Path) -> dict:
    return fit_scanlocnet(
        model_cfg={"_target_": "scanloc.scanlocnet.model.ScanLocNet"} | TINY_NET,
        grid=PoseGrid.from_map(room, 1.0, 12, 0.15),
        stream=StreamSpec(str(inputs["map"]), SENSOR, NOISE, 0.15, 256, 3),
        val_dataset=inputs["val"],
        out_dir=out_dir,
        epochs=3,
        batch_size=64,
        lr=3e-3,
        weight_decay=1e-4,
        pct_start=0.3,
        trainer_cfg={"precision": "32-true"},
        checkpoint_dir=checkpoints,
    )


def _folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_sigterm_ends_the_training_and_the_rerun_resumes_to_the_same_bytes(
    tmp_path: Path,
    inputs: dict[str, Path],
    room: OccupancyGrid,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
) -> None:
    """SIGTERM, which Lightning handles too (it would stop at the epoch's end); SIGINT: the
    slow test below, through the stage's process group."""
    stop = signal.SIGTERM
    _fit(inputs, room, tmp_path / "whole", tmp_path / "whole_checkpoints")
    print_epoch = ScanLocModule.print_epoch

    def stop_after_first_epoch(module: ScanLocModule) -> None:
        print_epoch(module)
        signal.raise_signal(stop)  # right after epoch 1's checkpoint

    monkeypatch.setattr(ScanLocModule, "print_epoch", stop_after_first_epoch)
    handlers = [signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)]
    out_dir = tmp_path / "resumed"
    with pytest.raises(TrainingStopped) as stopped:
        _fit(inputs, room, out_dir, tmp_path / "checkpoints")
    assert not out_dir.exists() and list(tmp_path.glob(".resumed*")) == []
    assert stopped.value.signum == stop and stopped.value.epochs_done == 1
    assert f"stopped by {stop.name}, nothing written" in str(stopped.value)
    assert "resumes after epoch 1 of 3" in str(stopped.value)
    assert [signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)] == handlers
    monkeypatch.undo()
    capfd.readouterr()
    _fit(inputs, room, out_dir, tmp_path / "checkpoints")
    printed = capfd.readouterr().err
    assert "scanlocnet epoch 1/3" not in printed and "scanlocnet epoch 3/3" in printed
    _assert_same_training(tmp_path / "whole", out_dir)
    assert _folder_bytes(out_dir) == _folder_bytes(tmp_path / "whole")


def _stage(inputs: dict[str, Path], folder: Path, out: str) -> list[str]:
    """The stage's command at the smoke profile with a tiny network and tiny epochs."""
    return [
        sys.executable,
        "-m",
        "scanloc.stages.train_scanlocnet",
        "map_name=room",
        "profile=smoke",
        "trainer.precision=32-true",
        "training.epochs=3",
        "training.scans_per_epoch=256",
        "training.batch_size=64",
        *(f"net.{key}={value}" for key, value in TINY_NET.items()),
        f"map_yaml={inputs['map']}",
        f"val_dataset={inputs['val']}",
        f"out_dir={folder / out}",
        f"metrics_path={folder / out}.json",
        f"timing_dir={folder / 'timing'}",
        f"checkpoint_dir={folder / 'checkpoints'}",
        f"hydra.run.dir={folder / 'hydra'}",
    ]


def _shared_memory_mapped_by(pid: int) -> set[str]:
    """The shared-memory segments (Python's psm_ names) process `pid` has mapped: the scan
    stream's buffers, and not those of the other tests running beside this one."""
    maps = Path(f"/proc/{pid}/maps").read_text()
    return {Path(line.split()[-1]).name for line in maps.splitlines() if "/dev/shm/psm_" in line}


def _shared_memory() -> set[str]:
    return {name for name in os.listdir("/dev/shm") if name.startswith("psm_")}


@pytest.mark.slow
def test_ctrl_c_to_the_stage_process_group_stops_it_and_it_resumes(
    tmp_path: Path, inputs: dict[str, Path]
) -> None:
    """What a terminal's Ctrl-C sends, to a stage that inherited SIGINT ignored (a background
    job of a script, where the training used to run on): it stops within seconds with exit
    status 130 and one line, leaves no output and no shared memory, and the same command
    resumes after epoch 1 to the model of an uninterrupted run."""
    whole = subprocess.run(
        _stage(inputs, tmp_path / "a", "model"), cwd=REPO, capture_output=True, text=True
    )
    assert whole.returncode == 0, whole.stderr
    command = _stage(inputs, tmp_path / "b", "model")
    process = subprocess.Popen(
        command,
        cwd=REPO,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    seen = []
    for line in process.stderr:
        seen.append(line)
        if "scanlocnet epoch 1/3" in line:
            break
    else:
        pytest.fail("no epoch line:\n" + "".join(seen))
    buffers = _shared_memory_mapped_by(process.pid)
    assert len(buffers) == 4  # two epochs' ranges and poses
    os.killpg(process.pid, signal.SIGINT)
    sent = time.perf_counter()
    rest = process.communicate(timeout=60)[1]
    assert time.perf_counter() - sent < 10.0
    assert process.returncode == 130, rest
    message = rest.strip().splitlines()[-1]
    assert "stopped by SIGINT, nothing written; the same command resumes after epoch 1" in message
    assert "scanlocnet epoch 2/3" not in rest and "Traceback" not in rest
    assert not (tmp_path / "b" / "model").exists() and not (tmp_path / "b" / "model.json").exists()
    time.sleep(0.5)
    assert buffers & _shared_memory() == set()
    resumed = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert "scanlocnet epoch 1/3" not in resumed.stderr
    _assert_same_training(tmp_path / "a" / "model", tmp_path / "b" / "model")


def _assert_same_training(whole: Path, resumed: Path) -> None:
    """The same model bytes; where they differ, the first epoch whose history row differs says
    whether the resume (epoch 2 on) or the run itself (epoch 1, from the stopped run's
    checkpoint) went another way."""
    rows = [(folder / "history.csv").read_text().splitlines() for folder in (whole, resumed)]
    differ = [epoch for epoch, (a, b) in enumerate(zip(*rows, strict=True)) if a != b]
    assert differ == [], f"history rows {differ} differ (0: the header):\n" + "\n".join(
        f"{a}\n{b}" for a, b in zip(*rows, strict=True)
    )
    assert (resumed / "model.pt").read_bytes() == (whole / "model.pt").read_bytes()
