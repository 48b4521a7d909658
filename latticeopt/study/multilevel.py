"""Two-level (control-variate) estimate of a design's fine-mesh mean V_rel from a coarse run over every phantom.

Pure statistics over arrays: no simulation, no store. The sweep that feeds it is :mod:`.multilevel_sweep`.

Every phantom ``i = 0..N-1`` is evaluated on the coarse mesh (``C_i``); a nested subset of them is evaluated on
the fine mesh as well (``F_i``). With ``D = F - C``, the estimate of the fine mean is

    mu = mean_N(C) + mean_n(D),

per stratum (touch count) and weighted by the strata's shares of the ``N`` phantoms. Because ``C`` over the ``n``
phantoms with both levels is part of ``mean_N(C)``, the two terms are correlated:
``Cov(mean_N(C), mean_n(D)) = cov(C, D) / N`` for a nested subset, so

    Var(mu) = var(C) / N + var(D) / n + 2 cov(C, D) / N = var(F) / N + var(D) (1 / n - 1 / N),

using ``var(C) + 2 cov(C, D) = var(F) - var(D)``. The second form shows what the coarse level buys: the fine
variance is paid at ``N`` and only the variance of the correction at ``n``. The plain fine estimate over all
``N`` phantoms has variance ``var(F) / N``; so ``se / se_plain = sqrt(1 + var(D) / var(F) (N / n - 1))``.

Assumptions: within a stratum the phantoms are independent draws from one distribution (true of
:class:`~.phantoms.RandomPhantoms`: one seeded stream per phantom); which phantoms get the fine level is fixed
before their values are known (:func:`fine_order`, a prefix of one order common to all designs), so the fine
subset is a simple random sample of its stratum; ``var(D)`` is estimated (``ddof = 1``) from the phantoms that
have both levels, at least two per stratum, and ``var(F)`` as ``var_N(C) + var_n(D) + 2 cov_n(C, D)``: the
coarse variance from all ``N`` phantoms, the rest from the ``n`` pairs (on the pairs alone the three terms sum to
``var_n(F)``). With ``F`` and ``C`` strongly correlated, ``var(F)`` is then about as precise as from ``N`` fine
phantoms instead of ``n`` (the plain SE a pilot of 9 estimated from its own fine values was about half the true
one). The standard error is then the usual plug-in one (exact for known variances). Choosing ``n`` from the
measured variances (:func:`next_fine_count`) uses only variances, not means; the bias that adaptive stopping can
introduce is second order and checked by Monte Carlo in the tests.

Strata: the study's phantoms come ordered by touch count (all single touches first), so the first ``n`` of that
sequence would be single touches only. :func:`fine_order` interleaves the strata in proportion to their sizes
(within a stratum in sequence order), so every prefix is a nested, near-proportional sample of each stratum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MultilevelEstimate", "fine_order", "gap_to_plain", "min_fine_count", "multilevel_estimate",
           "next_fine_count", "predicted_fine_count"]


def _strata(strata, size: int) -> np.ndarray:
    s = np.zeros(size, dtype=int) if strata is None else np.asarray(strata)
    if s.shape != (size,):
        raise ValueError(f"strata must have shape ({size},), got {s.shape}")
    return s


def fine_order(strata) -> np.ndarray:
    """The order in which phantoms get the fine level: strata interleaved in proportion to their sizes.

    Parameters
    ----------
    strata : array_like, shape (N,)
        Stratum label of every phantom (e.g. its touch count), in sequence order.

    Returns
    -------
    ndarray of int, shape (N,)
        A permutation of ``0..N-1``. Phantom ``r`` of a stratum of ``N_k`` (``r``-th in sequence order) gets the
        key ``(r + 0.5) / N_k``; sorting by key (ties by stratum label) makes every prefix of length ``n`` hold
        within one of ``n N_k / N`` phantoms of each stratum, the first ones of the stratum: prefixes are nested.
    """
    s = np.asarray(strata)
    keys = np.empty(s.size)
    for k in np.unique(s):
        idx = np.flatnonzero(s == k)
        keys[idx] = (np.arange(idx.size) + 0.5) / idx.size
    return np.lexsort((np.arange(s.size), s, keys))


def min_fine_count(strata, per_stratum: int = 2) -> int:
    """Shortest prefix of :func:`fine_order` holding ``per_stratum`` phantoms of every stratum (or all of one
    smaller than that)."""
    s = np.asarray(strata)
    order = fine_order(s)
    need = {k: min(per_stratum, int(np.sum(s == k))) for k in np.unique(s)}
    seen = dict.fromkeys(need, 0)
    for pos, i in enumerate(order):
        seen[s[i]] += 1
        if all(seen[k] >= need[k] for k in need):
            return pos + 1
    return int(s.size)


@dataclass(frozen=True)
class MultilevelEstimate:
    """The two-level estimate of one design (V_rel is dimensionless; every SE is a standard error of a mean).

    Attributes
    ----------
    mean, se
        ``mu = mean_N(C) + mean_n(F - C)`` (stratified) and its standard error.
    coarse_mean, coarse_se
        Mean of the coarse level over all ``N`` phantoms and its SE (``sqrt(var(C) / N)``, stratified).
    correction_mean, correction_se
        Mean of ``F - C`` over the fine subset and its SE (``sqrt(var(D) / n)``, stratified).
    n_fine, n_coarse
        Phantoms with both levels (``n``) and with the coarse level (``N``).
    plain_fine_se
        Estimated SE of the plain fine mean over all ``N`` phantoms, ``sqrt(var(F) / N)`` (stratified), with
        ``var(F) = var_N(C) + var_n(D) + 2 cov_n(C, D)`` (module docstring): what :attr:`se` is compared with.
    """

    mean: float
    se: float
    coarse_mean: float
    coarse_se: float
    correction_mean: float
    correction_se: float
    n_fine: int
    n_coarse: int
    plain_fine_se: float

    def __post_init__(self) -> None:
        if not 0 < self.n_fine <= self.n_coarse:
            raise ValueError(f"need 0 < n_fine <= n_coarse, got {self.n_fine}, {self.n_coarse}")

    @property
    def se_ratio(self) -> float:
        """``se / plain_fine_se`` (1: as good as running every phantom fine)."""
        return self.se / self.plain_fine_se if self.plain_fine_se > 0 else math.nan

    def meets(self, se_factor: float) -> bool:
        """Whether ``se <= se_factor * plain_fine_se`` (the criterion :func:`next_fine_count` stops at)."""
        return bool(self.se <= se_factor * self.plain_fine_se)


def _per_stratum(coarse, fine, strata):
    c = np.asarray(coarse, dtype=float)
    f = np.asarray(fine, dtype=float)
    if c.ndim != 1 or f.shape != c.shape:
        raise ValueError(f"coarse and fine must be 1-D of one shape, got {c.shape} and {f.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("every phantom needs a finite coarse value")
    s = _strata(strata, c.size)
    rows = []
    for k in np.unique(s):
        ck, fk = c[s == k], f[s == k]
        has = np.isfinite(fk)
        n = int(has.sum())
        if n < 2 and n < ck.size or n == 0:
            raise ValueError(f"stratum {k}: {n} phantoms with both levels; at least 2 are needed (or all of it)")
        d = fk[has] - ck[has]
        var_d = float(np.var(d, ddof=1)) if n > 1 else 0.0
        var_c_sub = float(np.var(ck[has], ddof=1)) if n > 1 else 0.0
        # var(F) = var(C) + var(D) + 2 cov(C, D): the D terms from the n pairs, var(C) from all N phantoms. On
        # the subset the same three terms add up to the sample var(F) exactly, so this is var_n(F) corrected by
        # how far the subset's coarse variance is from the whole stratum's (exact when n = N)
        var_f = float(np.var(fk[has], ddof=1)) + float(np.var(ck, ddof=1)) - var_c_sub if n > 1 else 0.0
        rows.append((ck.size / c.size, ck.size, n, float(ck.mean()), float(d.mean()), max(var_f, 0.0), var_d,
                     var_c_sub))
    return rows


def multilevel_estimate(coarse, fine, strata=None) -> MultilevelEstimate:
    """The two-level estimate of the fine mean and its standard error (module docstring).

    Parameters
    ----------
    coarse : array_like, shape (N,)
        Coarse-level V_rel of every phantom (finite).
    fine : array_like, shape (N,)
        Fine-level V_rel, NaN where the phantom has no fine value. The fine phantoms must have been chosen
        independently of the values (a prefix of :func:`fine_order`), at least 2 per stratum (or the whole
        stratum).
    strata : array_like, shape (N,), optional
        Stratum label per phantom (touch count); ``None``: one stratum.

    Returns
    -------
    MultilevelEstimate
        With every phantom fine (``n = N``) ``mean`` is exactly the plain fine mean (per stratum
        ``mean(C) + mean(F - C) = mean(F)``) and ``se`` the plain fine SE.
    """
    rows = _per_stratum(coarse, fine, strata)
    mean = coarse_mean = corr = var = var_c = var_d = var_plain = 0.0
    for w, n_c, n_f, c_mean, d_mean, var_f, v_d, v_c in rows:
        coarse_mean += w * c_mean
        corr += w * d_mean
        # var(F)/N + var(D)(1/n - 1/N), per stratum, weights squared
        var += w * w * (var_f / n_c + v_d * (1.0 / n_f - 1.0 / n_c))
        var_c += w * w * v_c / n_c
        var_d += w * w * v_d / n_f
        var_plain += w * w * var_f / n_c
    mean = coarse_mean + corr
    return MultilevelEstimate(mean=mean, se=math.sqrt(max(var, 0.0)), coarse_mean=coarse_mean,
                              coarse_se=math.sqrt(var_c), correction_mean=corr, correction_se=math.sqrt(var_d),
                              n_fine=sum(r[2] for r in rows), n_coarse=sum(r[1] for r in rows),
                              plain_fine_se=math.sqrt(var_plain))


def predicted_fine_count(coarse, fine, strata=None, *, se_factor: float = 1.1) -> float:
    """Fine phantoms needed for ``se <= se_factor * plain_fine_se``, from the variances measured so far.

    With proportional allocation (``n_k = w_k n``) ``Var(mu) = A + B / n`` with ``B = sum_k w_k var_k(D)``;
    solving ``A + B / n = se_factor^2 var_plain`` gives ``n = B / ((se_factor^2 - 1) var_plain + B / N)``, at
    most ``N``.

    Parameters
    ----------
    coarse, fine, strata
        As in :func:`multilevel_estimate`.
    se_factor : float
        Allowed ratio of the two-level SE to the plain fine SE, >= 1.

    Returns
    -------
    float
        The predicted ``n`` (not rounded), in ``[0, N]``.
    """
    if not se_factor >= 1:
        raise ValueError(f"se_factor must be >= 1, got {se_factor}")
    rows = _per_stratum(coarse, fine, strata)
    n_total = sum(r[1] for r in rows)
    b = sum(w * v_d for w, _, _, _, _, _, v_d, _ in rows)
    var_plain = sum(w * w * var_f / n_c for w, n_c, _, _, _, var_f, _, _ in rows)
    denom = (se_factor ** 2 - 1.0) * var_plain + b / n_total
    return float(n_total) if denom <= 0 else min(float(n_total), b / denom)


def next_fine_count(coarse, fine, strata, n: int, *, pilot: int, se_factor: float) -> int:
    """How many phantoms (a prefix of :func:`fine_order`) should have the fine level next.

    Parameters
    ----------
    coarse : array_like, shape (N,)
        Coarse V_rel of every phantom.
    fine : array_like, shape (N,)
        Fine V_rel of the first ``n`` phantoms of :func:`fine_order` (``strata``), NaN elsewhere.
    strata : array_like, shape (N,) or None
        Stratum label per phantom.
    n : int
        The current prefix length (0 before the pilot).
    pilot : int
        First prefix length; raised to :func:`min_fine_count` so every stratum has two fine phantoms.
    se_factor : float
        The criterion ``se <= se_factor * plain_fine_se``.

    Returns
    -------
    int
        ``n`` itself when the criterion holds or ``n = N`` (done); otherwise a larger prefix: the predicted
        count (:func:`predicted_fine_count`), at least ``n + max(1, n // 4)`` and at most ``2 n`` per step,
        so a noisy variance estimate from few phantoms cannot jump to ``N`` at once.
    """
    c = np.asarray(coarse, dtype=float)
    s = _strata(strata, c.size)
    start = min(c.size, max(int(pilot), min_fine_count(s)))
    if n < start:
        return start
    if n >= c.size or multilevel_estimate(c, fine, s).meets(se_factor):
        return int(min(n, c.size))
    want = math.ceil(predicted_fine_count(c, fine, s, se_factor=se_factor))
    return int(min(c.size, max(n + max(1, n // 4), min(2 * n, want))))


def gap_to_plain(coarse, fine, strata, subset) -> tuple[float, float]:
    """How far the two-level estimate on ``subset`` lies from the plain fine mean, and the SE of that gap.

    For validating the estimator when every phantom has been run fine as well. Over common phantoms the gap is
    ``mu - mean_N(F) = sum_k w_k (mean_{n_k}(D) - mean_{N_k}(D))`` with ``D = F - C``: the subset's mean
    correction against the full one. For a nested simple random subset its variance is
    ``sum_k w_k^2 var_k(D) (1 / n_k - 1 / N_k)`` (finite-population sampling of the ``N_k`` values of ``D``),
    estimated here with ``var_k(D)`` over the whole stratum. So the gap's SE is much smaller than the two-level
    SE, which also carries the sampling error of the ``N`` phantoms themselves, shared with the plain mean.

    Parameters
    ----------
    coarse, fine : array_like, shape (N,)
        Both levels on every phantom (finite).
    strata : array_like, shape (N,) or None
        Stratum label per phantom.
    subset : array_like of bool, shape (N,)
        The phantoms the two-level estimate has fine.

    Returns
    -------
    gap, se : float
        ``multilevel_estimate(coarse, fine on subset) .mean - multilevel_estimate(coarse, fine).mean`` and its SE.
    """
    c = np.asarray(coarse, dtype=float)
    f = np.asarray(fine, dtype=float)
    sub = np.asarray(subset, dtype=bool)
    if f.shape != c.shape or sub.shape != c.shape or not np.all(np.isfinite(f)):
        raise ValueError("coarse, fine and subset must have one shape, with every fine value finite")
    s = _strata(strata, c.size)
    part = multilevel_estimate(c, np.where(sub, f, np.nan), s).mean
    full = multilevel_estimate(c, f, s).mean
    d = f - c
    var = 0.0
    for k in np.unique(s):
        sel = s == k
        big, n = int(sel.sum()), int((sel & sub).sum())
        if big > 1:
            var += (big / c.size) ** 2 * float(np.var(d[sel], ddof=1)) * (1.0 / n - 1.0 / big)
    return part - full, math.sqrt(max(var, 0.0))
