"""Look-alike places (evaluate/look_alikes.py): the copies of a map that render the same scans,
and which stretches of a run they keep ambiguous."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from scanloc.evaluate.look_alikes import (
    EvidenceModel,
    LookAlikeParams,
    Symmetry,
    beam_evidence,
    copy_track,
    look_alikes_json,
    map_look_alikes,
    map_symmetries,
    run_look_alikes,
    stretch_resolution,
)
from scanloc.sensor.noise import RangeGaussianNoise
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.trajectory.format import Trajectory, save_trajectory
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid
from small_world import SPEC, small_map

PARAMS = LookAlikeParams()
NOISE = RangeGaussianNoise()  # the UG01 datasheet's, as the maps' runs
ORIGIN = (-1.0, 2.0, 0.0)  # off the world's origin: the symmetries' shifts must account for it


def _two_rooms(box_in_second: bool = False) -> OccupancyGrid:
    """The small asymmetric room twice, side by side along x (a copy 6 m further), each closed
    by its own walls; optionally a box in the second copy only, around local (3.15, 2.15)."""
    room = small_map()
    cells = np.hstack([room.cells, room.cells])
    if box_in_second:
        r, shift = room.resolution, room.width
        cells[round(2.0 / r) : round(2.3 / r), shift + round(3.0 / r) : shift + round(3.3 / r)] = (
            OCCUPIED
        )
    return OccupancyGrid(cells, room.resolution, ORIGIN)


def _turning_in_place(steps: int = 20) -> np.ndarray:
    """Poses at local (5.0, 2.2) of the first room, turning from heading 0 to π: the spot
    around local (3.15, 2.15) is behind the laser (its 240° field) at first, in view later."""
    x, y = ORIGIN[0] + 5.0, ORIGIN[1] + 2.2
    return np.column_stack([np.full(steps, x), np.full(steps, y), np.linspace(0, math.pi, steps)])


def test_a_copied_room_is_found_as_a_shift_and_keeps_the_stretch_ambiguous() -> None:
    grid = _two_rooms()
    symmetries = map_symmetries(grid, PARAMS)
    shifts = [(s.tx, s.ty) for s in symmetries if s.quarter_turns == 0]
    assert any(s == pytest.approx((6.0, 0.0), abs=1e-9) for s in shifts)
    assert all(math.hypot(*s) >= PARAMS.min_separation_m for s in shifts)
    assert len(symmetries) <= PARAMS.max_candidates
    stretches = run_look_alikes(grid, SPEC, NOISE, _turning_in_place(), [], PARAMS)
    assert stretches == [
        {"start": 0, "look_alikes": 1, "ambiguous": True, "resolved_at": PARAMS.window}
    ]


def test_a_difference_in_view_resolves_the_stretch_when_it_comes_into_view() -> None:
    grid = _two_rooms(box_in_second=True)
    poses = _turning_in_place()
    (stretch,) = run_look_alikes(grid, SPEC, NOISE, poses, [], PARAMS)
    assert stretch["look_alikes"] == 1 and not stretch["ambiguous"]
    resolved = stretch["resolved_at"]
    assert 0 < resolved < len(poses)
    # the scans at the copy agree before that step and differ at it
    copy = Symmetry(0, 6.0, 0.0, 0.0).apply(poses)
    cast_map = CastMap.from_grid(grid)
    at_truth = cast_exact(cast_map, poses, SPEC.beam_angles(), SPEC.range_max)
    at_copy = cast_exact(cast_map, copy, SPEC.beam_angles(), SPEC.range_max)
    pairs = zip(at_truth, at_copy, strict=True)
    same = [np.allclose(a, b, atol=1e-6, equal_nan=True) for a, b in pairs]
    assert all(same[:resolved]) and not same[resolved]


@pytest.mark.parametrize("offset", [(0.04, 0.0), (-0.03, 0.05)])
def test_a_copy_posed_off_its_exact_place_is_optimised_onto_it(offset) -> None:
    """A symmetry is found on whole cells and a real copy may sit between them: the copy is
    posed by optimisation within the refine bounds, so a symmetry a few centimetres off the
    exact copy still keeps the stretch ambiguous. Unrefined, the same copy is told apart at
    the first step (every beam a few centimetres off)."""
    grid = _two_rooms()
    off = Symmetry(0, 6.0 + offset[0], offset[1], 0.0)
    poses = _turning_in_place()
    model = EvidenceModel(grid, CastMap.from_grid(grid), SPEC, NOISE, PARAMS)
    at_truth = cast_exact(model.cast_map, poses, SPEC.beam_angles(), SPEC.range_max)
    unrefined = copy_track(poses, off, (0.0, 0.0, 0.0))
    assert model.per_step(unrefined[:1], at_truth[:1])[0] >= PARAMS.llr_threshold_nats
    stretch = stretch_resolution(model, poses, [off])
    assert stretch == {"look_alikes": 1, "ambiguous": True, "resolved_at": PARAMS.window}


def test_the_evidence_is_the_expected_log_likelihood_ratio_of_the_noise_model() -> None:
    """Against a Monte Carlo estimate: scans drawn at the truth under the UG01 noise, the mean
    log-likelihood ratio of the truth's Gaussian over the copy's, every beam summed."""
    rng = np.random.default_rng(0)
    a = rng.uniform(0.3, 5.0, (1, 50))
    b = a + rng.normal(0.0, 0.02, a.shape)
    sa, sb = NOISE.sigma(a), NOISE.sigma(b)
    z = a + sa * rng.standard_normal((20000, a.shape[1]))
    log_ratio = np.log(sb / sa) - (z - a) ** 2 / (2 * sa**2) + (z - b) ** 2 / (2 * sb**2)
    expected = log_ratio.sum(axis=1).mean()
    assert beam_evidence(a, b, NOISE, 0.0, np.inf)[0] == pytest.approx(expected, rel=0.03)


def test_a_copy_a_few_centimetres_off_on_every_beam_is_told_apart() -> None:
    """The case a per-beam tolerance lets through: every beam 3 cm off (within one 5 cm cell)
    is little evidence per beam and much over a scan's beams."""
    truth = np.full((1, 600), 2.0)
    per_beam = beam_evidence(truth, truth + 0.03, NOISE, 0.025, PARAMS.beam_cap_nats)[0] / 600
    assert per_beam < 0.5  # no beam alone tells them apart
    assert 600 * per_beam > PARAMS.llr_threshold_nats  # the scan does, at once
    assert beam_evidence(truth, truth, NOISE, 0.025, PARAMS.beam_cap_nats)[0] == 0.0


