"""How many epochs ScanLocNet trains on a map: the configured number, raised on a large map so
that each pose-grid cell sees at least `min_samples_per_cell` training scans on average.

Why per cell: the cell head has one logit per cell and the conditional (heading) head learns
each cell through its embedding, which only the scans drawn in that cell train. At a fixed
budget a bigger map gives each cell fewer scans, and its recall falls with them. Measured at
the laptop profile (25,000 scans per epoch, 2 CPU cores with bf16, 2026-12-03; a generated
50 x 25 m rooms map, 1250 cells, `big_rooms` of tests/test_pipeline_e2e.py; docs/benchmarks.md):

    epochs  scans per cell  validation top-5  drive: top-5  drive: verified top-1  training
      12         240             57.7 %          71.3 %          97.3 %              68 s
      28         560             67.8 %          90.0 %          97.8 %             157 s
      60        1200             80.6 %          96.0 %          97.2 %             328 s

and the defaults' maps at 12 epochs: sparse_obstacles 1351 scans per cell (validation top-5
98.5 %), simple_rooms 1053 (77.7 %), fr079 610 (70.5 %), intel 567 (69.3 %). The laptop floor
is 560, the fewest any default map gets, so that the default run is unchanged and a bigger map
trains at least as densely as intel; the paper profile's is 7500 for the same reason.
"""

from __future__ import annotations

import math


def training_epochs(
    epochs: int, scans_per_epoch: int, cells: int, min_samples_per_cell: int
) -> int:
    """`epochs`, or more where `cells` pose-grid cells would get fewer than
    `min_samples_per_cell` training scans each over the run (0 turns the floor off)."""
    if epochs < 1 or scans_per_epoch < 1 or cells < 1 or min_samples_per_cell < 0:
        raise ValueError(
            "need epochs >= 1, scans_per_epoch >= 1, cells >= 1 and min_samples_per_cell >= 0, "
            f"got {epochs}, {scans_per_epoch}, {cells}, {min_samples_per_cell}"
        )
    return max(epochs, math.ceil(min_samples_per_cell * cells / scans_per_epoch))
