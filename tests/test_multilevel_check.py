"""The gap between a two-level estimate and the all-fine mean, on synthetic data (no simulation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from latticeopt.study.multilevel import fine_order, multilevel_estimate, take_all_mask
from latticeopt.study.multilevel_check import gap_to_plain

STRATA = np.repeat([1, 2, 3], [30, 45, 45])


def _population(rng):
    """One fixed map: fine values by touch count, a coarse level that misses them by a spread-out error."""
    f = 0.01 * STRATA + 0.02 * rng.gamma(2.0, size=STRATA.size)
    c = f + 0.004 + 0.01 * rng.standard_normal(STRATA.size) * (f / f.mean())
    return c, f


def _random_nested_subset(rng, n, take_all=None):
    """The first ``n`` of the value-blind fine order of a random phantom order (the study's phantoms are seeded)."""
    perm = rng.permutation(STRATA.size)
    sub = np.zeros(STRATA.size, dtype=bool)
    sub[perm[fine_order(STRATA[perm])[:n]]] = True
    return sub if take_all is None else sub & ~take_all


@pytest.mark.parametrize("with_take_all", [False, True])
def test_the_gap_spreads_over_random_subsets_as_its_se_says(with_take_all):
    # finite-population sampling of one fixed map: the gap's spread over random nested subsets is the SE it
    # states, and its mean over them is zero
    rng = np.random.default_rng(11)
    c, f = _population(rng)
    take = take_all_mask(c, STRATA, 0.1) if with_take_all else None
    gaps, ses = [], []
    for _ in range(3000):
        gap, se = gap_to_plain(c, f, STRATA, _random_nested_subset(rng, 30, take), take_all=take)
        gaps.append(gap)
        ses.append(se)
    assert abs(np.mean(gaps)) < 4 * np.std(gaps) / math.sqrt(len(gaps))
    assert np.std(gaps) == pytest.approx(math.sqrt(np.mean(np.square(ses))), rel=0.06)
    if not with_take_all:  # var(D) over whole strata: one value for every subset of one size per stratum
        assert np.ptp(ses) < 1e-15


def test_the_gap_is_the_difference_of_the_two_estimates_and_vanishes_with_every_phantom_fine():
    rng = np.random.default_rng(3)
    c, f = _population(rng)
    sub = _random_nested_subset(rng, 24)
    gap, se = gap_to_plain(c, f, STRATA, sub)
    plain = sum(np.mean(f[STRATA == k]) * np.mean(STRATA == k) for k in (1, 2, 3))
    assert gap == pytest.approx(multilevel_estimate(c, np.where(sub, f, np.nan), STRATA).mean - plain, abs=1e-15)
    assert 0 < se < multilevel_estimate(c, np.where(sub, f, np.nan), STRATA).se
    assert gap_to_plain(c, f, STRATA, np.ones(STRATA.size, dtype=bool)) == (pytest.approx(0, abs=1e-15), 0.0)
    with pytest.raises(ValueError, match="finite"):
        gap_to_plain(c, np.where(sub, f, np.nan), STRATA, sub)
