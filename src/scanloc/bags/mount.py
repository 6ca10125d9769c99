"""Where the laser sits on the robot: the transform base_link → the scans' frame, wherever ROS
put it.

ROS 2 robots (and ROS 1's robot_state_publisher) publish fixed joints once on /tf_static; older
ROS 1 setups repeat them on /tf at a rate (`static_transform_publisher` of tf, not tf2). So the
chain is searched among the static transforms first, then among those and the transforms on
/tf; a link taken from /tf must hold still (TfSpread: every message within CONSTANT_M and
CONSTANT_RAD of its first), since scanloc's runs carry one fixed mount. A laser on a moving
joint (a tilting or turning mount) is refused with how far it moved.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanloc.bags.errors import BagError
from scanloc.pose import compose

CONSTANT_M = 1e-6  # a repeated transform varying by less than this is the same transform
CONSTANT_RAD = 1e-6

Edge = tuple[str, str]
Planar = tuple[float, float, float]


@dataclass
class TfSpread:
    """One transform as it recurs on /tf: its first pose and how far later ones stray from it."""

    first: Planar
    count: int = 1
    max_shift_m: float = 0.0
    max_turn_rad: float = 0.0

    def add(self, pose: Planar) -> None:
        self.count += 1
        shift = math.hypot(pose[0] - self.first[0], pose[1] - self.first[1])
        turn = abs(math.remainder(pose[2] - self.first[2], math.tau))
        self.max_shift_m = max(self.max_shift_m, shift)
        self.max_turn_rad = max(self.max_turn_rad, turn)

    @property
    def constant(self) -> bool:
        return self.max_shift_m <= CONSTANT_M and self.max_turn_rad <= CONSTANT_RAD


def _chain(edges: dict[Edge, Planar], base: str, laser: str) -> list[Edge] | None:
    """The parent → child links from `base` down to `laser` (breadth first), None if none."""
    todo: deque[tuple[str, list[Edge]]] = deque([(base, [])])
    seen = {base}
    while todo:
        at, path = todo.popleft()
        for parent, child in edges:
            if parent == at and child not in seen:
                if child == laser:
                    return [*path, (parent, child)]
                seen.add(child)
                todo.append((child, [*path, (parent, child)]))
    return None


def _composed(edges: dict[Edge, Planar], chain: list[Edge]) -> Planar:
    pose = np.asarray(edges[chain[0]], dtype=np.float64)  # as is: no wrap to lose a bit
    for link in chain[1:]:
        pose = compose(pose, np.asarray(edges[link], dtype=np.float64))
    return float(pose[0]), float(pose[1]), float(pose[2])


def laser_mount(
    bag: str | Path,
    static: dict[Edge, Planar],
    dynamic: dict[Edge, TfSpread],
    base: str,
    laser: str,
    topics: tuple[str, str] = ("/tf_static", "/tf"),
) -> tuple[Planar, str]:
    """(base → laser (x, y, yaw), where it came from) through the static transforms, else
    through them and constant transforms on /tf (module doc); `topics`: (tf_static, tf)."""
    tf_static, tf = topics
    if base == laser:
        return (0.0, 0.0, 0.0), "identity: the scans are in the base frame"
    chain = _chain(static, base, laser)
    if chain is not None:
        return _composed(static, chain), tf_static
    edges = {link: spread.first for link, spread in dynamic.items()} | static
    chain = _chain(edges, base, laser)
    if chain is None:
        present = [f"{p}→{c}" for p, c in static] or "none"
        raise BagError(
            bag,
            tf_static,
            f"no transform {base}→{laser} (the laser's mounting): expected it among the "
            f"static transforms or as a constant transform repeated on {tf}; static "
            f"transforms present: {present}",
        )
    from_tf = [link for link in chain if link not in static]
    for parent, child in from_tf:
        spread = dynamic[(parent, child)]
        if not spread.constant:
            raise BagError(
                bag,
                tf,
                f"the laser's mounting {base}→{laser} moves: its link {parent}→{child} varies "
                f"by up to {spread.max_shift_m:.4f} m and {math.degrees(spread.max_turn_rad):.3f}"
                f" deg over {spread.count} messages; expected a fixed mount (a static "
                "transform, or a constant one repeated on /tf)",
            )
    counts = ", ".join(f"{p}→{c} x {dynamic[(p, c)].count}" for p, c in from_tf)
    return _composed(edges, chain), f"{tf} (constant: {counts})"
