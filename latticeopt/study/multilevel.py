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

Take-all phantoms: ``D = F - C`` can have a rare heavy tail (deep presses on which the coarse mesh overshoots);
a pilot of a few phantoms per stratum then misses it most of the time, the rule stops there, and the estimate is
biased. Phantoms chosen from the coarse values alone (the largest: :func:`take_all_mask`) can all be run fine: a
take-all part of their stratum (two-phase sampling for stratification). A stratum's estimate is then
``beta mean_N(C) + sum_h a_h mean_{n_h}(G)`` over its parts ``h`` (shares ``a_h = N_h / N_k``; the take-all part
with ``n_h = N_h``, exact), with variance ``var(F) / N_k + sum_h a_h^2 var_h(G) (1 / n_h - 1 / N_h)``, and
``var(F)`` takes ``var(D)`` and ``cov(C, D)`` within the parts plus between their means, weighted as the
``ddof = 1`` variance of the ``N_k`` values splits. The choice depends on ``C`` only and the other phantoms keep
their value-blind order, so the estimate stays unbiased; without take-all phantoms every formula is the one above.

Depth parts: the corrections of deep presses vary several times as much as those of shallow ones, so each
stratum's sampled phantoms can be split into parts fixed by the phantoms alone (:func:`depth_parts`: the deepest
touch beyond a depth), sampled in proportion (every prefix of :func:`sampling_order` holds within one of its share
of each part, beyond the two of each part it puts first) and estimated each on its own, exactly as the take-all
part is: the correction term becomes ``sum_h a_h mean_{n_h}(G)`` over the parts and its variance
``sum_h a_h^2 var_h(G) (1 / n_h - 1 / N_h)``, which drops the between-parts spread of ``G`` that a single part
pays. The plain SE the criterion compares with is the same ``var(F) / N`` by touch count (the parts only change
how ``var(F)`` is pieced together). With proportional allocation over the parts the variance never exceeds the
single part's to first order, and the stopping rule predicts the count with every part's ``var(G)``
(:func:`predicted_fine_count`).

Which phantoms get the fine level, in what order, and the take-all choice: :mod:`.multilevel_plan`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .multilevel_plan import (
    _strata,
    depth_parts,
    fine_order,
    min_fine_count,
    sampling_labels,
    sampling_order,
    take_all_mask,
)

__all__ = ["CONTROLS", "MultilevelEstimate", "depth_parts", "fine_order", "min_fine_count",
           "multilevel_estimate", "next_fine_count", "predicted_fine_count", "sampling_labels", "sampling_order",
           "take_all_mask"]

#: The control-variate coefficient: ``"fixed"`` (``beta = 1``) or ``"fitted"`` per design (module docstring).
CONTROLS = ("fixed", "fitted")


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


