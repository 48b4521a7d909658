"""Protocol rows against pyEIT itself, reciprocity bookkeeping and electrode relabelling."""

import numpy as np
import pytest
from pyeit.eit import protocol as pyeit_protocol

from latticeopt.electrics import Protocol
from latticeopt.errors import ParameterError


@pytest.mark.parametrize("n", [8, 16, 32])
def test_adjacent_matches_pyeit_std_order(n):
    ours = Protocol.adjacent(n)
    ref = pyeit_protocol.create(n, 1, 1, "std")
    assert ours.n_rows == ref.n_meas_tot == n * (n - 3)
    np.testing.assert_array_equal(ours.drive_pairs, ref.ex_mat)
    np.testing.assert_array_equal(ours.meas_pairs, ref.meas_mat.reshape(-1, 2))
    np.testing.assert_array_equal(ours.row_drive, np.repeat(np.arange(n), n - 3))


def test_opposite_matches_pyeit():
    ours = Protocol.opposite(16)
    ref = pyeit_protocol.create(16, 8, 1, "std")
    np.testing.assert_array_equal(ours.drive_pairs, ref.ex_mat)
    np.testing.assert_array_equal(ours.meas_pairs, ref.meas_mat.reshape(-1, 2))
    # Opposite drive with adjacent measurement has no reciprocal partners among its rows.
    assert np.all(ours.reciprocal == -1) and len(ours.independent) == ours.n_rows


def test_independent_rows_are_drive_before_pair():
    p = Protocol.adjacent(16)
    assert p.n_rows == 208 and len(p.independent) == 104
    d = p.row_drive[p.independent]
    m = p.meas_pairs[p.independent, 1]  # M of the pair [N, M] = [m + 1, m]
    assert np.all(d < m)
    # Every dropped row (d, m) with d > m is the row (m, d) with sign +1, and the partner is independent.
    dropped = np.setdiff1d(np.arange(208), p.independent)
    part = p.reciprocal[dropped]
    assert np.all(np.isin(part, p.independent))
    np.testing.assert_array_equal(p.row_drive[part], p.meas_pairs[dropped, 1])
    np.testing.assert_array_equal(p.meas_pairs[part, 1], p.row_drive[dropped])
    assert np.all(p.reciprocal_sign[dropped] == 1)


def test_from_matrices_round_trip_and_validation():
    p = Protocol.adjacent(16)
    q = Protocol.from_matrices(p.drive_currents, p.measure, p.row_drive)
    np.testing.assert_array_equal(q.meas_pairs, p.meas_pairs)
    np.testing.assert_array_equal(q.independent, p.independent)
    with pytest.raises(ParameterError, match="drive_currents"):
        Protocol.from_matrices([[1, 1, 0]], [[1, -1, 0]], [0])  # current does not balance
    with pytest.raises(ParameterError, match="measure"):
        Protocol.from_matrices([[1, -1, 0]], [[1, -1]], [0])
    with pytest.raises(ParameterError, match="row_drive"):
        Protocol.from_matrices([[1, -1, 0]], [[1, -1, 0]], [1])
    with pytest.raises(ParameterError, match="n_electrodes"):
        Protocol.opposite(15)
    assert p.drive_currents.flags.writeable is False


def _brute_row_map(p: Protocol, perm):
    """Transform each row's electrodes and look the result up among the rows, by pairs."""
    rows = {(int(d), int(a), int(b)): r for r, (d, (a, b)) in enumerate(zip(p.row_drive, p.meas_pairs))}
    drives = {tuple(map(int, dp)): d for d, dp in enumerate(p.drive_pairs)}
    inv = np.argsort(perm)
    index, sign = [], []
    for d, (a, b) in zip(p.row_drive, p.meas_pairs):
        src, snk = inv[p.drive_pairs[d]]  # physical electrodes pulled back to the original labels
        na, nb = inv[a], inv[b]
        s = 1
        if (src, snk) in drives:
            dd = drives[(src, snk)]
        else:
            dd, s = drives[(snk, src)], -s
        if (dd, na, nb) in rows:
            r = rows[(dd, na, nb)]
        else:
            r, s = rows[(dd, nb, na)], -s
        index.append(r)
        sign.append(s)
    return np.array(index), np.array(sign)


@pytest.mark.parametrize("kind", ["rotate", "reflect"])
def test_row_map_matches_pairwise_bookkeeping(kind):
    p = Protocol.adjacent(16)
    perm = (np.arange(16) + 4) % 16 if kind == "rotate" else (3 - np.arange(16)) % 16
    index, sign = p.row_map(perm)
    bi, bs = _brute_row_map(p, perm)
    np.testing.assert_array_equal(index, bi)
    np.testing.assert_array_equal(sign, bs)
    assert np.all(sign == 1)  # NOTES.md: no sign change for rotations and these reflections
    with pytest.raises(ParameterError, match="electrode_perm"):
        p.row_map(np.zeros(16, int))
