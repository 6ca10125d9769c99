"""The kinds of localizer the localize stage can run, chosen by the `kind` of a localizer config
(conf/localizer/<name>.yaml): each a function (config, inputs) -> Localization, registered
under its kind by `@register_kind("<kind>")`. A new kind is one registered function; a new
localizer of an existing kind is one yaml file.

The amcl variants and the hybrid are configurations of one particle filter (localize/mcl/):
the hybrid plugs its learned proposal and importance weights into it."""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from scanloc.data.scan_dataset import load_scan_dataset
from scanloc.estimates import Localization, table_covariances, table_poses
from scanloc.localize.cnn_localizer import localize_cnn
from scanloc.localize.fusion import FusionParams, fuse_odometry
from scanloc.localize.hybrid import (
    HybridParams,
    ImportanceWeights,
    LearnedProposal,
    VerifiedGate,
)
from scanloc.localize.hypothesis_tracker import TrackerParams, track_hypotheses
from scanloc.localize.hypothesis_verification import HypothesisVerifier, VerifierParams
from scanloc.localize.learned_localizer import (
    fit_calibration,
    in_base_frame,
    localize_learned,
    scan_hypotheses,
    verified,
)
from scanloc.localize.mcl.config import MclConfig, build_filter, run_mcl
from scanloc.localize.mcl.filter import run_filter
from scanloc.localize.mcl.proposals import UniformProposal
from scanloc.sensor.laser import LaserSpec
from scanloc.trajectory.format import Trajectory
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import OccupancyGrid

# Keys of a hybrid config beside amcl's parameters: the learned model and its proposal.
HYBRID_KEYS = (
    "model",
    "k",
    "k_raw",
    "nms_distance",
    "nms_angle_deg",
    "verify",
    "calibration_scans",
    "calibration_count",
    "proposal",
)

Kind = Callable[[Mapping[str, Any], "LocalizeInputs"], Localization]
LOCALIZER_KINDS: dict[str, Kind] = {}
SEEDED_KINDS: set[str] = set()  # kinds whose result depends on the config's `seed`


def register_kind(kind: str, *, seeded: bool = False) -> Callable[[Kind], Kind]:
    """Register the decorated function as the runner of localizer configs of `kind`;
    `seeded`: its result depends on the config's `seed` (a particle filter), so that runs over
    several seeds mean something (the other kinds are deterministic)."""

    def register(run: Kind) -> Kind:
        if kind in LOCALIZER_KINDS and LOCALIZER_KINDS[kind] is not run:
            raise ValueError(f"localizer kind {kind!r} is registered twice")
        LOCALIZER_KINDS[kind] = run
        if seeded:
            SEEDED_KINDS.add(kind)
        return run

    return register


def is_seeded(cfg: Mapping[str, Any]) -> bool:
    """Whether the localizer a config describes gives other results for other seeds."""
    return cfg.get("kind") in SEEDED_KINDS


@dataclass(frozen=True)
class LocalizeInputs:
    """What a localizer sees: the run (times, odometry; truth only to start tracking), its
    scans, the map, the laser and where the laser sits on the robot (x, y, θ in the base
    frame; the particle filters cast beams from base ⊕ mount, the learned localizers turn
    the laser poses they find into base poses: learned_localizer.in_base_frame)."""

    trajectory: Trajectory
    ranges: np.ndarray
    map_yaml: Path
    laser: LaserSpec
    laser_mount: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # What localizers of one stage share instead of recomputing: the verifier's calibration
    # per (model, calibration scans, verifier and decoding settings).
    shared: dict[str, Any] = dataclasses.field(default_factory=dict, compare=False, repr=False)

    @cached_property
    def grid(self) -> OccupancyGrid:
        return load_map(self.map_yaml)


def ensemble_model_paths(cfg: Mapping[str, Any]) -> list[Path]:
    """The listed models, then member_<k>/model.pt of `member_dir` in member order."""
    paths = [Path(p) for p in cfg["models"]]
    if cfg.get("member_dir"):
        member_dir = Path(cfg["member_dir"])
        members = sorted(member_dir.glob("member_*/model.pt"), key=lambda p: int(p.parent.name[7:]))
        if not members:
            raise FileNotFoundError(
                f"{member_dir}: no member_<k>/model.pt (localizer {cfg['name']})"
            )
        paths += members
    return paths


@register_kind("amcl", seeded=True)
def run_amcl_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """ROS amcl (the particle filter with amcl's parts), tracking from the true first pose or
    global (`mode`)."""
    start = time.perf_counter()
    grid = inputs.grid
    loaded = time.perf_counter() - start
    run = run_mcl(
        grid,
        inputs.laser,
        inputs.trajectory,
        inputs.ranges,
        MclConfig.from_ros(cfg),
        mode=str(cfg.get("mode", "tracking")),
        seed=int(cfg.get("seed", 0)),
        laser_mount=inputs.laser_mount,
    )
    return run._replace(setup_s=run.setup_s + loaded)


@register_kind("hybrid", seeded=True)
def run_hybrid_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """The particle filter with the learned localizer's hypotheses as its proposal and their
    importance weights (hybrid.py)."""
    start = time.perf_counter()
    hybrid = HybridParams.from_config(dict(cfg["proposal"]))
    grid = inputs.grid
    config = MclConfig.from_ros({k: v for k, v in cfg.items() if k not in HYBRID_KEYS})
    hypotheses_of, _ = learned_hypotheses(cfg, inputs)
    uniform = UniformProposal(grid, config.map_half_cell_offset)
    proposal = LearnedProposal(hypotheses_of, uniform, hybrid)
    gate = None
    if hybrid.verified_gate:
        verifier = HypothesisVerifier(
            grid, inputs.laser, VerifierParams.from_config(dict(cfg.get("verify") or {}))
        )
        gate = VerifiedGate(
            verifier, hybrid.gate_margin, inputs.laser_mount, hybrid.gate_persistence
        )
    weighting = ImportanceWeights(proposal, hybrid, gate)
    pf = build_filter(
        grid,
        inputs.laser,
        config,
        int(cfg.get("seed", 0)),
        proposal=proposal,
        weighting=weighting,
        laser_mount=inputs.laser_mount,
    )
    return run_filter(
        pf,
        inputs.trajectory,
        inputs.ranges,
        str(cfg.get("mode", "global")),
        time.perf_counter() - start,
    )


