"""Scan → image (paper eq. 1–4) against hand-computed pixels and a per-point reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from scanloc.data.rasterize import rasterize_scans
from scanloc.sensor.laser import LaserSpec


def lit(image: torch.Tensor) -> set[tuple[int, int]]:
    """(row, col) = (imgX, imgY) of the set pixels of one (1, size, size) image."""
    return {(int(r), int(c)) for r, c in torch.nonzero(image[0]).tolist()}


def reference_pixels(ranges, angles, size=384, max_range=7.1, skip_range=None):
    """Eq. 1–4 point by point in float64 (row from x = sin(α)·r, column from y = cos(α)·r).

    Also returns whether any point lies within 1e-3 px of a rounding boundary, where float32
    and float64 may legitimately round differently."""
    pixels, ambiguous = set(), False
    for r, a in zip(ranges, angles, strict=True):
        if not math.isfinite(r) or (skip_range is not None and r >= skip_range):
            continue
        coords = []
        for v in (math.sin(a) * r, math.cos(a) * r):  # row, col
            p = v * size / (2 * max_range) + size / 2
            ambiguous |= abs(p - math.floor(p) - 0.5) < 1e-3
            coords.append(min(max(math.floor(p + 0.5), 0), size - 1))
        pixels.add(tuple(coords))
    return pixels, ambiguous


def test_hand_made_scan() -> None:
    # 27.042... px/m around the centre pixel (192, 192).
    angles = torch.tensor([0.0, math.pi / 2, -math.pi / 2, math.pi / 4])
    ranges = torch.tensor([[1.0, 2.0, 0.5, 3.0]])
    image = rasterize_scans(ranges, angles)
    assert image.shape == (1, 1, 384, 384) and image.dtype == torch.float32
    # By hand, s = 384 / 14.2 = 27.0423 px/m:
    expected = {
        (192, 219),  # forward: column grows (eq. 2, 4), 192 + 1.0·s = 219.04
        (246, 192),  # left (+90°): row grows (eq. 1, 3), 192 + 2.0·s = 246.08
        (178, 192),  # right: row shrinks, 192 − 0.5·s = 178.48
        (249, 249),  # 45° left: 192 + 3·s/√2 = 249.37 in both
    }
    assert lit(image[0]) == expected
    assert image.sum() == 4


def test_no_return_points_drawn_or_skipped_and_bad_values() -> None:
    angles = torch.tensor([0.0, 0.5, 1.0, 1.5])
    ranges = torch.tensor([[7.0, 2.0, float("inf"), float("nan")]])
    assert rasterize_scans(ranges, angles).sum() == 2  # the 7.0 point is drawn, inf/nan never
    assert rasterize_scans(ranges, angles, skip_range=7.0).sum() == 1
    far = rasterize_scans(torch.tensor([[100.0, 100.0]]), torch.tensor([0.0, math.pi]))
    assert lit(far[0]) == {(192, 383), (192, 0)}  # clipped to the border


def test_batched_equals_one_by_one_and_shape_errors() -> None:
    angles = torch.from_numpy(LaserSpec(num_beams=40).beam_angles()).float()
    ranges = torch.rand(5, 40) * 7
    batch = rasterize_scans(ranges, angles, size=96, max_range=7.1)
    for i in range(5):
        torch.testing.assert_close(batch[i : i + 1], rasterize_scans(ranges[i : i + 1], angles, 96))
    with pytest.raises(ValueError, match="ranges must have shape"):
        rasterize_scans(ranges[0], angles)
    with pytest.raises(ValueError, match="angles must have shape"):
        rasterize_scans(ranges, angles[:-1])


@settings(max_examples=40, deadline=None)
@given(
    ranges=st.lists(st.floats(0.02, 7.0), min_size=8, max_size=8),
    size=st.sampled_from([64, 128, 384]),
    max_range=st.floats(3.0, 10.0),
)
def test_matches_the_equations(ranges: list[float], size: int, max_range: float) -> None:
    angles = LaserSpec(num_beams=8).beam_angles()
    expected, ambiguous = reference_pixels(ranges, angles, size, max_range)
    assume(not ambiguous)  # within 1e-3 px of a rounding boundary: float32 may round either way
    image = rasterize_scans(
        torch.tensor([ranges], dtype=torch.float32),
        torch.from_numpy(angles),
        size,
        max_range,
    )
    assert lit(image[0]) == expected
    assert image.sum() == len(expected)  # binary: each lit pixel is 1, however many beams hit it


def test_image_follows_the_input_device_and_dtype() -> None:
    ranges = np.full((2, 3), 1.5, dtype=np.float64)
    image = rasterize_scans(torch.from_numpy(ranges), torch.zeros(3), size=32)
    assert image.dtype == torch.float32
    assert image.sum() == 2  # three beams on one pixel per scan
    # Scans on another device (here "meta", which needs no accelerator) give the image there,
    # with angles on the CPU moved along.
    meta = rasterize_scans(torch.from_numpy(ranges).to("meta"), torch.zeros(3), size=32)
    assert meta.device.type == "meta" and meta.dtype == torch.float32
    assert meta.shape == (2, 1, 32, 32)
