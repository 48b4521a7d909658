"""The sampling plan of the two-level estimator: which phantoms get the fine level, and in what order.

The study's phantoms come ordered by touch count (all single touches first), so the first ``n`` of that sequence
would be single touches only. :func:`fine_order` interleaves the strata (touch counts) in proportion to their
sizes (within a stratum in sequence order), so every prefix is a nested, near-proportional sample of each
stratum; :func:`take_all_mask` picks the phantoms that get the fine level whatever the pilot says, from the coarse
values alone (:mod:`latticeopt.study.multilevel` has the estimate and the stopping rule).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["fine_order", "min_fine_count", "take_all_mask"]


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


def min_fine_count(strata, per_stratum: int = 2, order=None) -> int:
    """Shortest prefix of ``order`` (default :func:`fine_order`) holding ``per_stratum`` phantoms of every stratum
    (or all of one smaller than that)."""
    s = np.asarray(strata)
    order = fine_order(s) if order is None else np.asarray(order, dtype=int)
    need = {k: min(per_stratum, int(np.sum(s == k))) for k in np.unique(s)}
    seen = dict.fromkeys(need, 0)
    for pos, i in enumerate(order):
        seen[s[i]] += 1
        if all(seen[k] >= need[k] for k in need):
            return pos + 1
    return int(s.size)


def take_all_mask(score, strata, share: float) -> np.ndarray:
    """The take-all phantoms: per stratum the ``ceil(share N_k)`` with the largest ``score`` (module docstring).

    Parameters
    ----------
    score : array_like, shape (N,)
        A function of the coarse values only: a design's coarse V_rel, or a phantom's mean rank over several
        designs' (the sweep's choice, common to every design).
    strata : array_like, shape (N,) or None
        Stratum label per phantom.
    share : float
        In ``[0, 1)``; 0 gives no take-all phantom.

    Returns
    -------
    ndarray of bool, shape (N,)
        Ties go to the earlier phantom.
    """
    c = np.asarray(score, dtype=float)
    s = _strata(strata, c.size)
    mask = np.zeros(c.size, dtype=bool)
    if share > 0:
        for k in np.unique(s):
            idx = np.flatnonzero(s == k)
            mask[idx[np.argsort(-c[idx], kind="stable")[:math.ceil(share * idx.size)]]] = True
    return mask
