"""What the paper publishes that the report sets our numbers beside: Table 1's training
parameters, its Table 1 rows and transfer runs, its two maps and its drive through map 1
(R. Dietrich, "Deep Learning Localization", 2017; paper-spec §4–§6)."""

from __future__ import annotations

# Table 1's rows (our experiment names) and the two transfer runs of §4.3, with their labels.
ROWS = {"mlp": "MLP", "cnn1d_20k": "1D CNN 20k", "cnn1d_200k": "1D CNN 200k", "cnn2d": "2D CNN"}
# The ensemble's member 0: its further members are trained exactly like this row.
ENSEMBLE_SOURCE = "cnn1d_200k"
TRANSFER = {"transfer/scratch": "random init", "transfer/pretrained": "pre-trained on map 1"}
# The paper's maps, with the figure that shows each.
MAPS = {"sparse_obstacles": "map 1 (paper Fig. 6)", "simple_rooms": "map 2 (paper Fig. 8)"}
MAP1 = "sparse_obstacles"
AMBIGUOUS_MAP = "simple_rooms"  # map 2, the symmetric one
PAPER_DRIVE = "sparse_obstacles_drive"  # §4.4: the drive through map 1
PAPER_KIDNAP = "sparse_obstacles_kidnap"
RASTER_SIZE, RASTER_MAX_RANGE = 384, 7.1  # eq. 1–4 and the author's code (7.0 + 0.1)
PAPER_PRECISION = "32-true"  # the paper's Keras trained in float32

# Table 1 (None: no dropout).
PAPER_TABLE1: dict[str, dict[str, float | int | None]] = {
    "mlp": {
        "epochs": 2000,
        "batch_size": 100,
        "lr": 0.01,
        "lr_decay": 0.005,
        "dropout": 0.25,
        "samples": 20000,
    },
    "cnn1d_20k": {
        "epochs": 5000,
        "batch_size": 100,
        "lr": 0.006,
        "lr_decay": 0.0,
        "dropout": 0.1,
        "samples": 20000,
    },
    "cnn1d_200k": {
        "epochs": 400,
        "batch_size": 400,
        "lr": 0.006,
        "lr_decay": 0.0,
        "dropout": None,
        "samples": 200000,
    },
    "cnn2d": {
        "epochs": 400,
        "batch_size": 100,
        "lr": 0.01,
        "lr_decay": 0.005,
        "dropout": 0.1,
        "samples": 20000,
    },
}
TABLE1_PARAMS = (
    ("epochs", "Epochs"),
    ("batch_size", "Batch size"),
    ("lr", "Learn rate"),
    ("lr_decay", "LR-decay"),
    ("dropout", "Dropout"),
    ("samples", "Samples"),
)
