import numpy as np
import pandas as pd
import pytest

from threedcal.dataset.splits import in_field_of_view, split_points, subset, subset_size
from threedcal.errors import ConfigError
from threedcal.seeds import replicate_seed

FRACTIONS = [1, 5, 10, 20, 40, 80]


def grid(n=400):
    side = int(np.sqrt(n))
    xs, ys = np.meshgrid(np.arange(side) * 0.5, np.arange(side) * 0.5)
    return pd.DataFrame({"point": np.arange(side * side), "x_mm": xs.ravel(), "y_mm": ys.ravel()})


def test_validation_is_20_percent_and_disjoint_from_every_subset():
    table = split_points(grid(), FRACTIONS, seed=3)
    assert (table["split"] == "val").sum() == 80
    val = set(table.loc[table["split"] == "val", "point"])
    for p in FRACTIONS:
        chosen = subset(table, p)
        assert len(chosen) == subset_size(400, p)
        assert not val & set(chosen["point"])


def test_subsets_are_nested_and_p80_is_the_whole_training_set():
    table = split_points(grid(), FRACTIONS, seed=3)
    previous = set()
    for p in FRACTIONS:
        current = set(subset(table, p)["point"])
        assert previous <= current
        previous = current
    assert previous == set(table.loc[table["split"] == "train", "point"])


def test_min_p_is_the_smallest_fraction_holding_the_point():
    table = split_points(grid(), FRACTIONS, seed=3)
    for p in FRACTIONS:
        chosen = subset(table, p)
        assert (chosen["min_p"] <= p).all()
    assert (table.loc[table["split"] == "val", "min_p"] == 0).all()


def test_seeded_same_bytes_and_different_seed_differs():
    a = split_points(grid(), FRACTIONS, seed=7).to_csv(index=False)
    b = split_points(grid(), FRACTIONS, seed=7).to_csv(index=False)
    c = split_points(grid(), FRACTIONS, seed=8).to_csv(index=False)
    assert a == b and a != c


def test_too_few_points_or_too_large_fraction_is_refused():
    with pytest.raises(ConfigError, match="too few"):
        split_points(grid(1), [80], seed=0)
    with pytest.raises(ConfigError, match="P=90"):
        split_points(grid(), [90], seed=0)


def test_duplicate_points_are_refused():
    table = pd.concat([grid(4), grid(4)])
    with pytest.raises(ConfigError, match="duplicate"):
        split_points(table, [80], seed=0)


def test_field_of_view_filter_uses_pixel_centre_extent():
    inside = in_field_of_view(
        [0, -0.5, -0.6, 239.5, 239.6, 120], [0, 0, 0, 10, 10, 319.5], 240, 320
    )
    assert inside.tolist() == [True, True, False, True, False, True]
    assert not in_field_of_view([5], [5], 240, 320, margin_px=10)[0]


def test_replicates_share_the_validation_coordinates_and_draw_their_own_nested_subsets():
    table = split_points(grid(), FRACTIONS, seed=3, replicates=3)
    single = split_points(grid(), FRACTIONS, seed=3)
    # replicate 0 is the single-replicate study
    pd.testing.assert_frame_equal(table[single.columns], single)
    assert list(table.columns[-2:]) == ["min_p_r1", "min_p_r2"]
    train = set(table.loc[table["split"] == "train", "point"])
    for replicate in range(3):
        previous = set()
        for p in FRACTIONS:
            chosen = subset(table, p, replicate)
            assert len(chosen) == subset_size(400, p)
            current = set(chosen["point"])
            assert previous <= current <= train  # nested, never a validation coordinate
            previous = current
        assert previous == train  # P = 80 is every training coordinate, in every replicate
    first = [set(subset(table, 5, r)["point"]) for r in range(3)]
    assert first[0] != first[1] and first[1] != first[2]  # a fresh draw per replicate


def test_replicate_seeds_are_the_scene_seed_then_derived_ones():
    assert replicate_seed(7, 0) == 7
    seeds = [replicate_seed(7, r) for r in range(1, 6)]
    assert len(set(seeds)) == 5 and 7 not in seeds
    assert seeds == [replicate_seed(7, r) for r in range(1, 6)]
    assert replicate_seed(8, 1) != replicate_seed(7, 1)
    with pytest.raises(ConfigError, match="replicate"):
        replicate_seed(7, -1)


def test_a_replicate_the_splits_do_not_hold_is_refused():
    table = split_points(grid(), FRACTIONS, seed=3, replicates=2)
    with pytest.raises(ConfigError, match="no replicate 2"):
        subset(table, 5, 2)
    with pytest.raises(ConfigError, match="replicates must be 1 or more"):
        split_points(grid(), FRACTIONS, seed=3, replicates=0)
