"""Drive and measurement protocols: which currents are injected and which voltages are read.

A :class:`Protocol` is three arrays. ``drive_currents`` (n_drives, n_e) gives, per drive, the current into
each electrode in units of the forward model's ``current_A`` (adjacent drive ``d``: +1 into electrode ``d``,
-1 into ``d + 1``, i.e. the current leaves there). ``measure`` (n_rows, n_e) gives per row the weights of the
electrode potentials (pair ``[N, M]``: +1 at ``N``, -1 at ``M``, so the row reads ``U[N] - U[M]``).
``row_drive`` (n_rows,) says under which drive each row is read. Electrode indices are 0-based (index 0 is
the hardware's electrode 1).

Row order of :meth:`Protocol.adjacent` is pyEIT 1.2.4's ``protocol.create(16, 1, 1, "std")`` (and EIDORS'
``{ad}`` with ``no_meas_current``): drive ``d = 0..n-1`` injects into ``d`` and draws from ``d + 1``; for
each drive, rows run over ``m = 0..n-1`` ascending with the pair ``[N, M] = [m + 1, m]`` (value
``U[m + 1] - U[m]``), dropping every pair that touches a drive electrode: 16 x 13 = 208 rows.

Reciprocity: the transfer impedance is symmetric, so row (drive ``d``, pair ``m``) equals row (drive ``m``,
pair ``d``) of the adjacent protocol (both sign flips, of drive and pair, cancel). :attr:`Protocol.reciprocal`
holds each row's partner and :attr:`Protocol.reciprocal_sign` the sign (``V[r] = sign * V[partner]``).
:attr:`Protocol.independent` keeps the first row of every partner pair in row order, which for the adjacent
protocol are the 104 rows with drive ``d`` < pair index ``m`` (the lower electrode ``M`` of the pair); the
dropped row ``(d, m)`` with ``d > m`` is ``reciprocal_sign * V[(m, d)]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import _validate as v
from ..errors import ParameterError


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def _pairs_of(mat: np.ndarray) -> np.ndarray:
    """``(k, 2)`` of (electrode with +1, electrode with -1) per row, -1 where a row is not such a pair."""
    out = np.full((len(mat), 2), -1, dtype=np.int64)
    nz = mat != 0
    is_pair = (nz.sum(1) == 2) & np.isclose(mat.max(1), 1) & np.isclose(mat.min(1), -1)
    out[is_pair, 0] = np.argmax(mat[is_pair], axis=1)
    out[is_pair, 1] = np.argmin(mat[is_pair], axis=1)
    return out


def _key(row: np.ndarray) -> bytes:
    """Hashable form of a pattern for exact matching (rounded; ``+ 0.0`` folds -0.0 into 0.0)."""
    return (np.round(row, 12) + 0.0).tobytes()


def _keyed(rows: np.ndarray) -> dict:
    """Map of each row to its (first) index."""
    out: dict = {}
    for i, r in enumerate(rows):
        out.setdefault(_key(r), i)
    return out


@dataclass(frozen=True, eq=False)
class Protocol:
    """A checked drive/measurement protocol (see the module docstring for conventions).

    Parameters
    ----------
    drive_currents
        Current into each electrode per drive, shape ``(n_drives, n_electrodes)``, in units of the forward
        model's ``current_A``; every row sums to zero and is not all zero.
    measure
        Weights of the electrode potentials per measurement row, shape ``(n_rows, n_electrodes)``.
    row_drive
        Drive index of each row, shape ``(n_rows,)``.
    name
        Label (``"adjacent"``, ``"opposite"``, ``"custom"`` ...).

    Attributes
    ----------
    drive_pairs : ndarray, shape (n_drives, 2)
        (source, sink) electrode of each drive, -1 where a drive is not a +1/-1 pair.
    meas_pairs : ndarray, shape (n_rows, 2)
        ``[N, M]`` of each row (value ``U[N] - U[M]``, pyEIT's order), -1 where a row is not a pair.
    reciprocal : ndarray, shape (n_rows,)
        Row equal to this one by reciprocity (``V[r] = reciprocal_sign[r] * V[reciprocal[r]]``), -1 if none.
    reciprocal_sign : ndarray, shape (n_rows,)
        +1 or -1 (0 where there is no partner).
    independent : ndarray, shape (n_independent,)
        Rows kept when reciprocal duplicates are dropped (the first of each pair in row order, and all
        rows without a partner); 104 for the 16-electrode adjacent protocol.
    """

    drive_currents: np.ndarray
    measure: np.ndarray
    row_drive: np.ndarray
    name: str = "custom"
    drive_pairs: np.ndarray = field(init=False, repr=False)
    meas_pairs: np.ndarray = field(init=False, repr=False)
    reciprocal: np.ndarray = field(init=False, repr=False)
    reciprocal_sign: np.ndarray = field(init=False, repr=False)
    independent: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        drive = np.asarray(self.drive_currents, dtype=float)
        meas = np.asarray(self.measure, dtype=float)
        row_drive = np.asarray(self.row_drive)
        if drive.ndim != 2 or drive.shape[1] < 2 or drive.shape[0] < 1:
            raise ParameterError("drive_currents", "an array of shape (n_drives >= 1, n_electrodes >= 2)",
                                 f"shape {drive.shape}")
        n_e = drive.shape[1]
        if not np.all(np.isfinite(drive)) or np.any(np.abs(drive.sum(1)) > 1e-9 * np.abs(drive).sum(1)) \
                or np.any(np.all(drive == 0, axis=1)):
            raise ParameterError("drive_currents", "finite rows that sum to zero (current in = current out) "
                                 "and are not all zero", "a row violating that")
        if meas.ndim != 2 or meas.shape[1] != n_e or meas.shape[0] < 1 or not np.all(np.isfinite(meas)):
            raise ParameterError("measure", f"a finite array of shape (n_rows >= 1, {n_e})", f"shape {meas.shape}")
        if row_drive.shape != (len(meas),) or not np.issubdtype(row_drive.dtype, np.integer) \
                or row_drive.min() < 0 or row_drive.max() >= len(drive):
            raise ParameterError("row_drive", f"{len(meas)} integers in [0, {len(drive) - 1}]",
                                 f"shape {row_drive.shape}, dtype {row_drive.dtype}")
        if not isinstance(self.name, str) or not self.name:
            raise ParameterError("name", "a non-empty string", self.name)
        set_(self, "drive_currents", _frozen(drive))
        set_(self, "measure", _frozen(meas))
        set_(self, "row_drive", _frozen(row_drive.astype(np.int64)))
        set_(self, "drive_pairs", _frozen(_pairs_of(drive)))
        set_(self, "meas_pairs", _frozen(_pairs_of(meas)))
        partner, sign = self._find_reciprocal()
        set_(self, "reciprocal", _frozen(partner))
        set_(self, "reciprocal_sign", _frozen(sign))
        keep = (partner < 0) | (partner > np.arange(len(partner)))
        set_(self, "independent", _frozen(np.nonzero(keep)[0]))

    def _find_reciprocal(self) -> tuple[np.ndarray, np.ndarray]:
        # Row r (drive vector a, measurement vector b) equals s1 s2 times row r' whose drive vector is s1 b
        # and measurement vector s2 a (symmetry of the transfer impedance).
        n = self.n_rows
        by_drive_meas = {}
        for r in range(n):
            key = (_key(self.drive_currents[self.row_drive[r]]), _key(self.measure[r]))
            by_drive_meas.setdefault(key, r)
        partner = np.full(n, -1, dtype=np.int64)
        sign = np.zeros(n, dtype=np.int64)
        for r in range(n):
            a, b = self.drive_currents[self.row_drive[r]], self.measure[r]
            for s1 in (1, -1):
                for s2 in (1, -1):
                    key = (_key(s1 * b), _key(s2 * a))
                    rr = by_drive_meas.get(key, -1)
                    if rr >= 0 and rr != r and partner[r] < 0:
                        partner[r], sign[r] = rr, s1 * s2
        return partner, sign

    # -- sizes --------------------------------------------------------------------------------------
    @property
    def n_electrodes(self) -> int:
        return self.drive_currents.shape[1]

    @property
    def n_drives(self) -> int:
        return self.drive_currents.shape[0]

    @property
    def n_rows(self) -> int:
        return self.measure.shape[0]

    # -- constructors -------------------------------------------------------------------------------
    @classmethod
    def from_matrices(cls, drive_currents, measure, row_drive, name: str = "custom") -> Protocol:
        """Arbitrary protocol (see the class parameters)."""
        return cls(np.asarray(drive_currents, dtype=float), np.asarray(measure, dtype=float),
                   np.asarray(row_drive), name)

    @classmethod
    def pairs(cls, n_electrodes: int = 16, drive_distance: int = 1, measure_step: int = 1,
              name: str = "pairs") -> Protocol:
        """pyEIT's ``protocol.create(n, drive_distance, measure_step, "std")``.

        Drive ``d`` (``d = 0..n-1``) injects into ``d`` and draws from ``(d + drive_distance) mod n``; its rows
        are the pairs ``[N, M] = [(m + measure_step) mod n, m]`` for ``m = 0..n-1`` ascending, skipping pairs
        that touch a drive electrode.
        """
        n = v.integer("n_electrodes", n_electrodes, lo=4)
        dist = v.integer("drive_distance", drive_distance, lo=1, hi=n - 1)
        step = v.integer("measure_step", measure_step, lo=1, hi=n - 1)
        eye = np.eye(n)
        drives, meas, row_drive = [], [], []
        for d in range(n):
            a, b = d, (d + dist) % n
            drives.append(eye[a] - eye[b])
            for m in range(n):
                nn = (m + step) % n
                if m in (a, b) or nn in (a, b):
                    continue
                meas.append(eye[nn] - eye[m])
                row_drive.append(d)
        return cls(np.array(drives), np.array(meas), np.array(row_drive, dtype=np.int64), name)

    @classmethod
    def adjacent(cls, n_electrodes: int = 16) -> Protocol:
        """Adjacent drive, adjacent measurement: ``n (n - 3)`` rows (208 for 16) in pyEIT "std" order."""
        return cls.pairs(n_electrodes, 1, 1, name="adjacent")

    @classmethod
    def opposite(cls, n_electrodes: int = 16, measure_step: int = 1) -> Protocol:
        """Opposite drive (``d`` to ``d + n/2``, all ``n`` drives as pyEIT lists them), adjacent measurement."""
        n = v.integer("n_electrodes", n_electrodes, lo=4)
        if n % 2:
            raise ParameterError("n_electrodes", "an even number for opposite drive", n)
        return cls.pairs(n, n // 2, measure_step, name="opposite")

    # -- helpers ------------------------------------------------------------------------------------
    def row_map(self, electrode_perm) -> tuple[np.ndarray, np.ndarray]:
        """How rows map under a relabelling of electrodes (sensor rotations and reflections).

        Parameters
        ----------
        electrode_perm : array of int, shape (n_electrodes,)
            ``electrode_perm[e]`` is the electrode that electrode ``e`` moves to.

        Returns
        -------
        index, sign : ndarray of int, shape (n_rows,)
            Measurements ``V`` of a phantom and ``V_t`` of the transformed phantom satisfy
            ``V_t = sign * V[index]``.

        Raises
        ------
        ParameterError
            If ``electrode_perm`` is not a permutation or the protocol is not closed under it.
        """
        perm = np.asarray(electrode_perm)
        n = self.n_electrodes
        if perm.shape != (n,) or not np.array_equal(np.sort(perm), np.arange(n)):
            raise ParameterError("electrode_perm", f"a permutation of 0..{n - 1}", electrode_perm)
        # Physical electrode p of the transformed sensor touches what original electrode inv[p] touched, so row
        # r of the transformed phantom is the original phantom read with the patterns pulled back:
        # a'[e] = a[perm[e]].
        drive_back = self.drive_currents[:, perm]
        meas_back = self.measure[:, perm]
        drive_idx = _keyed(self.drive_currents)
        lookup = {}
        for r in range(self.n_rows):
            lookup.setdefault((int(self.row_drive[r]), _key(self.measure[r])), r)
        index = np.empty(self.n_rows, dtype=np.int64)
        sign = np.empty(self.n_rows, dtype=np.int64)
        for r in range(self.n_rows):
            a, b = drive_back[self.row_drive[r]], meas_back[r]
            found = False
            for s1 in (1, -1):
                d = drive_idx.get(_key(s1 * a), -1)
                if d < 0:
                    continue
                for s2 in (1, -1):
                    rr = lookup.get((d, _key(s2 * b)), -1)
                    if rr >= 0:
                        index[r], sign[r], found = rr, s1 * s2, True
                        break
                if found:
                    break
            if not found:
                raise ParameterError("electrode_perm", "a relabelling under which the protocol is closed",
                                     electrode_perm)
        return index, sign

    def summary(self) -> dict:
        return {"name": self.name, "n_electrodes": self.n_electrodes, "n_drives": self.n_drives,
                "n_rows": self.n_rows, "n_independent": len(self.independent)}

