"""Short- and long-term averages of the mean sensor likelihood (augmented MCL, Thrun et al.,
Probabilistic Robotics, table 8.3): amcl's recovery injects random poses while the short-term
average falls below the long-term one, and the hybrid's adaptive mixing draws proposed
particles then. Both follow the same two averages, written here once."""

from __future__ import annotations


class LikelihoodAverages:
    """w_slow / w_fast: exponential averages of the mean weight with rates `alpha_slow` /
    `alpha_fast`, each starting at the first value it sees (amcl's pf_update_sensor)."""

    def __init__(self, alpha_slow: float, alpha_fast: float) -> None:
        if not (0 <= alpha_slow <= 1 and 0 <= alpha_fast <= 1):
            raise ValueError(
                f"alpha_slow / alpha_fast must lie in [0, 1], got {alpha_slow}, {alpha_fast}"
            )
        self.alpha_slow, self.alpha_fast = alpha_slow, alpha_fast
        self.slow = self.fast = 0.0

    def follow(self, w_avg: float) -> None:
        """One update's mean (unnormalised) weight."""
        self.slow = w_avg if self.slow == 0.0 else self.slow + self.alpha_slow * (w_avg - self.slow)
        self.fast = w_avg if self.fast == 0.0 else self.fast + self.alpha_fast * (w_avg - self.fast)

    def lost(self) -> float:
        """1 - w_fast / w_slow (0 before the first value): how far the likelihood fell."""
        return 1.0 - self.fast / self.slow if self.slow > 0.0 else 0.0

    def reset(self) -> None:
        self.slow = self.fast = 0.0
