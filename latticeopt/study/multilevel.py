"""Two-level (control-variate) estimate of a design's fine-mesh mean V_rel from a coarse run over every phantom.

Pure statistics over arrays: no simulation, no store. The sweep that feeds it is :mod:`.multilevel_sweep`.

Every phantom ``i = 0..N-1`` is evaluated on the coarse mesh (``C_i``); a nested subset of them is evaluated on
the fine mesh as well (``F_i``). Per stratum (touch count) the estimate of the fine mean is the control-variate
(regression) estimate with coefficient ``beta``,

    mu = mean_n(F) - beta (mean_n(C) - mean_N(C)) = beta mean_N(C) + mean_n(G),   G = F - beta C,

weighted by the strata's shares of the ``N`` phantoms. ``beta = 1`` (``control = "fixed"``) is
``mean_N(C) + mean_n(D)`` with ``D = F - C``. Because ``C`` over the ``n`` phantoms with both levels is part of
``mean_N(C)``, the two terms are correlated: ``Cov(mean_N(C), mean_n(G)) = cov(C, G) / N`` for a nested subset, so
for a fixed ``beta``

    Var(mu) = beta^2 var(C) / N + var(G) / n + 2 beta cov(C, G) / N = var(F) / N + var(G) (1 / n - 1 / N),

using ``beta^2 var(C) + 2 beta cov(C, G) = var(F) - var(G)``. The second form shows what the coarse level buys:
the fine variance is paid at ``N`` and only the variance of ``G`` at ``n``. The plain fine estimate over all
``N`` phantoms has variance ``var(F) / N``; so ``se / se_plain = sqrt(1 + var(G) / var(F) (N / n - 1))``.
Only ``var(G)`` depends on ``beta``; it is smallest at ``beta = cov(F, C) / var(C)``, where
``var(G) = var(F) (1 - rho^2)``; ``beta = 1`` gives ``var(D)``, larger unless the coarse level's errors are
uncorrelated with its values.

``control = "fitted"``: one ``beta`` per design, the one that minimizes the estimated variance,
``beta = sum_k a_k cov_k(F, C) / sum_k a_k var_k(C)`` with ``a_k = w_k^2 (1 / n_k - 1 / N_k)`` (the weight
``var_k(G)`` has in ``Var(mu)``; about ``w_k`` for a proportional subset), both moments within each stratum
(centred on the stratum's means) and over its pairs. Pooled, not per stratum: a pilot of 15 has 5 pairs per
touch count, too few for a slope when a single tail pair can decide it; the coarse mesh's error is a property of
the design and mesh more than of the touch count. ``var(C)`` over the pairs, not all ``N`` coarse values: then
``beta - cov/var`` depends only on the pairs' residuals (the regression estimator of two-phase sampling), whereas
``cov_n / var_N`` also carries the ratio ``var_n(C) / var_N(C)``, which under a heavy tail moves by a large
factor with whether a tail phantom is among the pairs. With fewer than 2 residual degrees of freedom
(``n - K < 2`` over ``K`` strata) or no spread of ``C`` among the weighted pairs, ``beta = 1``. A fitted ``beta``
is chosen to make the sample ``var(G)`` small; the estimate multiplies it by ``(n - K) / (n - K - 1)`` (one
degree of freedom spent on the slope), and the variance formula above then holds to first order. Its bias is
``O(1 / n)``: with ``e = F - mu_F - beta (C - mu_C)`` for the population ``beta``,

    E[mu] - mu_F = -(1 / n - 1 / N) E[(C - mu_C)^2 e] / var(C) + O(n^-2),

(``-(1 - n / N) cov(beta_hat, mean_n(C))``; exact for normal ``C``), zero when the residual is unrelated to the
size of the coarse deviation, against an SE of order ``1 / sqrt(n)``; checked by Monte Carlo in the tests
and in ``benchmarks/multilevel_control.py``.

Assumptions: within a stratum the phantoms are independent draws from one distribution (true of
:class:`~.phantoms.RandomPhantoms`: one seeded stream per phantom); which phantoms get the fine level is fixed
before their values are known (:func:`fine_order`, a prefix of one order common to all designs), so the fine
subset is a simple random sample of its stratum; ``var(G)`` is estimated (``ddof = 1``) from the phantoms that
have both levels, at least two per stratum, and ``var(F)`` (whatever ``beta``) as
``var_N(C) + var_n(D) + 2 cov_n(C, D)``: the coarse variance from all ``N`` phantoms, the rest from the ``n``
pairs (on the pairs alone the three terms sum to ``var_n(F)``). With ``F`` and ``C`` strongly correlated,
``var(F)`` is then about as precise as from ``N`` fine phantoms instead of ``n`` (the plain SE a pilot of 9
estimated from its own fine values was about half the true one). The standard error is then the usual plug-in
one (exact for known variances and a fixed ``beta``). Choosing ``n`` from the measured variances
(:func:`next_fine_count`, the same ``var(G)`` as the estimate) uses only variances, not means; the bias that
adaptive stopping can introduce is second order and checked by Monte Carlo in the tests.

Strata: the study's phantoms come ordered by touch count (all single touches first), so the first ``n`` of that
sequence would be single touches only. :func:`fine_order` interleaves the strata in proportion to their sizes
(within a stratum in sequence order), so every prefix is a nested, near-proportional sample of each stratum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["CONTROLS", "MultilevelEstimate", "fine_order", "gap_to_plain", "min_fine_count", "multilevel_estimate",
           "next_fine_count", "predicted_fine_count"]

#: The control-variate coefficient: ``"fixed"`` (``beta = 1``) or ``"fitted"`` per design (module docstring).
CONTROLS = ("fixed", "fitted")


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
        ``mu = beta mean_N(C) + mean_n(F - beta C)`` (stratified) and its standard error.
    coarse_mean, coarse_se
        Mean of the coarse level over all ``N`` phantoms and its SE (``sqrt(var(C) / N)``, stratified).
    correction_mean, correction_se
        ``mean - coarse_mean`` (with ``beta = 1`` the mean of ``F - C`` over the fine subset) and the SE of
        ``mean_n(F - beta C)``, ``sqrt(var(F - beta C) / n)`` (stratified).
    n_fine, n_coarse
        Phantoms with both levels (``n``) and with the coarse level (``N``).
    plain_fine_se
        Estimated SE of the plain fine mean over all ``N`` phantoms, ``sqrt(var(F) / N)`` (stratified), with
        ``var(F) = var_N(C) + var_n(D) + 2 cov_n(C, D)`` (module docstring): what :attr:`se` is compared with.
    beta
        The control-variate coefficient used: 1 (``control = "fixed"``) or the fitted one.
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
    beta: float = 1.0

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


def _split(coarse, fine, strata):
    """Per stratum ``(share, coarse values, fine values of the pairs, coarse values of the pairs)``."""
    c = np.asarray(coarse, dtype=float)
    f = np.asarray(fine, dtype=float)
    if c.ndim != 1 or f.shape != c.shape:
        raise ValueError(f"coarse and fine must be 1-D of one shape, got {c.shape} and {f.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("every phantom needs a finite coarse value")
    s = _strata(strata, c.size)
    parts = []
    for k in np.unique(s):
        ck, fk = c[s == k], f[s == k]
        has = np.isfinite(fk)
        n = int(has.sum())
        if n < 2 and n < ck.size or n == 0:
            raise ValueError(f"stratum {k}: {n} phantoms with both levels; at least 2 are needed (or all of it)")
        parts.append((ck.size / c.size, ck, fk[has], ck[has]))
    return parts


def _fitted_beta(parts) -> tuple[float, float]:
    """The pooled coefficient and the factor on ``var(G)`` for the degree of freedom it spends (docstring)."""
    num = den = 0.0
    dof = -1
    for w, ck, fp, cp in parts:
        if fp.size > 1:
            a = w * w * (1.0 / fp.size - 1.0 / ck.size)
            num += a * float(np.cov(fp, cp)[0, 1])
            den += a * float(np.var(cp, ddof=1))
            dof += fp.size - 1
    if dof < 1 or not den > 0:
        return 1.0, 1.0
    return num / den, (dof + 1) / dof


def _per_stratum(coarse, fine, strata, control: str = "fixed"):
    if control not in CONTROLS:
        raise ValueError(f"control must be one of {', '.join(CONTROLS)}, got {control!r}")
    parts = _split(coarse, fine, strata)
    beta, inflate = _fitted_beta(parts) if control == "fitted" else (1.0, 1.0)
    rows = []
    for w, ck, fp, cp in parts:
        n = fp.size
        g = fp - beta * cp  # with beta = 1 exactly F - C
        var_g = float(np.var(g, ddof=1)) * inflate if n > 1 else 0.0
        var_c_sub = float(np.var(cp, ddof=1)) if n > 1 else 0.0
        # var(F) = var(C) + var(D) + 2 cov(C, D): the D terms from the n pairs, var(C) from all N phantoms. On
        # the subset the same three terms add up to the sample var(F) exactly, so this is var_n(F) corrected by
        # how far the subset's coarse variance is from the whole stratum's (exact when n = N)
        var_f = float(np.var(fp, ddof=1)) + float(np.var(ck, ddof=1)) - var_c_sub if n > 1 else 0.0
        rows.append((w, ck.size, n, float(ck.mean()), float(g.mean()), max(var_f, 0.0), var_g, var_c_sub))
    return rows, beta


def multilevel_estimate(coarse, fine, strata=None, *, control: str = "fixed") -> MultilevelEstimate:
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
    control : {"fixed", "fitted"}
        ``beta = 1`` or ``beta`` fitted from the pairs (module docstring).

    Returns
    -------
    MultilevelEstimate
        With every phantom fine (``n = N``) ``mean`` is the plain fine mean (per stratum
        ``beta mean(C) + mean(F - beta C) = mean(F)``; exactly with ``beta = 1``) and ``se`` the plain fine SE.
    """
    rows, beta = _per_stratum(coarse, fine, strata, control)
    mean = coarse_mean = corr = var = var_c = var_g = var_plain = 0.0
    for w, n_c, n_f, c_mean, g_mean, var_f, v_g, v_c in rows:
        coarse_mean += w * c_mean
        corr += w * (g_mean + (beta - 1.0) * c_mean)  # adds exactly 0 with beta = 1
        # var(F)/N + var(G)(1/n - 1/N), per stratum, weights squared
        var += w * w * (var_f / n_c + v_g * (1.0 / n_f - 1.0 / n_c))
        var_c += w * w * v_c / n_c
        var_g += w * w * v_g / n_f
        var_plain += w * w * var_f / n_c
    mean = coarse_mean + corr
    return MultilevelEstimate(mean=mean, se=math.sqrt(max(var, 0.0)), coarse_mean=coarse_mean,
                              coarse_se=math.sqrt(var_c), correction_mean=corr, correction_se=math.sqrt(var_g),
                              n_fine=sum(r[2] for r in rows), n_coarse=sum(r[1] for r in rows),
                              plain_fine_se=math.sqrt(var_plain), beta=beta)


