"""The two-level estimator's statistics on synthetic correlated data (no simulation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from latticeopt.study.multilevel import (
    fine_order,
    min_fine_count,
    multilevel_estimate,
    next_fine_count,
    predicted_fine_count,
    take_all_mask,
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


def _adaptive(c, f, strata, pilot, factor, min_growth=0.0):
    n, steps = 0, 0
    while True:
        nxt = next_fine_count(c, _prefix(f, strata, n), strata, n, pilot=pilot, se_factor=factor,
                              min_growth=min_growth)
        if nxt == n:
            return n, multilevel_estimate(c, _prefix(f, strata, n), strata), steps
        assert nxt > n
        assert nxt >= n + max(1, math.floor(min_growth * n)) or nxt == strata.size
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


def test_stepping_to_the_predicted_count_needs_fewer_phantoms_for_the_same_precision():
    # the rule steps to the count the variances predict; a minimum step of a quarter of the prefix overshoots
    # it. On maps whose coarse level follows the fine one loosely (counts of 60-200 of 300) the predicted steps
    # stop earlier on average while the error stays within se_factor of the plain all-fine mean's and the
    # coverage of +-2 SE holds (benchmarks/multilevel_pilot.py --noise 0.3 --min-growth 0.25 0)
    rng = np.random.default_rng(29)
    strata = np.repeat([1, 2, 3], 100)
    base = np.array([0.03, 0.06, 0.09])[strata - 1]
    counts = {0.0: [], 0.25: []}
    errors, covered, plain = [], [], []
    for _ in range(250):
        f = base * rng.lognormal(-0.245, 0.7, strata.size)
        c = 0.92 * f + 0.002 + 0.3 * base * rng.standard_normal(strata.size)
        plain.append(multilevel_estimate(c, f, strata).mean - 0.06)
        for growth, ns in counts.items():
            n, e, _ = _adaptive(c, f, strata, pilot=15, factor=1.1, min_growth=growth)
            ns.append(n)
            if growth == 0.0:
                assert e.meets(1.1) or n == strata.size
                errors.append(e.mean - 0.06)
                covered.append(abs(e.mean - 0.06) <= 2 * e.se)
    assert np.mean(counts[0.0]) < 0.97 * np.mean(counts[0.25])
    assert math.sqrt(np.mean(np.square(errors))) < 1.15 * np.std(plain)
    assert np.mean(covered) > 0.92
    with pytest.raises(ValueError, match="min_growth"):
        next_fine_count(c, _prefix(f, strata, 30), strata, 30, pilot=15, se_factor=1.1, min_growth=-0.1)


# -- the control-variate coefficient (control = "fixed" / "fitted") ------------------------------------------

def _old_rows(c, f, s):
    """The estimator before ``control`` and take-all strata existed (beta = 1), as it was but for the coarse SE,
    which now reads the variance of all N coarse values (its documented definition) instead of the pairs'."""
    rows = []
    for k in np.unique(s):
        ck, fk = c[s == k], f[s == k]
        has = np.isfinite(fk)
        n = int(has.sum())
        d = fk[has] - ck[has]
        var_d = float(np.var(d, ddof=1)) if n > 1 else 0.0
        var_c_sub = float(np.var(ck[has], ddof=1)) if n > 1 else 0.0
        var_f = float(np.var(fk[has], ddof=1)) + float(np.var(ck, ddof=1)) - var_c_sub if n > 1 else 0.0
        rows.append((ck.size / c.size, ck.size, n, float(ck.mean()), float(d.mean()), max(var_f, 0.0), var_d,
                     float(np.var(ck, ddof=1))))
    return rows


