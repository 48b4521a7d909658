"""Seeded splits: partitions with the paper's fractions, per group when asked."""

from __future__ import annotations

import numpy as np
import pytest

from latticeopt.errors import ParameterError
from latticeopt.learn.splits import GESTURE_SPLIT, RECON_SPLIT, split_indices, stratified_split


def test_split_indices_partition_with_paper_fractions():
    parts = split_indices(10_000, RECON_SPLIT, seed=1)
    assert [len(p) for p in parts] == [7000, 2000, 1000]
    assert np.array_equal(np.sort(np.concatenate(parts)), np.arange(10_000))
    again = split_indices(10_000, RECON_SPLIT, seed=1)
    assert all(np.array_equal(a, b) for a, b in zip(parts, again))
    other = split_indices(10_000, RECON_SPLIT, seed=2)
    assert not np.array_equal(parts[0], other[0])
    # Sizes always add up, also when n * fraction is not an integer.
    assert sum(len(p) for p in split_indices(7, (0.7, 0.2, 0.1))) == 7


def test_stratified_split_keeps_group_proportions():
    groups = np.repeat(np.arange(1, 6), 1000)  # 1..5 touches, 1000 samples each
    np.random.default_rng(0).shuffle(groups)
    parts = stratified_split(groups, RECON_SPLIT, seed=3)
    assert np.array_equal(np.sort(np.concatenate(parts)), np.arange(len(groups)))
    for part, frac in zip(parts, RECON_SPLIT):
        counts = np.bincount(groups[part], minlength=6)[1:]
        assert np.all(counts == round(frac * 1000))
    labels = np.repeat(np.arange(12), 1000)
    train, val = stratified_split(labels, GESTURE_SPLIT, seed=0)
    assert np.all(np.bincount(labels[train]) == 800) and np.all(np.bincount(labels[val]) == 200)


@pytest.mark.parametrize("fractions", [(0.7, 0.2), (0.5, -0.1, 0.6), (), ("a",)])
def test_bad_fractions_are_rejected(fractions):
    with pytest.raises(ParameterError, match="fractions"):
        split_indices(10, fractions)