@register_kind("cnn")
def run_cnn_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """The paper's CNN localizers: one network, or the mean of an ensemble, per scan."""
    traj = inputs.trajectory
    return localize_cnn(ensemble_model_paths(cfg), inputs.ranges, traj.times)


@register_kind("fusion")
def run_fusion_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """The CNN ensemble's poses fused with odometry by an EKF (fusion.py)."""
    params = FusionParams.from_config(dict(cfg["fusion"]))
    cnn = run_cnn_kind(cfg, inputs)
    traj = inputs.trajectory
    start = time.perf_counter()
    fused = fuse_odometry(
        traj.odometry, traj.times, table_poses(cnn.table), table_covariances(cnn.table), params
    )
    per_step = (time.perf_counter() - start) / len(fused.table)
    counts = {
        "n_rejected": int(fused.rejected.sum()),
        "n_reinitialised": int(fused.reinitialised.sum()),
    }
    return Localization(fused.table, cnn.setup_s, cnn.scan_seconds + per_step, counts)


def learned_options(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """The learned localizer's decoding options of a localizer config."""
    keys = ("k", "k_raw", "nms_distance", "nms_angle_deg")
    return {key: cfg[key] for key in keys if key in cfg}


def learned_hypotheses(
    cfg: Mapping[str, Any], inputs: LocalizeInputs
) -> tuple[Callable[[np.ndarray], Any], float]:
    """(per-scan hypotheses function, setup seconds) of a config with a learned model: its
    ranked hypotheses, verified against the map when the config has a `verify` section (the
    calibration fitted on `calibration_count` of the `calibration_scans` dataset's validation
    scans, evenly spaced: scans no evaluation scores). The network and the verifier work in
    the laser's frame; what the function returns are poses of the robot's base."""
    start = time.perf_counter()
    for field in ("calibration_scans", "calibration_count") if cfg.get("verify") else ():
        if cfg.get(field) is None:
            raise ValueError(
                f"conf/localizer/{cfg.get('name')}.yaml: field '{field}': expected a value "
                "(verified hypotheses need the scans their score is calibrated on)"
            )
    _, hypotheses_of, _ = scan_hypotheses(Path(cfg["model"]), inputs.ranges, **learned_options(cfg))
    if not cfg.get("verify"):
        return in_base_frame(hypotheses_of, inputs.laser_mount), time.perf_counter() - start
    verifier = HypothesisVerifier(
        inputs.grid, inputs.laser, VerifierParams.from_config(dict(cfg["verify"]))
    )
    verifier.calibration = _calibration(cfg, inputs, hypotheses_of, verifier)
    checked = verified(hypotheses_of, verifier)
    return in_base_frame(checked, inputs.laser_mount), time.perf_counter() - start


def _calibration(
    cfg: Mapping[str, Any], inputs: LocalizeInputs, hypotheses_of, verifier: HypothesisVerifier
):
    """The verifier's calibration for `cfg`, fitted once per stage: localizers with the same
    model, calibration scans and settings (scanlocnet_verified, hybrid_verified) share it."""
    settings = [cfg["model"], cfg["calibration_scans"], cfg["calibration_count"], cfg["verify"]]
    settings.append(learned_options(cfg))
    key = "calibration:" + json.dumps(settings, sort_keys=True, default=str)
    if key not in inputs.shared:
        data = load_scan_dataset(cfg["calibration_scans"])
        val = data.val_idx
        count = int(cfg["calibration_count"])
        pick = val[np.unique(np.linspace(0, len(val) - 1, count).astype(int))]
        inputs.shared[key], _ = fit_calibration(
            hypotheses_of, verifier, np.asarray(data.ranges[pick]), data.poses[pick]
        )
    return inputs.shared[key]


@register_kind("learned")
def run_learned_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """scanloc's learned localizer: ranked hypotheses from each scan alone (verified against
    the map when the config has `verify`)."""
    hypotheses_of, setup_s = learned_hypotheses(cfg, inputs)
    return localize_learned(hypotheses_of, setup_s, inputs.ranges, inputs.trajectory.times)


@register_kind("learned_tracking")
def run_learned_tracking_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """The learned localizer's hypotheses tracked over time with odometry (a Gaussian sum)."""
    params = TrackerParams.from_config(dict(cfg["tracker"]))
    learned = run_learned_kind(cfg, inputs)
    start = time.perf_counter()
    u = UniformProposal(inputs.grid).uniform_density
    traj = inputs.trajectory
    table = track_hypotheses(traj.odometry, traj.times, learned.hypotheses, u, params)
    per_step = (time.perf_counter() - start) / len(table)
    return Localization(
        table, learned.setup_s, learned.scan_seconds + per_step, hypotheses=learned.hypotheses
    )


def run_localizer(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """Run the localizer a config describes (its `kind` picks the function)."""
    kind = cfg.get("kind")
    if kind not in LOCALIZER_KINDS:
        raise ValueError(
            f"conf/localizer/{cfg.get('name')}.yaml: field 'kind': expected one of "
            f"{sorted(LOCALIZER_KINDS)}, got {kind!r}"
        )
    return LOCALIZER_KINDS[kind](cfg, inputs)