def predicted_fine_count(coarse, fine, strata=None, *, se_factor: float = 1.1, control: str = "fixed") -> float:
    """Fine phantoms needed for ``se <= se_factor * plain_fine_se``, from the variances measured so far.

    With proportional allocation (``n_k = w_k n``) ``Var(mu) = A + B / n`` with ``B = sum_k w_k var_k(G)``
    (``var(G)`` as :func:`multilevel_estimate` uses it, with the current ``beta``); solving
    ``A + B / n = se_factor^2 var_plain`` gives ``n = B / ((se_factor^2 - 1) var_plain + B / N)``, at most ``N``.

    Parameters
    ----------
    coarse, fine, strata, control
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
    rows, _ = _per_stratum(coarse, fine, strata, control)
    n_total = sum(r[1] for r in rows)
    b = sum(w * v_g for w, _, _, _, _, _, v_g, _ in rows)
    var_plain = sum(w * w * var_f / n_c for w, n_c, _, _, _, var_f, _, _ in rows)
    denom = (se_factor ** 2 - 1.0) * var_plain + b / n_total
    return float(n_total) if denom <= 0 else min(float(n_total), b / denom)


def next_fine_count(coarse, fine, strata, n: int, *, pilot: int, se_factor: float, control: str = "fixed") -> int:
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
    control : {"fixed", "fitted"}
        The estimate's ``beta`` (:func:`multilevel_estimate`); the criterion and the prediction use its variance.

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
    if n >= c.size or multilevel_estimate(c, fine, s, control=control).meets(se_factor):
        return int(min(n, c.size))
    want = math.ceil(predicted_fine_count(c, fine, s, se_factor=se_factor, control=control))
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
