"""Checking a two-level estimate against a map that was also run fine on every phantom.

Pure statistics over arrays, for validation runs (``benchmarks/validate_multilevel.py``): how far the two-level
estimate from a nested fine subset lies from the plain all-fine mean, and how far it should.
"""

from __future__ import annotations

import math

import numpy as np

from .multilevel import multilevel_estimate
from .multilevel_plan import _strata, sampling_labels

__all__ = ["gap_to_plain"]


def gap_to_plain(coarse, fine, strata, subset, take_all=None, parts=None) -> tuple[float, float]:
    """How far the two-level estimate on ``subset`` lies from the plain fine mean, and the SE of that gap.

    For validating the estimator when every phantom has been run fine as well. Over common phantoms the gap is
    ``mu - mean_N(F) = sum_k w_k (mean_{n_k}(D) - mean_{N_k}(D))`` with ``D = F - C``: the subset's mean
    correction against the full one. For a nested simple random subset its variance is
    ``sum_k w_k^2 var_k(D) (1 / n_k - 1 / N_k)`` (finite-population sampling of the ``N_k`` values of ``D``;
    with ``parts``, ``k`` runs over every stratum's parts), estimated here with ``var_k(D)`` over the whole
    stratum. So the gap's SE is much smaller than the two-level SE, which also carries the sampling error of the
    ``N`` phantoms themselves, shared with the plain mean.

    Parameters
    ----------
    coarse, fine : array_like, shape (N,)
        Both levels on every phantom (finite).
    strata : array_like, shape (N,) or None
        Stratum label per phantom.
    subset : array_like of bool, shape (N,)
        The phantoms the two-level estimate has fine.
    take_all : array_like of bool, shape (N,), optional
        Its take-all phantoms (fine in the estimate whatever ``subset`` says; no sampling error).
    parts : array_like of int, shape (N,), optional
        Its sampling parts within the strata (:func:`multilevel_estimate`).

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
    t = np.zeros(c.size, dtype=bool) if take_all is None else np.asarray(take_all, dtype=bool)
    part = multilevel_estimate(c, np.where(sub | t, f, np.nan), s, take_all=t, parts=parts).mean
    full = multilevel_estimate(c, f, s).mean
    d = f - c
    var = 0.0
    lab = sampling_labels(s, parts)
    for k in np.unique(lab):
        sel = (lab == k) & ~t  # the take-all phantoms are all in, and add nothing
        big, n = int(sel.sum()), int((sel & sub).sum())
        if big > 1:
            var += (big / c.size) ** 2 * float(np.var(d[sel], ddof=1)) * (1.0 / n - 1.0 / big)
    return part - full, math.sqrt(max(var, 0.0))
