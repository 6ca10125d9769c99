"""Scan → binary image, the 2D CNN's input (paper eq. 1–4), batched on the scans' device.

For beam i at angle α_i (0 = forward, counter-clockwise positive, as `LaserSpec.beam_angles`)
and range r_i:

    x_i = sin(α_i)·r_i                           (eq. 1: lateral, positive to the robot's left)
    y_i = cos(α_i)·r_i                           (eq. 2: forward)
    imgX_i = iround(x_i·size/(2·max) + size/2)   (eq. 3)
    imgY_i = iround(y_i·size/(2·max) + size/2)   (eq. 4)

and image[b, 0, imgX_i, imgY_i] = 1: the row index is imgX (towards the robot's left), the
column index imgY (forward), the robot at pixel (size/2, size/2). Shown with
`imshow(origin="lower")` the robot looks to the right and its left side is up, the usual
robot frame. `iround` rounds halves up (floor(v + 0.5), like Python 2's round for these
non-negative coordinates); indices outside the image are clipped to its border.

The author used max = 7.0 + 0.1 (27.04 px/m) and also drew the 7.0 m "no return" points;
`skip_range` leaves out points whose range is at least that value instead. Non-finite ranges
are never drawn.
"""

from __future__ import annotations

import torch
from torch import Tensor


def rasterize_scans(
    ranges: Tensor,
    angles: Tensor,
    size: int = 384,
    max_range: float = 7.1,
    *,
    skip_range: float | None = None,
) -> Tensor:
    """Binary images (B, 1, size, size) float32 of scans `ranges` (B, N) at beam `angles` (N,).

    One scatter over all scans at once (flat index = (b·size + imgX)·size + imgY), on the
    device of `ranges`; no per-scan Python loop.
    """
    if ranges.ndim != 2:
        raise ValueError(f"ranges must have shape (B, N), got {tuple(ranges.shape)}")
    if angles.shape != (ranges.shape[1],):
        raise ValueError(
            f"angles must have shape ({ranges.shape[1]},) to match ranges, got "
            f"{tuple(angles.shape)}"
        )
    if size < 1 or max_range <= 0:
        raise ValueError(f"need size >= 1 and max_range > 0, got {size}, {max_range}")
    batch, _ = ranges.shape
    r = ranges.to(torch.float32)
    drawn = torch.isfinite(r)
    if skip_range is not None:
        drawn &= r < skip_range
    r = torch.where(drawn, r, torch.zeros((), dtype=r.dtype, device=r.device))
    angles = angles.to(device=r.device, dtype=torch.float32)
    scale, centre = size / (2.0 * max_range), size / 2.0
    img_x = _pixel(torch.sin(angles) * r, scale, centre, size)
    img_y = _pixel(torch.cos(angles) * r, scale, centre, size)
    first = torch.arange(batch, device=r.device).unsqueeze(1) * (size * size)
    index = first + img_x * size + img_y
    # Points that are not drawn go to one spare pixel past the images, dropped below.
    index = torch.where(drawn, index, torch.full_like(index, batch * size * size))
    flat = torch.zeros(batch * size * size + 1, dtype=torch.float32, device=r.device)
    # Out of place, so that torch.func.vmap can batch it (stacked ensembles).
    flat = flat.index_fill(0, index.reshape(-1), 1.0)
    return flat[:-1].view(batch, 1, size, size)


def _pixel(coord: Tensor, scale: float, centre: float, size: int) -> Tensor:
    """iround(coord·scale + centre) clipped to [0, size − 1], as int64."""
    return torch.floor(coord * scale + (centre + 0.5)).clamp(0, size - 1).to(torch.int64)
