"""`localize` stage (paper §4.4): one localizer along the driven trajectory, one row per step."""

from __future__ import annotations

import time
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from scanloc.io import atomic_path, write_json
from scanloc.localize.amcl import AmclParams, run_amcl
from scanloc.localize.cnn_localizer import localize_cnn
from scanloc.localize.estimates import table_covariances, table_poses
from scanloc.localize.fusion import FusionParams, fuse_odometry
from scanloc.localize.trajectory import load_trajectory
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.world.map_server import load_map


def ensemble_model_paths(cfg: DictConfig) -> list[Path]:
    """The listed models, then member_<k>/model.pt of `member_dir` in member order."""
    paths = [Path(p) for p in cfg.models]
    if cfg.get("member_dir"):
        member_dir = Path(cfg.member_dir)
        members = sorted(member_dir.glob("member_*/model.pt"), key=lambda p: int(p.parent.name[7:]))
        if not members:
            raise FileNotFoundError(f"{member_dir}: no member_<k>/model.pt (localizer {cfg.name})")
        paths += members
    return paths


def localize(cfg: DictConfig) -> tuple[pd.DataFrame, dict[str, float]]:
    """The per-step table and what goes into the timing JSON: `time_per_scan_s` (mean wall
    time per scan) and, for a fusion localizer, the gate's counts."""
    traj, ranges = load_trajectory(cfg.trajectory_dir)
    loc = cfg.localizer
    if loc.kind == "amcl":
        params = AmclParams.from_config(
            {k: v for k, v in to_dict(loc).items() if k not in ("name", "kind", "mode", "seed")}
        )
        start = time.perf_counter()
        table = run_amcl(
            load_map(cfg.map_yaml),
            laser_spec_from_config(to_dict(cfg.sensor)),
            traj,
            ranges,
            params,
            mode=loc.mode,
            seed=int(loc.get("seed", 0)),
        )
        return table, {"time_per_scan_s": (time.perf_counter() - start) / len(table)}
    if loc.kind in ("cnn", "fusion"):
        fusion = FusionParams.from_config(to_dict(loc.fusion)) if loc.kind == "fusion" else None
        cnn = localize_cnn(
            ensemble_model_paths(loc), ranges, traj.times, batch_size=int(loc.batch_size)
        )
        if fusion is None:
            return cnn.table, {"time_per_scan_s": cnn.time_per_scan_s}
        start = time.perf_counter()
        fused = fuse_odometry(
            traj.odometry,
            traj.times,
            table_poses(cnn.table),
            table_covariances(cnn.table),
            fusion,
        )
        per_step = (time.perf_counter() - start) / len(fused.table)
        return fused.table, {
            "time_per_scan_s": cnn.time_per_scan_s + per_step,
            "n_rejected": int(fused.rejected.sum()),
            "n_reinitialised": int(fused.reinitialised.sum()),
        }
    raise ValueError(
        f"conf/localizer/{loc.name}.yaml: kind must be 'amcl', 'cnn' or 'fusion', got {loc.kind!r}"
    )


@stage_main("localize")
def main(cfg: DictConfig) -> None:
    with timed_stage(f"localize_{cfg.localizer.name}"):
        table, timing = localize(cfg)
        with atomic_path(cfg.out_path) as tmp:
            table.to_csv(tmp, index=False, float_format="%.9g")
        write_json(Path(cfg.timing_path), timing)


if __name__ == "__main__":
    main()