def test_a_beam_says_at_most_the_cap_and_no_return_at_both_says_nothing() -> None:
    cap = PARAMS.beam_cap_nats
    a = np.array([[np.inf, np.inf, 2.0, 2.0]])
    b = np.array([[np.inf, 2.0, np.inf, 4.0]])
    assert beam_evidence(a, b, NOISE, 0.025, cap)[0] == pytest.approx(3 * cap)


def test_kidnaps_split_a_run_into_stretches_judged_alone() -> None:
    grid = _two_rooms(box_in_second=True)
    seen_at_once = _turning_in_place()[::-1]  # starts facing the spot: told apart at step 0
    truth = np.vstack([seen_at_once, _turning_in_place()])
    stretches = run_look_alikes(grid, SPEC, NOISE, truth, [20], PARAMS)
    assert [s["start"] for s in stretches] == [0, 20]
    assert stretches[0]["look_alikes"] == 0 and not stretches[0]["ambiguous"]
    assert stretches[1]["look_alikes"] == 1 and stretches[1]["resolved_at"] > 0


def test_a_point_symmetric_room_has_a_half_turn_that_maps_scans_onto_scans() -> None:
    r = 0.05
    cells = np.zeros((100, 160), dtype=np.int8)  # 8 m x 5 m
    cells[[0, -1], :] = OCCUPIED
    cells[:, [0, -1]] = OCCUPIED
    cells[20:30, 30:60] = OCCUPIED  # a block and its image under the half turn
    cells[70:80, 100:130] = OCCUPIED
    grid = OccupancyGrid(cells, r, ORIGIN)
    half_turn = map_symmetries(grid, PARAMS)[0]  # the strongest: every wall onto a wall
    assert half_turn.quarter_turns == 2 and half_turn.overlap == pytest.approx(1.0)
    # rotation by π about the map's centre c: p ↦ 2c − p
    centre = (ORIGIN[0] + 4.0, ORIGIN[1] + 2.5)
    assert (half_turn.tx, half_turn.ty) == pytest.approx((2 * centre[0], 2 * centre[1]))
    rng = np.random.default_rng(3)
    free_rows, free_cols = np.nonzero(grid.free)
    pick = rng.choice(len(free_rows), 30, replace=False)
    poses = np.column_stack(
        [
            ORIGIN[0] + (free_cols[pick] + 0.5) * r,
            ORIGIN[1] + (free_rows[pick] + 0.5) * r,
            rng.uniform(-math.pi, math.pi, 30),
        ]
    )
    moved = half_turn.apply(poses)
    assert np.all(np.abs(moved[:, 2]) <= math.pi)
    cast_map = CastMap.from_grid(grid)
    at_poses = cast_exact(cast_map, poses, SPEC.beam_angles(), SPEC.range_max)
    at_moved = cast_exact(cast_map, moved, SPEC.beam_angles(), SPEC.range_max)
    finite = np.isfinite(at_poses)
    assert np.array_equal(finite, np.isfinite(at_moved))
    assert np.abs(at_poses[finite] - at_moved[finite]).max() < 1e-6


