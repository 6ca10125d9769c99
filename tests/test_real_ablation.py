"""The real_ablation stage's variants: which corruptions each switches off."""

import pytest

from scanloc.sensor.corruptions import KINDS
from scanloc.stages.real_ablation import VARIANTS, variant_off


def test_each_variant_switches_off_its_own_corruption() -> None:
    assert variant_off("none") == []  # the matched baseline: every corruption on
    assert variant_off("all") == [*KINDS, "noise"]
    for kind in (*KINDS, "noise"):
        assert variant_off(kind) == [kind]
    assert set(VARIANTS) == {"none", "all", *KINDS, "noise"}


def test_an_unknown_variant_names_the_choices() -> None:
    with pytest.raises(ValueError, match=r"variant: expected one of .*'none'.*got 'glass'"):
        variant_off("glass")
