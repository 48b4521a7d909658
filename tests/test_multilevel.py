"""The two-level estimator's statistics on synthetic correlated data (no simulation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from latticeopt.study.multilevel import (
    fine_order,
    gap_to_plain,
    min_fine_count,
    multilevel_estimate,
    next_fine_count,
    predicted_fine_count,
)

STRATA = np.repeat([1, 2, 3], [40, 40, 40])
TRUE_MEANS = {1: 0.02, 2: 0.035, 3: 0.05}


def _draw(rng, strata=STRATA, noise=0.002):
    """Fine values with stratum means TRUE_MEANS and spread; coarse = biased, scaled fine + small noise."""
    mu = np.array([TRUE_MEANS[k] for k in strata])
    f = mu + 0.01 * rng.standard_normal(strata.size) * (1 + 0.3 * strata)
    c = 0.9 * f - 0.003 + noise * rng.standard_normal(strata.size)
    return c, f


def _true_mean(strata=STRATA):
    return float(np.mean([TRUE_MEANS[k] for k in strata]))


def _prefix(f, strata, n):
    out = np.full(f.shape, np.nan)
    idx = fine_order(strata)[:n]
    out[idx] = f[idx]
    return out


def test_fine_order_is_nested_proportional_and_in_sequence_order_per_stratum():
    s = np.repeat([1, 2, 3], [10, 20, 30])
    order = fine_order(s)
    assert sorted(order.tolist()) == list(range(60))
    for n in range(1, 61):
        counts = [int(np.sum(s[order[:n]] == k)) for k in (1, 2, 3)]
        for k, c in zip((1, 2, 3), counts):
            assert abs(c - n * np.sum(s == k) / 60) <= 1
    for k in (1, 2, 3):  # each stratum's phantoms come in their sequence order
        pos = order[s[order] == k]
        assert np.all(np.diff(pos) > 0)
    assert min_fine_count(s) == int(np.argmax(np.cumsum(s[order] == 1) >= 2)) + 1


@pytest.mark.parametrize("n", [12, 30, 60])
def test_unbiased_and_se_matches_the_spread_over_repetitions(n):
    reps = 2000
    rng = np.random.default_rng(11)
    est, ses = np.empty(reps), np.empty(reps)
    for r in range(reps):
        c, f = _draw(rng)
        e = multilevel_estimate(c, _prefix(f, STRATA, n), STRATA)
        est[r], ses[r] = e.mean, e.se
    spread = est.std(ddof=1)
    # mean error within a few standard errors of the Monte Carlo mean
    assert abs(est.mean() - _true_mean()) < 4 * spread / math.sqrt(reps)
    # the SE formula against the empirical spread (RMS of the estimated SEs; 5 % for 2000 repetitions)
    assert math.sqrt(np.mean(ses ** 2)) == pytest.approx(spread, rel=0.06)


def test_the_nested_covariance_term_matters():
    """Dropping 2 cov(C, D)/N would misstate the SE: here D is anticorrelated with C."""
    rng = np.random.default_rng(3)
    reps, n = 2000, 20
    s = np.zeros(120, dtype=int)
    est, naive, ses = np.empty(reps), np.empty(reps), np.empty(reps)
    for r in range(reps):
        f = 0.03 + 0.01 * rng.standard_normal(120)
        c = 1.3 * f + 0.002 * rng.standard_normal(120)  # coarse overshoots: cov(C, D) < 0
        fine = _prefix(f, s, n)
        e = multilevel_estimate(c, fine, s)
        est[r], ses[r] = e.mean, e.se
        naive[r] = math.hypot(e.coarse_se, e.correction_se)
    spread = est.std(ddof=1)
    assert math.sqrt(np.mean(ses ** 2)) == pytest.approx(spread, rel=0.06)
    assert np.sqrt(np.mean(naive ** 2)) > 1.15 * spread  # the formula without the covariance is off by ~20 %


def test_all_fine_gives_exactly_the_plain_fine_mean_and_se():
    rng = np.random.default_rng(5)
    c, f = _draw(rng)
    e = multilevel_estimate(c, f, STRATA)
    assert e.mean == pytest.approx(np.mean(f), rel=1e-12, abs=1e-15)
    assert e.n_fine == e.n_coarse == 120
    plain = math.sqrt(sum((1 / 3) ** 2 * np.var(f[STRATA == k], ddof=1) / 40 for k in (1, 2, 3)))
    assert e.se == pytest.approx(plain, rel=1e-12) and e.plain_fine_se == pytest.approx(plain, rel=1e-12)
    one = multilevel_estimate(c, f)  # one stratum: the plain std(ddof=1)/sqrt(N)
    assert one.mean == pytest.approx(np.mean(f), rel=1e-12)
    assert one.se == pytest.approx(np.std(f, ddof=1) / math.sqrt(120), rel=1e-12)


def _adaptive(c, f, strata, pilot, factor):
    n, steps = 0, 0
    while True:
        nxt = next_fine_count(c, _prefix(f, strata, n), strata, n, pilot=pilot, se_factor=factor)
        if nxt == n:
            return n, multilevel_estimate(c, _prefix(f, strata, n), strata), steps
        assert nxt > n
        n, steps = nxt, steps + 1


def test_adaptive_count_meets_the_criterion_and_stays_unbiased():
    rng = np.random.default_rng(21)
    reps = 600
    est, counts = np.empty(reps), []
    for r in range(reps):
        c, f = _draw(rng)
        n, e, _ = _adaptive(c, f, STRATA, pilot=9, factor=1.1)
        assert e.n_fine == n
        assert e.meets(1.1) or n == STRATA.size
        assert e.se <= 1.1 * e.plain_fine_se + 1e-15 or n == STRATA.size
        est[r] = e.mean
        counts.append(n)
    assert np.median(counts) < STRATA.size / 2  # the coarse level pays for itself on well-correlated data
    assert abs(est.mean() - _true_mean()) < 4 * est.std(ddof=1) / math.sqrt(reps)


def test_uncorrelated_coarse_level_needs_every_phantom():
    rng = np.random.default_rng(8)
    f = 0.03 + 0.01 * rng.standard_normal(60)
    c = 0.03 + 0.01 * rng.standard_normal(60)  # no information about f
    n, e, _ = _adaptive(c, f, np.zeros(60, dtype=int), pilot=10, factor=1.1)
    assert n > 40
    assert predicted_fine_count(c, f, se_factor=1.1) <= 60


def test_the_pilot_covers_every_stratum_twice_and_bad_input_is_refused():
    s = np.repeat([1, 2], [50, 5])
    c = np.linspace(0, 1, 55)
    first = next_fine_count(c, np.full(55, np.nan), s, 0, pilot=3, se_factor=1.1)
    assert first == min_fine_count(s) and np.sum(s[fine_order(s)[:first]] == 2) >= 2
    with pytest.raises(ValueError, match="at least 2"):
        multilevel_estimate(c, _prefix(c, s, 3), s)
    with pytest.raises(ValueError, match="shape"):
        multilevel_estimate(c, c[:10])
    with pytest.raises(ValueError, match="se_factor"):
        predicted_fine_count(c, c, se_factor=0.9)


def test_gap_to_the_plain_mean_has_the_stated_spread_over_random_subsets():
    # one fixed population of phantoms; the subset is a random nested sample of each stratum (a random phantom
    # order, as the study's seeded phantoms are in random order): the gap's spread over subsets is its SE
    rng = np.random.default_rng(5)
    c, f = _draw(rng)
    gaps, ses = [], []
    for _ in range(3000):
        perm = rng.permutation(STRATA.size)
        sub = np.zeros(STRATA.size, dtype=bool)
        sub[perm[fine_order(STRATA[perm])[:24]]] = True
        gap, se = gap_to_plain(c, f, STRATA, sub)
        gaps.append(gap)
        ses.append(se)
    assert abs(np.mean(gaps)) < 4 * np.std(gaps) / math.sqrt(len(gaps))  # unbiased
    assert np.std(gaps) == pytest.approx(ses[0], rel=0.06)
    assert np.ptp(ses) == 0  # var(D) over whole strata: one value for every subset of one size per stratum
    # the gap is exactly the difference of the two estimates, and vanishes with every phantom fine
    sub = np.zeros(STRATA.size, dtype=bool)
    sub[fine_order(STRATA)[:30]] = True
    gap, _ = gap_to_plain(c, f, STRATA, sub)
    assert gap == pytest.approx(multilevel_estimate(c, np.where(sub, f, np.nan), STRATA).mean - np.mean(
        [f[STRATA == k].mean() for k in (1, 2, 3)]), abs=1e-15)
    assert gap_to_plain(c, f, STRATA, np.ones(STRATA.size, dtype=bool)) == (pytest.approx(0, abs=1e-15), 0.0)
    with pytest.raises(ValueError):
        gap_to_plain(c, np.where(sub, f, np.nan), STRATA, sub)


def test_plain_variance_from_the_coarse_level_is_more_precise_than_from_the_fine_subset():
    # var(F) = var_N(C) + var_n(D) + 2 cov_n(C, D) uses all N coarse values; from the n fine values alone it
    # is as noisy as n phantoms make it. Same data, same subset: compare the spread of the two estimates
    rng = np.random.default_rng(13)
    ours, subset_only = [], []
    for _ in range(1500):
        c, f = _draw(rng)
        sub = _prefix(f, STRATA, 12)
        ours.append(multilevel_estimate(c, sub, STRATA).plain_fine_se)
        has = np.isfinite(sub)
        subset_only.append(math.sqrt(sum((1 / 3) ** 2 * np.var(f[has & (STRATA == k)], ddof=1) / 40
                                         for k in (1, 2, 3))))
    true = math.sqrt(sum((1 / 3) ** 2 * (0.01 * (1 + 0.3 * k)) ** 2 / 40 for k in (1, 2, 3)))
    assert np.mean(ours) == pytest.approx(true, rel=0.03)
    assert np.std(ours) < 0.5 * np.std(subset_only)


def test_a_small_pilot_keeps_precision_and_coverage_on_right_skewed_values():
    # V_rel over random presses is right-skewed (most touches light, a few deep); the default pilot (5 fine
    # phantoms per touch count) with the adaptive rule still gives an error within se_factor of the plain
    # all-fine mean's and mean +- 2 SE covers the truth about as often as it should (benchmarks/multilevel_pilot.py)
    rng = np.random.default_rng(17)
    strata = np.repeat([1, 2, 3], 100)
    base = np.array([0.03, 0.06, 0.09])[strata - 1]
    truth = 0.06
    errors, covered, plain = [], [], []
    for _ in range(600):
        f = base * rng.lognormal(-0.245, 0.7, strata.size)
        c = 0.92 * f + 0.002 + 0.05 * base * rng.standard_normal(strata.size)
        n, e, _ = _adaptive(c, f, strata, pilot=15, factor=1.1)
        errors.append(e.mean - truth)
        covered.append(abs(e.mean - truth) <= 2 * e.se)
        plain.append(multilevel_estimate(c, f, strata).mean - truth)
    assert math.sqrt(np.mean(np.square(errors))) < 1.12 * np.std(plain)
    assert np.mean(covered) > 0.92
