"""The sampling plan of the two-level estimator: which phantoms get the fine level, and in what order.

The study's phantoms come ordered by touch count (all single touches first), so the first ``n`` of that sequence
would be single touches only. :func:`fine_order` interleaves the strata (touch counts) in proportion to their
sizes (within a stratum in sequence order), so every prefix is a nested, near-proportional sample of each
stratum; :func:`take_all_mask` picks the phantoms that get the fine level whatever the pilot says, from the coarse
values alone; :func:`depth_parts` splits the other phantoms of each stratum into shallow and deep sampling parts
(:mod:`latticeopt.study.multilevel` has the estimate and the stopping rule).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MIN_PART", "depth_parts", "fine_order", "min_fine_count", "sampling_labels", "sampling_order",
           "take_all_mask"]

#: Fewest phantoms a depth part may hold: a stratum whose shallow or deep sampled phantoms are fewer stays whole
#: (a part needs two pairs for its variance, so a smaller one would be sampled far above its share).
MIN_PART = 10


def _strata(strata, size: int) -> np.ndarray:
    s = np.zeros(size, dtype=int) if strata is None else np.asarray(strata)
    if s.shape != (size,):
        raise ValueError(f"strata must have shape ({size},), got {s.shape}")
    return s


def sampling_labels(strata, parts=None) -> np.ndarray:
    """One label per (stratum, part) pair, ranked as the strata are (parts ``None``: the strata's own ranks)."""
    s = np.asarray(strata)
    p = np.zeros(s.size, dtype=int) if parts is None else np.asarray(parts)
    if p.shape != s.shape:
        raise ValueError(f"parts must have shape {s.shape}, got {p.shape}")
    return np.unique(np.stack([np.unique(s, return_inverse=True)[1].ravel(), p]), axis=1,
                     return_inverse=True)[1].ravel()


def depth_parts(deepest_mm, strata, split_mm: float, take_all=None) -> np.ndarray:
    """Sampling parts by depth: 1 for a phantom whose deepest touch presses beyond ``split_mm``, else 0.

    The fine-minus-coarse corrections of deep presses vary several times as much as those of shallow ones, so
    estimating each part on its own (and sampling both in proportion, :func:`sampling_order`) needs fewer fine
    phantoms for the same SE than one part would. The split uses the phantoms alone, never their values, so the
    estimate stays unbiased.

    Parameters
    ----------
    deepest_mm : array_like, shape (N,)
        Depth of each phantom's deepest touch (mm).
    strata : array_like, shape (N,) or None
        Stratum label per phantom (touch count).
    split_mm : float
        The depth beyond which a press is deep (mm); 0 gives one part (all 0).
    take_all : array_like of bool, shape (N,), optional
        The take-all phantoms: outside the sampling, so they count towards neither part's size.

    Returns
    -------
    ndarray of int, shape (N,)
        0 or 1; all 0 in a stratum whose shallow or deep sampled phantoms number fewer than :data:`MIN_PART`.
    """
    d = np.asarray(deepest_mm, dtype=float)
    s = _strata(strata, d.size)
    t = np.zeros(d.size, dtype=bool) if take_all is None else np.asarray(take_all, dtype=bool)
    deep = (d > split_mm) if split_mm > 0 else np.zeros(d.size, dtype=bool)
    for k in np.unique(s):
        sel = (s == k) & ~t
        if min(int(np.sum(deep[sel])), int(np.sum(~deep[sel]))) < MIN_PART:
            deep[s == k] = False
    return deep.astype(int)


def fine_order(strata, first: int = 0) -> np.ndarray:
    """The order in which phantoms get the fine level: strata interleaved in proportion to their sizes.

    Parameters
    ----------
    strata : array_like, shape (N,)
        Stratum label of every phantom (e.g. its touch count), in sequence order.
    first : int
        Phantoms of every stratum put before all others (the first of each stratum, then the second, ...): so
        that a short prefix already holds the two pairs a small stratum needs (:func:`sampling_order`).

    Returns
    -------
    ndarray of int, shape (N,)
        A permutation of ``0..N-1``. Phantom ``r`` of a stratum of ``N_k`` (``r``-th in sequence order) gets the
        key ``(r + 0.5) / N_k`` (``r - first`` for ``r < first``); sorting by key (ties by stratum label) makes
        every prefix of length ``n`` hold within one of ``n N_k / N`` phantoms of each stratum (beyond the
        ``first`` of each), the first ones of the stratum: prefixes are nested.
    """
    s = np.asarray(strata)
    keys = np.empty(s.size)
    for k in np.unique(s):
        idx = np.flatnonzero(s == k)
        r = np.arange(idx.size)
        keys[idx] = np.where(r < first, r - first, (r + 0.5) / idx.size)
    return np.lexsort((np.arange(s.size), s, keys))


def sampling_order(strata, parts=None) -> np.ndarray:
    """The fine order of a two-level sweep: :func:`fine_order` of the strata or, with sampling parts (any part
    label not 0), of every (stratum, part) cell with each cell's first two put first.

    A part as small as a twentieth of the phantoms would otherwise get its second phantom only some 30 phantoms
    into the order, and every design would run that many before its estimate exists (each part needs two pairs);
    putting two of each part first keeps the pilot at two per part. The estimate weights each part by its share,
    so the allocation need not be proportional to be unbiased; beyond the first two of each part it is.
    """
    if parts is None or not np.any(parts):
        return fine_order(strata)
    return fine_order(sampling_labels(strata, parts), first=2)


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
