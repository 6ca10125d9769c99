"""ScanLocNet's epochs on a map (scanloc.scanlocnet.schedule): the configured number, raised on
a large map to a floor of training scans per pose-grid cell."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from scanloc.scanlocnet.schedule import training_epochs


def test_the_default_maps_keep_their_epochs_and_a_large_map_gets_more() -> None:
    # the laptop profile: 12 x 25000 scans, floor 560 per cell
    for cells in (222, 285, 492, 529):  # sparse_obstacles, simple_rooms, fr079, intel
        assert training_epochs(12, 25_000, cells, 560) == 12
    assert training_epochs(12, 25_000, 1250, 560) == 28  # the 50 x 25 m rooms map
    assert training_epochs(12, 25_000, 5000, 560) == 112
    assert training_epochs(12, 25_000, 5000, 0) == 12  # floor off


@given(
    epochs=st.integers(1, 100),
    per_epoch=st.integers(1, 200_000),
    cells=st.integers(1, 20_000),
    floor=st.integers(0, 10_000),
)
def test_the_floor_is_met_with_the_fewest_epochs(epochs, per_epoch, cells, floor) -> None:
    got = training_epochs(epochs, per_epoch, cells, floor)
    assert got >= epochs
    assert got * per_epoch >= floor * cells  # every cell gets its floor on average
    if got > epochs:  # one epoch fewer would miss it
        assert (got - 1) * per_epoch < floor * cells


@pytest.mark.parametrize("args", [(0, 10, 10, 1), (1, 0, 10, 1), (1, 10, 0, 1), (1, 10, 10, -1)])
def test_nonsense_sizes_are_refused(args) -> None:
    with pytest.raises(ValueError, match="need epochs >= 1"):
        training_epochs(*args)
