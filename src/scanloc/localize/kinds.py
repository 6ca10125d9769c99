"""The kinds of localizer the localize stage can run, chosen by the `kind` of a localizer config
(conf/localizer/<name>.yaml): each a function (config, inputs) -> Localization, registered
under its kind by `@register_kind("<kind>")`. A new kind is one registered function; a new
localizer of an existing kind is one yaml file.

A config is written in sections (localize/config_params.py): `meta` for the catalog, and the
sections its kind registered; the amcl variants and the hybrid are configurations of one kind,
`particle_filter` (localize/mcl/), the hybrid's `proposal`, `mixing` and `weighting` naming
the learned parts it plugs in (hybrid.py)."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from scanloc.data.scan_dataset import load_scan_dataset
from scanloc.estimates import Localization, table_covariances, table_poses
from scanloc.localize import hybrid  # noqa: F401  (registers the hybrid's parts)
from scanloc.localize.branch_and_bound import (
    GlobalSearch,
    SearchParams,
    TopKParams,
    end_points,
    heading_step,
)
from scanloc.localize.cnn_localizer import localize_cnn
from scanloc.localize.config_params import check_sections, parse_section, section_values
from scanloc.localize.fusion import FusionParams, fuse_odometry
from scanloc.localize.hypothesis_tracker import TrackerParams, track_hypotheses
from scanloc.localize.hypothesis_verification import HypothesisVerifier, VerifierParams
from scanloc.localize.learned_localizer import (
    LearnedParams,
    fit_calibration,
    in_base_frame,
    localize_learned,
    scan_hypotheses,
    verified,
)
from scanloc.localize.mcl.config import FILTER_SECTIONS, filter_from_sections
from scanloc.localize.mcl.filter import run_filter
from scanloc.localize.mcl.parts import PartsContext
from scanloc.localize.mcl.proposals import UniformProposal
from scanloc.scanlocnet.model import Hypotheses
from scanloc.sensor.laser import LaserSpec
from scanloc.trajectory.format import Trajectory
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import OccupancyGrid

Kind = Callable[[Mapping[str, Any], "LocalizeInputs"], Localization]
LOCALIZER_KINDS: dict[str, Kind] = {}
KIND_SECTIONS: dict[str, tuple[str, ...]] = {}  # the config sections each kind reads
SEEDED_KINDS: set[str] = set()  # kinds whose result depends on the `filter` section's `seed`


def register_kind(
    kind: str, sections: tuple[str, ...] = (), *, seeded: bool = False
) -> Callable[[Kind], Kind]:
    """Register the decorated function as the runner of localizer configs of `kind`, which
    read `sections` (beside `meta`); `seeded`: its result depends on the seed (a particle
    filter), so that runs over several seeds mean something (the other kinds are
    deterministic)."""

    def register(run: Kind) -> Kind:
        if kind in LOCALIZER_KINDS and LOCALIZER_KINDS[kind] is not run:
            raise ValueError(f"localizer kind {kind!r} is registered twice")
        LOCALIZER_KINDS[kind] = run
        KIND_SECTIONS[kind] = ("meta", *sections)
        if seeded:
            SEEDED_KINDS.add(kind)
        return run

    return register


def config_file(cfg: Mapping[str, Any]) -> str:
    """The file a localizer config came from, for errors."""
    return f"conf/localizer/{(cfg.get('meta') or {}).get('name', '<unnamed>')}.yaml"


def kind_of(cfg: Mapping[str, Any]) -> str:
    """The `meta` section's `kind`, checked against the registered kinds."""
    kind = (cfg.get("meta") or {}).get("kind")
    if kind not in LOCALIZER_KINDS:
        raise ValueError(
            f"{config_file(cfg)}: section 'meta': key 'kind': expected one of "
            f"{sorted(LOCALIZER_KINDS)}, got {kind!r}"
        )
    return str(kind)


def is_seeded(cfg: Mapping[str, Any]) -> bool:
    """Whether the localizer a config describes gives other results for other seeds."""
    return kind_of(cfg) in SEEDED_KINDS