def _old_estimate(c, f, s):
    coarse_mean = corr = var = var_c = var_d = var_plain = 0.0
    rows = _old_rows(c, f, s)
    for w, n_c, n_f, c_mean, d_mean, var_f, v_d, v_c in rows:
        coarse_mean += w * c_mean
        corr += w * d_mean
        var += w * w * (var_f / n_c + v_d * (1.0 / n_f - 1.0 / n_c))
        var_c += w * w * v_c / n_c
        var_d += w * w * v_d / n_f
        var_plain += w * w * var_f / n_c
    return (coarse_mean + corr, math.sqrt(max(var, 0.0)), coarse_mean, math.sqrt(var_c), corr, math.sqrt(var_d),
            sum(r[2] for r in rows), sum(r[1] for r in rows), math.sqrt(var_plain))


def _old_predicted(c, f, s, se_factor):
    rows = _old_rows(c, f, s)
    n_total = sum(r[1] for r in rows)
    b = sum(w * v_d for w, _, _, _, _, _, v_d, _ in rows)
    var_plain = sum(w * w * var_f / n_c for w, n_c, _, _, _, var_f, _, _ in rows)
    denom = (se_factor ** 2 - 1.0) * var_plain + b / n_total
    return float(n_total) if denom <= 0 else min(float(n_total), b / denom)