def test_an_asymmetric_room_has_no_look_alike() -> None:
    room = small_map()
    truth = np.column_stack([np.full(20, 5.0), np.full(20, 2.2), np.linspace(0, math.pi, 20)])
    assert run_look_alikes(room, SPEC, NOISE, truth, [], PARAMS)[0]["look_alikes"] == 0


def test_quarter_turns_move_poses_as_rotations() -> None:
    pose = np.array([[1.0, 2.0, 0.5]])
    quarter = Symmetry(1, 10.0, 0.0, 1.0).apply(pose)
    assert quarter == pytest.approx(np.array([[10.0 - 2.0, 1.0, 0.5 + math.pi / 2]]))
    back = Symmetry(3, 0.0, 0.0, 1.0).apply(Symmetry(1, 0.0, 0.0, 1.0).apply(pose))
    assert back == pytest.approx(pose)


def test_the_map_figures_count_ambiguous_starts_and_kidnaps(tmp_path) -> None:
    grid = _two_rooms()
    save_map(grid, tmp_path / "map" / "map.yaml")
    truth = np.vstack([_turning_in_place(), _turning_in_place()])
    run_dir = tmp_path / "room_kidnap"
    steps = len(truth)
    trajectory = Trajectory(
        times=np.arange(steps) * 0.1, truth=truth, odometry=truth.copy(), kidnap_steps=(20,)
    )
    ranges = np.zeros((steps, SPEC.num_beams), np.float32)
    meta = {"sensor": dataclasses.asdict(SPEC), "noise": dataclasses.asdict(NOISE)}
    save_trajectory(trajectory, run_dir, ranges, meta)
    doc = map_look_alikes(tmp_path / "map" / "map.yaml", {"room_kidnap": run_dir}, PARAMS)
    assert (doc["starts"], doc["starts_ambiguous"]) == (1, 1)
    assert (doc["kidnaps"], doc["kidnaps_ambiguous"]) == (1, 1)
    assert doc["window"] == PARAMS.window and doc["symmetries"]
    assert look_alikes_json({"room": doc}) == look_alikes_json({"room": doc})
    save_trajectory(trajectory, run_dir, ranges, meta | {"sensor": {"num_beams": 1.5}})
    with pytest.raises(ValueError, match=r"room_kidnap/meta.json: field 'sensor'"):
        map_look_alikes(tmp_path / "map" / "map.yaml", {"room_kidnap": run_dir}, PARAMS)
    save_trajectory(trajectory, run_dir, ranges, meta | {"noise": {"kind": "laser"}})
    with pytest.raises(ValueError, match=r"room_kidnap/meta.json: field 'noise'"):
        map_look_alikes(tmp_path / "map" / "map.yaml", {"room_kidnap": run_dir}, PARAMS)


def test_bad_parameters_name_the_source_and_the_field() -> None:
    with pytest.raises(ValueError, match=r"conf/evaluate.yaml: unknown fields \['tolerance'\]"):
        LookAlikeParams.from_config({"tolerance": 0.1}, "conf/evaluate.yaml")
    with pytest.raises(ValueError, match="min_overlap"):
        LookAlikeParams(min_overlap=0.0)
    assert LookAlikeParams.from_config({"max_candidates": "3"}, "x").max_candidates == 3
