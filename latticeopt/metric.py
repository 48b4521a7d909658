"""The sensitivity ``V_rel`` (paper eq. 5), its partial derivatives, and how small the reference rows get.

``V_rel = mean_i |V_i - V_i_ref| / d_i`` over the measurement rows, with ``d_i = |V_i_ref|`` as in the paper.
A layout can make some reference rows vanish: two electrodes that hang on one dead-end branch of the channels
(the diagonal lattice's corner channel below w = 4.4 mm at p = 12.5 mm joins two electrodes and meets the rest of the
network at a single crossing) are at one potential whenever the current is driven elsewhere, and are measured
at 1e-6 down to 1e-18 of the largest row: values no instrument resolves, down to the solver's round-off. Their
relative change is then a ratio of round-off, and can carry the mean (V_rel of 50 from one press).

``floor_rel`` models the instrument's resolution: ``d_i = max(|V_i_ref|, floor_rel * max_j |V_j_ref|)``, so a row
below the floor counts with the change an instrument of that dynamic range would see relative to its floor.
``floor_rel = 0`` is eq. 5 as published. :func:`smallest_reference_rel` tells whether a design has such rows.

>>> import numpy as np
>>> from latticeopt.metric import relative_change
>>> ref, touched = np.array([1.0, 0.5, 1e-15]), np.array([1.1, 0.5, 3e-15])
>>> round(relative_change(touched, ref), 4)  # the third row, round-off, reads a change of 200 %
0.7
>>> round(relative_change(touched, ref, floor_rel=1e-4), 4)  # an 80 dB instrument sees none there
0.0333
"""

from __future__ import annotations

import numpy as np

__all__ = ["ROUND_OFF_REL", "relative_change", "relative_change_partials", "smallest_reference_rel"]

#: Reference rows below this fraction of the largest are round-off (a dead-end channel's, 1e-11 to 1e-18 measured)
#: rather than a physically small row (the square lattice's smallest, 4e-7 at w = 1).
ROUND_OFF_REL = 1e-8


def _denominators(reference: np.ndarray, floor_rel: float) -> tuple[np.ndarray, float, np.ndarray]:
    mag = np.abs(reference)
    floor = floor_rel * float(mag.max()) if floor_rel > 0 else 0.0
    floored = mag < floor
    return np.where(floored, floor, mag), floor, floored


def relative_change(voltages: np.ndarray, reference: np.ndarray, floor_rel: float = 0.0) -> float:
    """``V_rel``: mean over rows of ``|V - V_ref| / max(|V_ref|, floor_rel max|V_ref|)``.

    Parameters
    ----------
    voltages, reference : ndarray, shape (n_rows,)
        Touched and untouched measurements (V).
    floor_rel
        Instrument resolution relative to the largest reference row, ``0 <= floor_rel < 1``; 0 (default) is
        paper eq. 5.
    """
    voltages, reference = np.asarray(voltages, float), np.asarray(reference, float)
    d, _, _ = _denominators(reference, floor_rel)
    return float(np.mean(np.abs(voltages - reference) / d))


def relative_change_partials(voltages: np.ndarray, reference: np.ndarray,
                             floor_rel: float = 0.0) -> tuple[float, np.ndarray, np.ndarray]:
    """``V_rel`` and its partial derivatives in the touched and in the reference voltages.

    Returns
    -------
    v_rel : float
    d_voltages, d_reference : ndarray, shape (n_rows,)
        ``dV_rel/dV_i`` and ``dV_rel/dV_ref_i`` (1/V). Where ``V_i = V_ref_i`` the one-sided slope ``0`` is taken
        for ``|V - V_ref|``; with a floor, the row holding ``max|V_ref|`` also carries the floor's derivative.
    """
    v, ref = np.asarray(voltages, float), np.asarray(reference, float)
    n = len(v)
    d, floor, floored = _denominators(ref, floor_rel)
    diff = v - ref
    s = np.sign(diff) / d / n
    # d/dV_ref of |V - V_ref| / |V_ref| on rows above the floor; on floored rows d is the floor itself
    d_ref = -s - np.where(floored, 0.0, np.abs(diff) * np.sign(ref) / d ** 2 / n)
    if floored.any():  # the floor is floor_rel * |V_ref[k]|, k the largest row
        k = int(np.argmax(np.abs(ref)))
        d_ref[k] -= float(np.sum(np.abs(diff[floored]))) / floor ** 2 / n * floor_rel * np.sign(ref[k])
    return float(np.mean(np.abs(diff) / d)), s, d_ref


def smallest_reference_rel(reference: np.ndarray) -> float:
    """``min_i |V_ref_i| / max_j |V_ref_j|``: below about 1e-4 a row is beyond a real instrument's resolution."""
    mag = np.abs(np.asarray(reference, float))
    return float(mag.min() / mag.max())