def _split(coarse, fine, strata, take_all=None, parts=None):
    """Per stratum ``(share of N, coarse values, parts)``, the parts (take-all phantoms, then one per sampling part)
    each ``(share of the stratum, coarse values, fine values of the pairs, coarse values of the pairs, take-all)``."""
    c = np.asarray(coarse, dtype=float)
    f = np.asarray(fine, dtype=float)
    if c.ndim != 1 or f.shape != c.shape:
        raise ValueError(f"coarse and fine must be 1-D of one shape, got {c.shape} and {f.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("every phantom needs a finite coarse value")
    s = _strata(strata, c.size)
    t = np.zeros(c.size, dtype=bool) if take_all is None else np.asarray(take_all, dtype=bool)
    if t.shape != c.shape:
        raise ValueError(f"take_all must have shape {c.shape}, got {t.shape}")
    p = np.zeros(c.size, dtype=int) if parts is None else np.asarray(parts)
    if p.shape != c.shape:
        raise ValueError(f"parts must have shape {c.shape}, got {p.shape}")
    strata_parts = []
    for k in np.unique(s):
        ck, fk, tk, pk = c[s == k], f[s == k], t[s == k], p[s == k]
        parts_k = []
        for sel, whole, h in [(tk, True, None)] + [(~tk & (pk == h), False, h) for h in np.unique(pk[~tk])]:
            has = np.isfinite(fk[sel])
            n = int(has.sum())
            if whole and n < sel.sum():
                raise ValueError(f"stratum {k}: every take-all phantom needs the fine level")
            if not whole and sel.any() and (n < 2 and n < sel.sum() or n == 0):
                where = f"stratum {k}" + (f", part {h}" if parts is not None else "")
                raise ValueError(f"{where}: {n} phantoms with both levels; at least 2 are needed (or all of it)")
            if sel.any():
                parts_k.append((sel.sum() / ck.size, ck[sel], fk[sel][has], ck[sel][has], whole))
        strata_parts.append((ck.size / c.size, ck, parts_k))
    return strata_parts


def _fitted_beta(strata_parts) -> tuple[float, float]:
    """The pooled coefficient and the factor on ``var(G)`` for the degree of freedom it spends (docstring)."""
    num = den = 0.0
    dof = -1
    for w, _, parts in strata_parts:
        for a, ch, fp, cp, _ in parts:
            if fp.size > 1:
                wt = (w * a) ** 2 * (1.0 / fp.size - 1.0 / ch.size)  # 0 for take-all parts
                num += wt * float(np.cov(fp, cp)[0, 1])
                den += wt * float(np.var(cp, ddof=1))
                dof += fp.size - 1
    if dof < 1 or not den > 0:
        return 1.0, 1.0
    return num / den, (dof + 1) / dof


def _var(x: np.ndarray) -> float:
    return float(np.var(x, ddof=1)) if x.size > 1 else 0.0


@dataclass(frozen=True)
class _Stratum:
    """One stratum's terms (module docstring): ``var_f`` the estimated ``var(F)`` over its phantoms, ``var_sub``
    the variance of its sampled correction, ``var_corr`` ``sum a^2 var(G) / n`` over its parts, and per sampled
    part its ``share``, size and ``var(G)`` (what more fine phantoms would shrink)."""

    w: float
    n_coarse: int
    n_fine: int
    c_mean: float
    g_mean: float
    var_c: float
    var_f: float
    var_sub: float
    var_corr: float
    sampled: tuple[tuple[float, int, float], ...]


def _per_stratum(coarse, fine, strata, control: str = "fixed", take_all=None, parts=None):
    if control not in CONTROLS:
        raise ValueError(f"control must be one of {', '.join(CONTROLS)}, got {control!r}")
    strata_parts = _split(coarse, fine, strata, take_all, parts)
    beta, inflate = _fitted_beta(strata_parts) if control == "fitted" else (1.0, 1.0)
    rows = []
    for w, ck, parts in strata_parts:
        d_mean = sum(a * float(np.mean(fp - cp)) for a, _, fp, cp, _ in parts)
        # var(F) = var(C) + var(D) + 2 cov(C, D): var(C) from all N phantoms, the D terms from the pairs of each
        # part, within the parts plus between their means, weighted as the (ddof = 1) variance of the stratum's
        # N_k values splits (one part: the pairs' sample moments; every phantom fine: the sample moments)
        var_d = cov_cd = 0.0
        dof = max(ck.size - 1, 1)
        for _, ch, fp, cp, _ in parts:
            d = fp - cp
            within, between = (ch.size - 1) / dof, ch.size / dof * (len(parts) > 1)
            var_d += within * _var(d) + between * (float(d.mean()) - d_mean) ** 2
            cov_cd += (within * (float(np.cov(cp, d)[0, 1]) if d.size > 1 else 0.0)
                       + between * (float(ch.mean()) - float(ck.mean())) * (float(d.mean()) - d_mean))
        n_pairs = sum(fp.size for _, _, fp, _, _ in parts)
        var_f = _var(ck) + var_d + 2.0 * cov_cd if n_pairs > 1 else 0.0
        g_mean = var_sub = var_corr = 0.0
        sampled = []
        for a, ch, fp, cp, whole in parts:
            g = fp - beta * cp  # with beta = 1 exactly F - C
            var_g = _var(g) * inflate
            g_mean += a * float(g.mean())
            var_sub += a * a * var_g * (1.0 / fp.size - 1.0 / ch.size)
            var_corr += a * a * var_g / fp.size
            if not whole:
                sampled.append((a, ch.size, var_g))
        rows.append(_Stratum(w, ck.size, n_pairs, float(ck.mean()), g_mean,
                             _var(ck), max(var_f, 0.0), var_sub, var_corr, tuple(sampled)))
    return rows, beta


def multilevel_estimate(coarse, fine, strata=None, take_all=None, *, control: str = "fixed",
                        parts=None) -> MultilevelEstimate:
    """The two-level estimate of the fine mean and its standard error (module docstring).

    Parameters
    ----------
    coarse : array_like, shape (N,)
        Coarse-level V_rel of every phantom (finite).
    fine : array_like, shape (N,)
        Fine-level V_rel, NaN where the phantom has no fine value. The fine phantoms must have been chosen
        independently of the values (a prefix of :func:`fine_order`), at least 2 per stratum (or the whole
        stratum), besides the take-all phantoms.
    strata : array_like, shape (N,), optional
        Stratum label per phantom (touch count); ``None``: one stratum.
    control : {"fixed", "fitted"}
        ``beta = 1`` or ``beta`` fitted from the pairs (module docstring).
    take_all : array_like of bool, shape (N,), optional
        Phantoms that all have the fine level, chosen from the coarse values alone (:func:`take_all_mask`).
    parts : array_like of int, shape (N,), optional
        Sampling part of each phantom within its stratum, chosen from the phantoms alone (:func:`depth_parts`;
        the take-all phantoms' entries are ignored): each part is estimated on its own, as a stratum of the
        sampling, while the plain SE stays stratified by ``strata``. Each part needs 2 pairs (or all of it).
        ``None``: one part per stratum.

    Returns
    -------
    MultilevelEstimate
        With every phantom fine (``n = N``) ``mean`` is the plain fine mean (per stratum
        ``beta mean(C) + mean(F - beta C) = mean(F)``; exactly with ``beta = 1``) and ``se`` the plain fine SE.
    """
    rows, beta = _per_stratum(coarse, fine, strata, control, take_all, parts)
    coarse_mean = corr = var = var_c = var_g = var_plain = 0.0
    for r in rows:
        coarse_mean += r.w * r.c_mean
        corr += r.w * (r.g_mean + (beta - 1.0) * r.c_mean)  # adds exactly 0 with beta = 1
        # var(F)/N + the sampled correction's variance, per stratum, weights squared
        var += r.w * r.w * (r.var_f / r.n_coarse + r.var_sub)
        var_c += r.w * r.w * r.var_c / r.n_coarse
        var_g += r.w * r.w * r.var_corr
        var_plain += r.w * r.w * r.var_f / r.n_coarse
    return MultilevelEstimate(mean=coarse_mean + corr, se=math.sqrt(max(var, 0.0)), coarse_mean=coarse_mean,
                              coarse_se=math.sqrt(var_c), correction_mean=corr, correction_se=math.sqrt(var_g),
                              n_fine=sum(r.n_fine for r in rows), n_coarse=sum(r.n_coarse for r in rows),
                              plain_fine_se=math.sqrt(var_plain), beta=beta)


def predicted_fine_count(coarse, fine, strata=None, *, se_factor: float = 1.1, control: str = "fixed",
                         take_all=None, parts=None) -> float:
    """Sampled fine phantoms needed for ``se <= se_factor * plain_fine_se``, from the variances measured so far.

    Over the ``M`` phantoms that are not take-all, sampled in proportion to the strata's parts (``m_k = m M_k /
    M``, ``k`` running over every stratum's sampling parts), the sampled corrections add
    ``sum_k u_k^2 var_k(G) (1 / m_k - 1 / M_k) = S (M / m - 1)`` to ``var_plain``, with
    ``u_k`` a part's share of all ``N`` phantoms and ``S = sum_k u_k^2 var_k(G) / M_k`` (``var(G)`` as
    :func:`multilevel_estimate` uses it, with the current ``beta``). Solving ``var_plain + S (M / m - 1) =
    se_factor^2 var_plain`` gives ``m = M S / (S + (se_factor^2 - 1) var_plain)``, at most ``M``; without
    take-all phantoms ``M = N`` and this is ``n = B / ((se_factor^2 - 1) var_plain + B / N)``,
    ``B = sum_k w_k var_k(G)``.

    Parameters
    ----------
    coarse, fine, strata, control, take_all, parts
        As in :func:`multilevel_estimate`.
    se_factor : float
        Allowed ratio of the two-level SE to the plain fine SE, >= 1.

    Returns
    -------
    float
        The predicted ``m`` (not rounded), in ``[0, M]``: fine phantoms besides the take-all ones.
    """
    if not se_factor >= 1:
        raise ValueError(f"se_factor must be >= 1, got {se_factor}")
    rows, _ = _per_stratum(coarse, fine, strata, control, take_all, parts)
    m_total = sum(size for r in rows for _, size, _ in r.sampled)
    s_term = sum((r.w * a) ** 2 * var_g / size for r in rows for a, size, var_g in r.sampled if size)
    var_plain = sum(r.w * r.w * r.var_f / r.n_coarse for r in rows)
    denom = s_term + (se_factor ** 2 - 1.0) * var_plain
    return float(m_total) if denom <= 0 else min(float(m_total), m_total * s_term / denom)


def next_fine_count(coarse, fine, strata, n: int, *, pilot: int, se_factor: float, control: str = "fixed",
                    take_all=None, order=None, min_growth: float = 0.0, parts=None) -> int:
    """How many sampled phantoms (a prefix of ``order``) should have the fine level next, besides the take-all
    ones.

    Parameters
    ----------
    coarse : array_like, shape (N,)
        Coarse V_rel of every phantom.
    fine : array_like, shape (N,)
        Fine V_rel of the take-all phantoms and the first ``n`` of ``order``, NaN elsewhere.
    strata : array_like, shape (N,) or None
        Stratum label per phantom.
    n : int
        The current prefix length (0 before the pilot).
    pilot : int
        First prefix length; raised so every stratum (every part of one) has two sampled fine phantoms.
    se_factor : float
        The criterion ``se <= se_factor * plain_fine_se``.
    control : {"fixed", "fitted"}
        The estimate's ``beta`` (:func:`multilevel_estimate`); the criterion and the prediction use its variance.
    take_all : array_like of bool, shape (N,), optional
        The take-all phantoms (:func:`take_all_mask`), all with the fine level.
    order : array_like of int, optional
        Positions of the other phantoms in the order they get the fine level; default :func:`sampling_order` of
        their strata and parts.
    min_growth : float
        The smallest step as a share of ``n``, in ``[0, 1]``. 0 (default) steps to the predicted count however
        close it is; steps of at least a quarter (0.25) ran 12 % more sampled fine phantoms on the paper map for
        the same criterion (``benchmarks/multilevel_pilot.py --min-growth`` compares them on synthetic maps).
    parts : array_like of int, shape (N,), optional
        Sampling parts within the strata (:func:`multilevel_estimate`); ``order`` should interleave them.

    Returns
    -------
    int
        ``n`` itself when the criterion holds or ``n = M`` (done); otherwise a larger prefix: the predicted
        count (:func:`predicted_fine_count`), at least ``n + max(1, floor(min_growth n))`` and at most ``2 n`` per
        step, so a noisy variance estimate from few phantoms cannot jump to ``M`` at once.
    """
    if not 0 <= min_growth <= 1:
        raise ValueError(f"min_growth must be in [0, 1], got {min_growth}")
    c = np.asarray(coarse, dtype=float)
    s = _strata(strata, c.size)
    lab = sampling_labels(s, parts)
    rest = np.flatnonzero(~np.asarray(take_all, dtype=bool)) if take_all is not None else np.arange(c.size)
    order = rest[sampling_order(s[rest], None if parts is None else np.asarray(parts)[rest])] if order is None \
        else np.asarray(order, dtype=int)
    m_total = order.size
    start = min(m_total, max(int(pilot), min_fine_count(lab[order], order=np.arange(m_total))))
    if n < start:
        return start
    est = dict(control=control, take_all=take_all, parts=parts)
    if n >= m_total or multilevel_estimate(c, fine, s, **est).meets(se_factor):
        return int(min(n, m_total))
    want = math.ceil(predicted_fine_count(c, fine, s, se_factor=se_factor, **est))
    return int(min(m_total, max(n + max(1, math.floor(min_growth * n)), min(2 * n, want))))
