"""Seeded train/validation/test splits (numpy only, no torch needed).

The paper splits each touch-count subgroup of the reconstruction data 7:2:1 (§V) and the gesture data 8:2
(§VII, with a separately recorded test set). :func:`stratified_split` splits every group (touch count, gesture
class) by the same fractions, so each part keeps the group proportions; :func:`split_indices` splits without
groups.
"""

from __future__ import annotations

import math

import numpy as np

from .. import _validate as v
from ..errors import ParameterError

#: The paper's reconstruction split (train, validation, test).
RECON_SPLIT = (0.7, 0.2, 0.1)
#: The paper's gesture split (train, validation); its test set is generated separately.
GESTURE_SPLIT = (0.8, 0.2)


def _fractions(fractions) -> np.ndarray:
    try:
        f = np.asarray([float(x) for x in fractions])
    except (TypeError, ValueError):
        raise ParameterError("fractions", "a sequence of positive numbers summing to 1", fractions) from None
    if f.size < 1 or not np.all(np.isfinite(f)) or np.any(f <= 0) or not math.isclose(f.sum(), 1.0, abs_tol=1e-9):
        raise ParameterError("fractions", "a sequence of positive numbers summing to 1", tuple(fractions))
    return f


def _part_sizes(n: int, f: np.ndarray) -> np.ndarray:
    """Sizes from rounded cumulative boundaries: they sum to ``n`` and are exact when ``n * f`` is integral."""
    bounds = np.rint(np.cumsum(f) * n).astype(int)
    bounds[-1] = n
    return np.diff(np.concatenate([[0], bounds]))


def split_indices(n: int, fractions=RECON_SPLIT, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Randomly partition ``range(n)`` into parts of the given fractions.

    Parameters
    ----------
    n
        Number of samples.
    fractions
        Positive fractions summing to 1, e.g. :data:`RECON_SPLIT` ``(0.7, 0.2, 0.1)``.
    seed
        Seed of the permutation; the same seed gives the same split on any machine.

    Returns
    -------
    tuple of ndarray
        One sorted int64 index array per fraction; together they are a partition of ``range(n)``.
    """
    n = v.integer("n", n, lo=0)
    f = _fractions(fractions)
    seed = v.integer("seed", seed, lo=0)
    perm = np.random.default_rng(seed).permutation(n)
    parts = np.split(perm, np.cumsum(_part_sizes(n, f))[:-1])
    return tuple(np.sort(p).astype(np.int64) for p in parts)


def stratified_split(groups: np.ndarray, fractions=RECON_SPLIT, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Split every group by the same fractions (the paper's per-touch-count / per-class split).

    Parameters
    ----------
    groups
        Group label of each sample, shape ``(n,)`` (touch count, gesture class, ...).
    fractions, seed
        As in :func:`split_indices`; each group gets its own stream derived from ``seed``.

    Returns
    -------
    tuple of ndarray
        One sorted int64 index array per fraction, indices into ``groups``.
    """
    groups = np.asarray(groups)
    if groups.ndim != 1:
        raise ParameterError("groups", "a 1-D array of group labels", groups.shape)
    f = _fractions(fractions)
    seed = v.integer("seed", seed, lo=0)
    parts: list[list[np.ndarray]] = [[] for _ in f]
    for k, g in enumerate(np.unique(groups)):
        members = np.flatnonzero(groups == g)
        perm = members[np.random.default_rng([seed, k]).permutation(len(members))]
        for i, chunk in enumerate(np.split(perm, np.cumsum(_part_sizes(len(members), f))[:-1])):
            parts[i].append(chunk)
    return tuple(np.sort(np.concatenate(p)).astype(np.int64) if p else np.zeros(0, np.int64) for p in parts)
