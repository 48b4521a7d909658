"""The sampling plan of the two-level estimator with depth parts: the split, the order, and the estimate it feeds
(synthetic correlated data, no simulation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from latticeopt.study.multilevel import (
    multilevel_estimate,
    next_fine_count,
    predicted_fine_count,
    take_all_mask,
)
from latticeopt.study.multilevel_check import gap_to_plain
from latticeopt.study.multilevel_plan import MIN_PART, depth_parts, fine_order, sampling_labels, sampling_order

STRATA = np.repeat([1, 2, 3], 60)


def _depth_map(rng, strata=STRATA):
    """Depths uniform in 1-5 mm; the fine value grows with depth; the coarse level overshoots presses deeper than
    3 mm (as a coarse mesh does) and errs 3 times as much on them."""
    depth = rng.uniform(1.0, 5.0, strata.size)
    f = 0.01 * strata + 0.02 * depth + 0.01 * rng.standard_normal(strata.size)
    deep = depth > 3.0
    err = np.where(deep, 0.015, 0.0) + 0.002 * rng.standard_normal(strata.size) * np.where(deep, 3.0, 1.0)
    return depth, 0.9 * f + err, f


def _stratified_prefix(f, strata, parts, n, take_all=None):
    t = np.zeros(f.size, dtype=bool) if take_all is None else take_all
    rest = np.flatnonzero(~t)
    idx = rest[sampling_order(strata[rest], None if parts is None else parts[rest])[:n]]
    out = np.where(t, f, np.nan)
    out[idx] = f[idx]
    return out


def test_depth_parts_split_at_the_depth_and_keep_small_parts_whole():
    strata = np.repeat([1, 2], 30)
    depth = np.r_[np.linspace(0.5, 5.0, 30), np.full(25, 1.0), np.full(5, 4.5)]
    parts = depth_parts(depth, strata, 3.0)
    assert parts[:30].tolist() == (depth[:30] > 3.0).astype(int).tolist()
    assert not parts[30:].any()  # 5 deep phantoms < MIN_PART: touch count 2 stays one part
    assert MIN_PART > 5
    assert not depth_parts(depth, strata, 0.0).any()  # 0: no split
    # take-all phantoms are outside the sampling: with the 15 deepest of touch count 1 taken whole, its sampled
    # deep part is too small to stand alone
    tail = np.zeros(60, dtype=bool)
    tail[15:30] = True
    assert not depth_parts(depth, strata, 3.0, tail)[:30].any()


def test_sampling_labels_refine_the_strata_and_keep_their_order():
    strata = np.array([3, 1, 1, 2, 3, 1])
    assert fine_order(sampling_labels(strata)).tolist() == fine_order(strata).tolist()
    lab = sampling_labels(strata, np.array([1, 0, 1, 0, 0, 1]))
    assert len(set(zip(strata.tolist(), lab.tolist()))) == len(set(lab.tolist())) == 5  # one label per cell
    with pytest.raises(ValueError, match="parts must have shape"):
        sampling_labels(strata, np.zeros(4))


def test_the_order_puts_two_of_each_part_first_then_holds_each_in_proportion():
    rng = np.random.default_rng(1)
    depth, _, _ = _depth_map(rng)
    parts = depth_parts(depth, STRATA, 3.0)
    lab = sampling_labels(STRATA, parts)
    cells = np.unique(lab)
    order = sampling_order(STRATA, parts)
    assert sorted(np.bincount(lab[order[:2 * cells.size]]).tolist()) == [2] * cells.size
    for n in (31, 77, 150):
        for k in cells:
            assert abs(np.sum(lab[order[:n]] == k) - n * np.mean(lab == k)) <= 2.0
    # without parts the order is the touch counts' own, and the pilot holds two of each part
    assert sampling_order(STRATA, None).tolist() == fine_order(STRATA).tolist()
    assert sampling_order(STRATA, 0 * parts).tolist() == fine_order(STRATA).tolist()
    start = next_fine_count(np.zeros(STRATA.size), np.full(STRATA.size, np.nan), STRATA, 0, pilot=2,
                            se_factor=1.1, parts=parts)
    assert start == 2 * cells.size


def test_one_part_is_the_estimator_without_parts():
    rng = np.random.default_rng(2)
    depth, c, f = _depth_map(rng)
    tail = take_all_mask(c, STRATA, 0.05)
    fine = _stratified_prefix(f, STRATA, None, 40, tail)
    zero = np.zeros(STRATA.size, dtype=int)
    assert multilevel_estimate(c, fine, STRATA, tail, parts=zero) == multilevel_estimate(c, fine, STRATA, tail)
    assert predicted_fine_count(c, fine, STRATA, take_all=tail, parts=zero) == predicted_fine_count(
        c, fine, STRATA, take_all=tail)


def test_parts_with_every_phantom_fine_give_the_plain_fine_mean_and_se():
    rng = np.random.default_rng(3)
    depth, c, f = _depth_map(rng)
    tail = take_all_mask(c, STRATA, 0.05)
    parts = depth_parts(depth, STRATA, 3.0, tail)
    assert parts.any()
    e, plain = multilevel_estimate(c, f, STRATA, tail, parts=parts), multilevel_estimate(c, f, STRATA)
    # plain: the stratified mean and SE of F itself (every stratum the same size)
    want_se = math.sqrt(sum(np.var(f[STRATA == k], ddof=1) / 60 for k in (1, 2, 3)) / 9)
    assert e.mean == pytest.approx(np.mean(f), rel=1e-12)
    assert plain.se == pytest.approx(want_se, rel=1e-12)
    assert e.se == pytest.approx(want_se, rel=1e-10) and e.plain_fine_se == pytest.approx(want_se, rel=1e-10)


def test_parts_need_two_pairs_each():
    rng = np.random.default_rng(4)
    depth, c, f = _depth_map(rng)
    parts = depth_parts(depth, STRATA, 3.0)
    fine = np.full(STRATA.size, np.nan)
    idx = np.flatnonzero((STRATA == 1) & (parts == 0))[:3]
    fine[idx] = f[idx]
    fine[STRATA > 1] = f[STRATA > 1]
    fine[np.flatnonzero((STRATA == 1) & (parts == 1))[0]] = f[np.flatnonzero((STRATA == 1) & (parts == 1))[0]]
    with pytest.raises(ValueError, match="stratum 1, part 1: 1 phantoms with both levels"):
        multilevel_estimate(c, fine, STRATA, parts=parts)


def test_depth_parts_are_unbiased_calibrated_and_tighter_at_a_fixed_count():
    # the same prefix length, sampled and estimated with and without the depth split: both unbiased with stated
    # SEs matching their spread over repetitions, and the split's gap to the plain (all-fine) mean smaller (the
    # corrections' between-part spread leaves the sampling error), with the SE gap_to_plain states
    rng = np.random.default_rng(5)
    est = {"one": [], "depth": []}
    off = {"one": [], "depth": []}
    sub = {"one": [], "depth": []}
    ses = {"one": [], "depth": []}
    gaps, gap_ses = [], []
    truth = []
    for _ in range(1500):
        depth, c, f = _depth_map(rng)
        parts = depth_parts(depth, STRATA, 3.0)
        truth.append(np.mean(f))
        for name, p in (("one", None), ("depth", parts)):
            fine = _stratified_prefix(f, STRATA, p, 30)
            e = multilevel_estimate(c, fine, STRATA, parts=p)
            est[name].append(e.mean)
            ses[name].append(e.se)
            off[name].append(e.mean - np.mean(f))
            sub[name].append(e.se ** 2 - e.plain_fine_se ** 2)  # the stated variance of the sampled correction
            if p is not None:
                gap, se = gap_to_plain(c, f, STRATA, np.isfinite(fine), parts=p)
                gaps.append(gap)
                gap_ses.append(se)
    mu = 0.01 * 2 + 0.02 * 3.0  # E[F]: 0.01 x the mean touch count + 0.02 x the mean depth
    for name in est:
        x = np.array(est[name])
        assert abs(x.mean() - mu) < 4 * x.std() / math.sqrt(x.size)
        assert math.sqrt(np.mean(np.square(ses[name]))) == pytest.approx(x.std(), rel=0.08)
    for name in off:  # the sampled correction's stated variance is its spread about the all-fine mean
        assert math.sqrt(np.mean(sub[name])) == pytest.approx(np.std(off[name]), rel=0.1), name
    assert np.std(off["depth"]) < 0.8 * np.std(off["one"])
    assert math.sqrt(np.mean(np.square(gap_ses))) == pytest.approx(np.std(gaps), rel=0.08)


def test_the_stopping_rule_with_depth_parts_needs_fewer_fine_phantoms_for_the_same_precision():
    rng = np.random.default_rng(6)
    count = {"one": [], "depth": []}
    err = {"one": [], "depth": []}
    plain = []
    for _ in range(200):
        depth, c, f = _depth_map(rng)
        plain.append(np.mean(f))
        for name, p in (("one", None), ("depth", depth_parts(depth, STRATA, 3.0))):
            n = 0
            while True:
                fine = _stratified_prefix(f, STRATA, p, n)
                nxt = next_fine_count(c, fine, STRATA, n, pilot=15, se_factor=1.1, parts=p)
                if nxt == n:
                    break
                n = nxt
            count[name].append(n)
            err[name].append(multilevel_estimate(c, fine, STRATA, parts=p).mean)
    sd = np.std(plain)
    for name in err:  # error against the true mean within about se_factor of the plain mean's
        rms = math.sqrt(np.mean(np.square(np.array(err[name]) - 0.08))) / sd
        assert rms < 1.25, (name, rms)
    assert np.mean(count["depth"]) < 0.8 * np.mean(count["one"])
