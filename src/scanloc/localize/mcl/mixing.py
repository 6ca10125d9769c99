"""How many particles come from the proposal at a filter update: the mixing policy.

amcl draws none (`none`): its proposal comes in only at a global initialisation and through
the recovery's injections while resampling. The hybrid (localize/hybrid.py) registers
`constant`, `adaptive` and `verified_gate`, which draw a share of the particle count from the
proposal beside the motion-predicted ones; the weighting (proposals.py) then weights the union.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Mixing(Protocol):
    """The share of the particle count to draw from the proposal at an update."""

    def share(self, poses: np.ndarray, weights: np.ndarray) -> float:
        """The share for this update, given the motion-predicted particles; called once per
        update after the first since an initialisation."""
        ...

    def observe_likelihood(self, w_avg: float) -> None:
        """The mean unnormalised sensor factor of an update (an adaptive policy follows it)."""
        ...

    def counts(self) -> dict[str, int]:
        """Event counts to report with the run (e.g. updates that drew proposed particles)."""
        ...


class NoMixing:
    """amcl: no particle from the proposal at updates."""

    def share(self, poses: np.ndarray, weights: np.ndarray) -> float:
        return 0.0

    def observe_likelihood(self, w_avg: float) -> None:
        """Nothing to follow."""

    def counts(self) -> dict[str, int]:
        return {}