def test_control_fixed_without_take_all_is_the_estimator_before_either_existed():
    rng = np.random.default_rng(123)
    fields = ("mean", "se", "coarse_mean", "coarse_se", "correction_mean", "correction_se", "n_fine", "n_coarse",
              "plain_fine_se")
    for r in range(150):
        k = int(rng.integers(1, 4))
        s = np.repeat(np.arange(1, k + 1), rng.integers(5, 60, k))
        f = rng.lognormal(-3, 0.7, s.size)
        c = 0.9 * f + 0.01 * rng.standard_normal(s.size)
        c[rng.random(s.size) < 0.05 * (r % 2)] *= 3  # a heavy tail on every other map
        n = int(rng.integers(min_fine_count(s), s.size + 1))
        fine = _prefix(f, s, n)
        e = multilevel_estimate(c, fine, s, control="fixed")
        # the same sums in another arrangement (var(F) from D's moments, not F's): equal to rounding
        assert tuple(getattr(e, x) for x in fields) == pytest.approx(_old_estimate(c, fine, s), rel=1e-10, abs=1e-15)
        assert e.beta == 1.0 and e == multilevel_estimate(c, fine, s)  # and the default is "fixed"
        assert predicted_fine_count(c, fine, s, se_factor=1.1, control="fixed") == pytest.approx(
            _old_predicted(c, fine, s, 1.1), rel=1e-10)
        old_next = n if n == s.size or _old_estimate(c, fine, s)[1] <= 1.1 * _old_estimate(c, fine, s)[8] else \
            min(s.size, max(n + max(1, n // 4), min(2 * n, math.ceil(_old_predicted(c, fine, s, 1.1)))))
        assert next_fine_count(c, fine, s, n, pilot=2, se_factor=1.1, min_growth=0.25) == old_next


def test_fitted_beta_recovers_cov_over_var_of_the_pairs():
    rng = np.random.default_rng(2)
    s = np.repeat([1, 2, 3], [40, 60, 50])
    c = rng.lognormal(-3, 0.5, s.size)
    exact = np.array([0.01, -0.02, 0.03])[s - 1] + 0.7 * c  # exactly linear, its own intercept per stratum
    fine = _prefix(exact, s, 45)
    assert multilevel_estimate(c, fine, s, control="fitted").beta == pytest.approx(0.7, rel=1e-12)
    noisy = 0.7 * c + 0.01 * rng.standard_normal(s.size)  # one stratum: the pairs' sample cov / var
    fine = _prefix(noisy, np.zeros(s.size, dtype=int), 30)
    has = np.isfinite(fine)
    want = np.cov(fine[has], c[has])[0, 1] / np.var(c[has], ddof=1)
    assert multilevel_estimate(c, fine, control="fitted").beta == pytest.approx(want, rel=1e-12)
    assert abs(want - 0.7) > 1e-3  # the noise moved it: the pairs' own moments are used, not the truth
    # several strata with their own slopes: pooled with the weights w_k^2 (1/n_k - 1/N_k) of var_k(G) in Var(mu)
    slopes = np.array([0.5, 1.0, 1.5])[s - 1]
    fine = _prefix(slopes * c + 0.005 * rng.standard_normal(s.size), s, 45)
    num = den = 0.0
    for k in (1, 2, 3):
        sel = (s == k) & np.isfinite(fine)
        a = (np.sum(s == k) / s.size) ** 2 * (1 / sel.sum() - 1 / np.sum(s == k))
        num += a * np.cov(fine[sel], c[sel])[0, 1]
        den += a * np.var(c[sel], ddof=1)
    assert multilevel_estimate(c, fine, s, control="fitted").beta == pytest.approx(num / den, rel=1e-12)
    # too few pairs for a slope and a variance (n - K < 2): beta = 1
    two = _prefix(noisy, np.zeros(s.size, dtype=int), 2)
    assert multilevel_estimate(c, two, control="fitted") == multilevel_estimate(c, two)
    with pytest.raises(ValueError, match="control must be one of fixed, fitted, got 'best'"):
        multilevel_estimate(c, fine, s, control="best")


def test_variance_formula_for_a_fitted_beta_matches_the_monte_carlo_spread():
    # F = 0.5 C + e: the population beta is 0.5, far from 1. Var(mu) = var(F)/N + var(F - 0.5 C)(1/n - 1/N)
    # with population variances; the fitted estimate's spread must match it (its extra variance is O(1/n^2))
    # and not the beta = 1 value var(F)/N + var(F - C)(1/n - 1/N), 2.4 times as large here
    rng = np.random.default_rng(31)
    big, n, reps = 300, 60, 3000
    sd_c, sd_e = 0.02, 0.004
    var_f, var_g, var_d = 0.25 * sd_c ** 2 + sd_e ** 2, sd_e ** 2, 0.25 * sd_c ** 2 + sd_e ** 2
    theory = math.sqrt(var_f / big + var_g * (1 / n - 1 / big))
    at_one = math.sqrt(var_f / big + var_d * (1 / n - 1 / big))
    assert at_one > 1.5 * theory
    est, ses = np.empty(reps), np.empty(reps)
    one = np.zeros(big, dtype=int)
    for r in range(reps):
        c = 0.05 + sd_c * rng.standard_normal(big)
        f = 0.5 * c + sd_e * rng.standard_normal(big)
        e = multilevel_estimate(c, _prefix(f, one, n), control="fitted")
        est[r], ses[r] = e.mean, e.se
    assert est.std(ddof=1) == pytest.approx(theory, rel=0.05)  # the SD of an SD from 3000 draws: 1.3 %
    assert math.sqrt(np.mean(ses ** 2)) == pytest.approx(theory, rel=0.05)
    assert abs(est.mean() - 0.025) < 4 * theory / math.sqrt(reps)


def test_bias_of_a_fitted_beta_is_the_stated_order_one_over_n_term():
    # C normal, e = a ((C - mu)^2 - var C) + noise: E[(C - mu)^2 e] = 2 a var(C)^2, so the module docstring's
    # bias -(1/n - 1/N) E[(C - mu)^2 e] / var(C) is -(1/n - 1/N) 2 a var(C) (exact for normal C). The fixed
    # control on the same maps is unbiased, which shows the bias is the fitted beta's, not the data's
    rng = np.random.default_rng(41)
    big, n, reps, a = 300, 10, 4000, 0.5
    one = np.zeros(big, dtype=int)
    fitted, fixed = np.empty(reps), np.empty(reps)
    for r in range(reps):
        c = rng.standard_normal(big)
        f = c + a * (c ** 2 - 1) + 0.3 * rng.standard_normal(big)  # true mean 0, population beta 1
        fine = _prefix(f, one, n)
        fitted[r] = multilevel_estimate(c, fine, control="fitted").mean
        fixed[r] = multilevel_estimate(c, fine, control="fixed").mean
    bias = -(1 / n - 1 / big) * 2 * a
    mc_se = fitted.std(ddof=1) / math.sqrt(reps)
    assert abs(bias) > 15 * mc_se  # large enough to be seen
    assert abs(fitted.mean() - bias) < 4 * mc_se
    assert abs(fixed.mean()) < 4 * fixed.std(ddof=1) / math.sqrt(reps)


def test_fitted_coverage_of_two_se_at_a_fixed_count():
    # 2000 maps, three touch counts, 10 fine phantoms each, beta 0.6. The binomial SD of a coverage near 0.954
    # from 2000 maps is 0.0047, so [0.93, 0.975] is about 5 SD either side of the nominal value (the plug-in SE
    # from 10 pairs per stratum costs well under 1 % of coverage); an SE 1.5 times too small would cover 0.82
    # and fail, which is what the plain fine SE (the SE if every phantom were fine) is here: checked too
    rng = np.random.default_rng(51)
    reps, n = 2000, 30
    hit, hit_plain, ratios = [], [], []
    for _ in range(reps):
        c, _ = _draw(rng)  # E[C] = 0.9 mu_k - 0.003 per stratum; so E[F] = mu_k, the truth
        mu = np.array([TRUE_MEANS[k] for k in STRATA])
        f = mu + 0.6 * (c - (0.9 * mu - 0.003)) + 0.006 * rng.standard_normal(STRATA.size)
        e = multilevel_estimate(c, _prefix(f, STRATA, n), STRATA, control="fitted")
        hit.append(abs(e.mean - _true_mean()) <= 2 * e.se)
        hit_plain.append(abs(e.mean - _true_mean()) <= 2 * e.plain_fine_se)
        ratios.append(e.se_ratio)
    assert 0.93 <= np.mean(hit) <= 0.975
    assert np.mean(ratios) > 1.3 and np.mean(hit_plain) < 0.88


def test_the_fine_count_rule_stops_exactly_when_the_controls_estimate_meets_the_criterion():
    rng = np.random.default_rng(61)
    disagree = 0
    for _ in range(300):
        c, f = _draw(rng, noise=0.004)
        f = f + 0.4 * (c - 0.9 * f)  # coarse errors correlated with the values: beta away from 1
        n = int(rng.integers(min_fine_count(STRATA), 60))
        fine = _prefix(f, STRATA, n)
        stops = {}
        for control in ("fixed", "fitted"):
            e = multilevel_estimate(c, fine, STRATA, control=control)
            nxt = next_fine_count(c, fine, STRATA, n, pilot=2, se_factor=1.1, control=control)
            assert (nxt == n) == e.meets(1.1)
            stops[control] = nxt == n
        disagree += stops["fixed"] != stops["fitted"]
    assert disagree >= 5  # the two controls' variances differ enough to matter: the check is not vacuous


# -- take-all phantoms (the largest coarse values always fine) -------------------------------------------------

def _tail_map(rng, strata, over=0.03):
    """Right-skewed fine values; the coarse level reads ``3 F`` on a few of the top fifth (deep presses)."""
    base = np.array([0.03, 0.06, 0.09])[strata - 1]
    f = base * rng.lognormal(-0.245, 0.7, strata.size)
    c = 0.92 * f + 0.002 + 0.05 * base * rng.standard_normal(strata.size)
    top = f > base * np.exp(-0.245 + 0.7 * 0.8416)
    return np.where(top & (rng.random(strata.size) < over / 0.2), 3.0 * f, c), f


def _adaptive_take_all(c, f, strata, share, pilot=15, factor=1.1):
    tail = take_all_mask(c, strata, share)
    rest = np.flatnonzero(~tail)
    order = rest[fine_order(strata[rest])]
    n = 0
    while True:
        fine = np.where(tail, f, np.nan)
        fine[order[:n]] = f[order[:n]]
        nxt = next_fine_count(c, fine, strata, n, pilot=pilot, se_factor=factor, take_all=tail)
        if nxt == n:
            return n + int(tail.sum()), multilevel_estimate(c, fine, strata, take_all=tail)
        n = nxt


def test_take_all_mask_holds_each_strata_largest_coarse_values():
    c = np.array([5.0, 1.0, 4.0, 2.0, 3.0, 9.0, 8.0, 7.0, 6.0, 0.0])
    s = np.array([1, 1, 1, 1, 1, 2, 2, 2, 2, 2])
    assert np.flatnonzero(take_all_mask(c, s, 0.3)).tolist() == [0, 2, 5, 6]  # ceil(0.3 * 5) = 2 per stratum
    assert not take_all_mask(c, s, 0.0).any()
    assert take_all_mask(c, None, 0.1).tolist() == [False] * 5 + [True] + [False] * 4


def test_take_all_with_every_phantom_fine_is_the_plain_fine_mean_and_se():
    rng = np.random.default_rng(4)
    strata = np.repeat([1, 2, 3], 50)
    c, f = _tail_map(rng, strata)
    tail = take_all_mask(c, strata, 0.1)
    e, plain = multilevel_estimate(c, f, strata, take_all=tail), multilevel_estimate(c, f, strata)
    assert e.mean == pytest.approx(np.mean(f), rel=1e-12)
    assert e.se == pytest.approx(plain.se, rel=1e-10) and e.plain_fine_se == pytest.approx(plain.se, rel=1e-10)


def test_take_all_is_unbiased_and_its_se_matches_the_spread_at_a_fixed_count():
    # the tail stratum is chosen from the coarse values, the rest sampled: the estimate stays unbiased and its
    # stated SE (phase 1 over the touch counts, phase 2 over the parts) matches the spread over repetitions
    rng = np.random.default_rng(9)
    strata = np.repeat([1, 2, 3], 60)
    est, ses, plain = [], [], []
    for _ in range(1500):
        c, f = _tail_map(rng, strata, over=0.04)
        tail = take_all_mask(c, strata, 0.05)
        rest = np.flatnonzero(~tail)
        idx = rest[fine_order(strata[rest])[:24]]
        fine = np.where(tail, f, np.nan)
        fine[idx] = f[idx]
        e = multilevel_estimate(c, fine, strata, take_all=tail)
        est.append(e.mean)
        ses.append(e.se)
        plain.append(np.mean(f))
    est, truth = np.array(est), 0.06
    assert abs(est.mean() - truth) < 4 * est.std() / math.sqrt(est.size)
    assert math.sqrt(np.mean(np.square(ses))) == pytest.approx(est.std(), rel=0.08)


def test_take_all_keeps_the_stopping_rule_honest_under_a_heavy_tail():
    # a pilot of 15 misses a 3 % coarse-level tail most of the time and stops there, biased; with the largest
    # 5 % of coarse values taken fine the error stays near se_factor times the plain SE, with fewer fine phantoms
    # (benchmarks/multilevel_control.py has the full table)
    rng = np.random.default_rng(11)
    strata = np.repeat([1, 2, 3], 100)
    err = {0.0: [], 0.05: []}
    count = {0.0: [], 0.05: []}
    plain = []
    for _ in range(300):
        c, f = _tail_map(rng, strata)
        plain.append(np.mean(f) - 0.06)
        for share in err:
            n, e = _adaptive_take_all(c, f, strata, share)
            err[share].append(e.mean - 0.06)
            count[share].append(n)
    sd = np.std(plain)
    rms = {k: math.sqrt(np.mean(np.square(v))) / sd for k, v in err.items()}
    assert rms[0.0] > 1.5 and rms[0.05] < 1.2
    assert np.mean(count[0.05]) < np.mean(count[0.0])