def with_seed(cfg: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """A copy of a seeded localizer's config with the `filter` section's `seed` set; a
    deterministic one's as it is (it has no seed to set)."""
    if not is_seeded(cfg):
        return dict(cfg)
    return {**cfg, "filter": {**(cfg.get("filter") or {}), "seed": int(seed)}}


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
    """The `ensemble` section's models, then member_<k>/model.pt of its `member_dir` in member
    order."""
    where = config_file(cfg)
    ensemble = section_values(cfg, "ensemble", where)
    unknown = sorted(set(ensemble) - {"models", "member_dir"})
    if unknown:
        raise ValueError(
            f"{where}: section 'ensemble': unknown key {unknown[0]!r}; known: member_dir, models"
        )
    paths = [Path(p) for p in ensemble.get("models") or []]
    if ensemble.get("member_dir"):
        member_dir = Path(ensemble["member_dir"])
        members = sorted(member_dir.glob("member_*/model.pt"), key=lambda p: int(p.parent.name[7:]))
        if not members:
            raise FileNotFoundError(f"{member_dir}: no member_<k>/model.pt ({where})")
        paths += members
    if not paths:
        raise ValueError(f"{where}: section 'ensemble': expected `models` or `member_dir`")
    return paths


@register_kind("particle_filter", (*FILTER_SECTIONS, "learned", "verifier"), seeded=True)
def run_particle_filter_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """The particle filter from its config's sections: amcl with its own parts, or with the
    learned localizer's proposal, mixing and importance weights (the hybrid, hybrid.py)."""
    start = time.perf_counter()
    context = PartsContext(
        inputs.grid,
        inputs.laser,
        inputs.laser_mount,
        hypotheses=lambda: learned_hypotheses(cfg, inputs)[0],
    )
    pf = filter_from_sections(cfg, config_file(cfg), context)
    return run_filter(pf, inputs.trajectory, inputs.ranges, setup_s=time.perf_counter() - start)


@register_kind("cnn", ("ensemble",))
def run_cnn_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """The paper's CNN localizers: one network, or the mean of an ensemble, per scan."""
    traj = inputs.trajectory
    return localize_cnn(ensemble_model_paths(cfg), inputs.ranges, traj.times)


@register_kind("fusion", ("ensemble", "fusion"))
def run_fusion_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """The CNN ensemble's poses fused with odometry by an EKF (fusion.py)."""
    params = parse_section(FusionParams, cfg, "fusion", config_file(cfg))
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


def learned_hypotheses(
    cfg: Mapping[str, Any], inputs: LocalizeInputs
) -> tuple[Callable[[np.ndarray], Any], float]:
    """(per-scan hypotheses function, setup seconds) of the `learned` section's model: its
    ranked hypotheses, verified against the map (the `verifier` section) when `verified` (the
    calibration fitted on `calibration_count` of the `calibration_scans` dataset's validation
    scans, evenly spaced: scans no evaluation scores). The network and the verifier work in
    the laser's frame; what the function returns are poses of the robot's base."""
    start = time.perf_counter()
    where = config_file(cfg)
    learned = parse_section(LearnedParams, cfg, "learned", where)
    for key in ("model", "calibration_scans") if learned.verified else ("model",):
        if not getattr(learned, key):
            raise ValueError(
                f"{where}: section 'learned': key '{key}': expected a value"
                + (
                    " (verified hypotheses need the scans their score is calibrated on)"
                    if key == "calibration_scans"
                    else ""
                )
            )
    _, hypotheses_of, _ = scan_hypotheses(Path(learned.model), inputs.ranges, learned)
    if not learned.verified:
        return in_base_frame(hypotheses_of, inputs.laser_mount), time.perf_counter() - start
    params = parse_section(VerifierParams, cfg, "verifier", where)
    verifier = HypothesisVerifier(inputs.grid, inputs.laser, params)
    verifier.calibration = _calibration(learned, params, inputs, hypotheses_of, verifier)
    checked = verified(hypotheses_of, verifier)
    return in_base_frame(checked, inputs.laser_mount), time.perf_counter() - start


def _calibration(
    learned: LearnedParams,
    params: VerifierParams,
    inputs: LocalizeInputs,
    hypotheses_of,
    verifier: HypothesisVerifier,
):
    """The verifier's calibration, fitted once per stage: localizers with the same model,
    calibration scans and settings (scanlocnet_verified, hybrid_verified) share it."""
    settings = [dataclasses.asdict(learned), dataclasses.asdict(params)]
    key = "calibration:" + json.dumps(settings, sort_keys=True, default=str)
    if key not in inputs.shared:
        data = load_scan_dataset(learned.calibration_scans)
        val = data.val_idx
        pick = val[np.unique(np.linspace(0, len(val) - 1, learned.calibration_count).astype(int))]
        inputs.shared[key], _ = fit_calibration(
            hypotheses_of, verifier, np.asarray(data.ranges[pick]), data.poses[pick]
        )
    return inputs.shared[key]


@register_kind("learned", ("learned", "verifier"))
def run_learned_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """scanloc's learned localizer: ranked hypotheses from each scan alone (verified against
    the map when its `learned` section says `verified`)."""
    hypotheses_of, setup_s = learned_hypotheses(cfg, inputs)
    return localize_learned(hypotheses_of, setup_s, inputs.ranges, inputs.trajectory.times)


@register_kind("learned_tracking", ("learned", "verifier", "tracker"))
def run_learned_tracking_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """The learned localizer's hypotheses tracked over time with odometry (a Gaussian sum)."""
    params = parse_section(TrackerParams, cfg, "tracker", config_file(cfg))
    learned = run_learned_kind(cfg, inputs)
    start = time.perf_counter()
    u = UniformProposal(inputs.grid).uniform_density
    traj = inputs.trajectory
    table = track_hypotheses(traj.odometry, traj.times, learned.hypotheses, u, params)
    per_step = (time.perf_counter() - start) / len(table)
    return Localization(
        table, learned.setup_s, learned.scan_seconds + per_step, hypotheses=learned.hypotheses
    )


@register_kind("bnb", ("search", "top_k", "learned"))
def run_bnb_kind(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """Branch and bound over the whole map (branch_and_bound.py), each scan alone: its `top_k`
    best poses more than `separation_m` or `separation_deg` apart, weighted by their match
    score. With a `learned` section (a model and its decoding), the learned localizer's
    hypotheses guide the search (scanlocnet_bnb): the same poses, fewer blocks scored. Each
    pose's standard deviations are those of a uniform error over its cell and heading step."""
    start = time.perf_counter()
    where = config_file(cfg)
    params = parse_section(SearchParams, cfg, "search", where)
    top = parse_section(TopKParams, cfg, "top_k", where)
    search = GlobalSearch(inputs.grid, params)
    laser, angles = inputs.laser, inputs.laser.beam_angles()
    guide_of = None
    if "learned" in cfg:
        learned = parse_section(LearnedParams, cfg, "learned", where)
        _, guide_of, _ = scan_hypotheses(Path(learned.model), inputs.ranges, learned)
    resolution = search.grids.resolution
    nodes: list[int] = []

    def hypotheses_of(scan: np.ndarray) -> Hypotheses:
        valid = (scan >= laser.range_min) & (scan < laser.range_max)
        points = end_points(np.asarray(scan, dtype=np.float64), angles, valid, params)
        guide = guide_of(scan).poses[0] if guide_of is not None else None
        found = search.search_top_k(
            points, top.k, top.separation_m, math.radians(top.separation_deg), guide
        )
        nodes.append(found[-1].nodes if found else 0)
        spread = np.array([resolution, resolution, heading_step(points, resolution)])
        stds = np.tile(spread / math.sqrt(12.0), (1, len(found), 1))
        poses = np.array([m.pose for m in found]).reshape(1, -1, 3)
        return Hypotheses(poses=poses, weights=np.array([[m.score for m in found]]), stds=stds)

    run = localize_learned(
        in_base_frame(hypotheses_of, inputs.laser_mount),
        time.perf_counter() - start,
        inputs.ranges,
        inputs.trajectory.times,
    )
    return run._replace(counts={"nodes_expanded": round(float(np.mean(nodes))) if nodes else 0})


def run_localizer(cfg: Mapping[str, Any], inputs: LocalizeInputs) -> Localization:
    """Run the localizer a config describes (its `meta` section's `kind` picks the function,
    which reads the sections it registered; any other section is an error)."""
    kind = kind_of(cfg)
    check_sections(cfg, KIND_SECTIONS[kind], config_file(cfg), f"a localizer of kind '{kind}'")
    return LOCALIZER_KINDS[kind](cfg, inputs)
