"""Eight-fold symmetry augmentation of the square sensor (paper §V, after dong2025data).

A rotation or reflection ``g`` of the square maps the sensor onto itself, moves electrode ``e`` to electrode
``perm[e]`` and a pixel image ``I`` to ``I_g(g p) = I(p)``. The measurements of the moved image are the
original measurements re-labelled: ``V_g = sign * V[index]`` with ``(index, sign)`` from
:meth:`Protocol.row_map`. Nothing here is hard-coded: the electrode permutation is found by mapping every
electrode centre of :meth:`LatticeDesign.electrodes` with ``g`` and matching it to an electrode centre, and the
design is checked to be invariant (its channel lines mirror onto channel lines), else the symmetry is refused.

Augmenting *relative* changes ``y = (V - V_ref) / V_ref`` is exact for the symmetric sensor (``y_g = y[index]``;
the signs cancel) and does not see the small asymmetry of a mesh whose tets are not mirror-symmetric.

The eight transforms act on centred coordinates ``(x - L/2, y - L/2)`` as the 2 x 2 matrices of
:data:`SQUARE_GROUP`: identity, rotations by 90, 180 and 270 degrees (counter-clockwise seen from above), and
the reflections across the vertical axis, the horizontal axis, the diagonal ``y = x`` and the anti-diagonal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..design import LatticeDesign
from ..electrics.protocol import Protocol
from ..errors import ParameterError

#: The dihedral group of the square: name -> matrix acting on centred (x, y).
SQUARE_GROUP = {
    "identity": ((1, 0), (0, 1)),
    "rot90": ((0, -1), (1, 0)),
    "rot180": ((-1, 0), (0, -1)),
    "rot270": ((0, 1), (-1, 0)),
    "flip_x": ((-1, 0), (0, 1)),      # x -> L - x
    "flip_y": ((1, 0), (0, -1)),      # y -> L - y
    "transpose": ((0, 1), (1, 0)),    # (x, y) -> (y, x)
    "antitranspose": ((0, -1), (-1, 0)),
}


@dataclass(frozen=True, eq=False)
class Symmetry:
    """One symmetry of the sensor with its action on electrodes, measurement rows and pixels.

    Attributes
    ----------
    name : str
        Key of :data:`SQUARE_GROUP`.
    matrix : ndarray, shape (2, 2)
        Action on centred ``(x, y)``.
    electrode_perm : ndarray of int, shape (n_e,)
        Electrode ``e`` moves to electrode ``electrode_perm[e]`` (0-based).
    row_index, row_sign : ndarray of int, shape (n_rows,)
        ``V_g = row_sign * V[row_index]``.
    pixel_source : ndarray of int, shape (n * n,)
        ``I_g.ravel() = I.ravel()[pixel_source]`` (pixel order ``iy * n + ix``).
    """

    name: str
    matrix: np.ndarray
    electrode_perm: np.ndarray
    row_index: np.ndarray
    row_sign: np.ndarray
    pixel_source: np.ndarray

    @property
    def orientation_reversing(self) -> bool:
        return bool(np.linalg.det(self.matrix) < 0)

    def voltages(self, V: np.ndarray) -> np.ndarray:
        """Measurements of the transformed phantom, ``(..., n_rows)`` -> ``(..., n_rows)``."""
        return np.asarray(V)[..., self.row_index] * self.row_sign

    def relative(self, y: np.ndarray) -> np.ndarray:
        """Relative changes ``(V - V_ref) / V_ref`` of the transformed phantom (signs cancel)."""
        return np.asarray(y)[..., self.row_index]

    def images(self, images: np.ndarray) -> np.ndarray:
        """Transformed images, ``(..., n, n)`` -> ``(..., n, n)``."""
        a = np.asarray(images)
        n = a.shape[-1]
        return a.reshape(*a.shape[:-2], n * n)[..., self.pixel_source].reshape(a.shape)

    def points(self, xy_mm: np.ndarray, size_mm: float) -> np.ndarray:
        """Transformed points ``(..., 2)`` (mm) on a sensor of side ``size_mm``."""
        c = size_mm / 2.0
        return (np.asarray(xy_mm, dtype=float) - c) @ self.matrix.T + c


def _design_is_invariant(design: LatticeDesign, M: np.ndarray) -> bool:
    """The channel layout maps onto itself (the electrodes are checked by matching their centres)."""
    if not design.has_lattice:
        return True
    L = design.size_mm
    iv = design.channel_intervals_mm()
    mirrored = np.sort(L - iv[:, ::-1], axis=0)
    # Rotations and reflections permute or mirror the x and y line sets, which are the same set here; so the
    # layout is invariant iff mirroring is not needed or the 1D layout is mirror-symmetric.
    needs_mirror = bool(np.any(M.sum(axis=0) < 0) or np.any(M.sum(axis=1) < 0))
    return not needs_mirror or np.allclose(np.sort(iv, axis=0), mirrored, atol=1e-9 * L)


def electrode_permutation(design: LatticeDesign, name: str) -> np.ndarray:
    """Electrode permutation of symmetry ``name`` from the electrode geometry (0-based).

    Raises
    ------
    ParameterError
        Unknown name, or the design (lattice or electrodes) is not invariant under the symmetry.
    """
    if name not in SQUARE_GROUP:
        raise ParameterError("symmetry", "one of " + ", ".join(SQUARE_GROUP), name)
    M = np.asarray(SQUARE_GROUP[name], dtype=float)
    el = design.electrodes()
    L = design.size_mm
    centres = el[:, :2] - L / 2
    moved = centres @ M.T
    normals = el[:, 3:5] @ M.T
    dist = np.linalg.norm(moved[:, None, :] - centres[None, :, :], axis=2)
    perm = np.argmin(dist, axis=1)
    ok = (np.min(dist, axis=1) < 1e-9 * L) & np.allclose(normals, el[perm, 3:5]) \
        & np.allclose(el[:, 6:8], el[perm, 6:8])
    if not np.all(ok) or len(np.unique(perm)) != len(perm) or not _design_is_invariant(design, M):
        raise ParameterError("symmetry", f"a symmetry of the design ({design.describe()})", name)
    return perm


def pixel_source(n: int, matrix) -> np.ndarray:
    """Source pixel of every pixel of an ``n x n`` image transformed by ``matrix`` (see :class:`Symmetry`)."""
    M = np.asarray(matrix, dtype=float)
    iy, ix = np.divmod(np.arange(n * n), n)
    c = (n - 1) / 2.0
    dest = np.stack([ix - c, iy - c], axis=1)
    # I_g(q) = I(g^-1 q); g is orthogonal, so g^-1 = g^T, i.e. row vectors times M.
    src = np.rint(dest @ M + c).astype(np.int64)
    return src[:, 1] * n + src[:, 0]


def square_symmetries(design: LatticeDesign, protocol: Protocol, n_pixels: int,
                      names=tuple(SQUARE_GROUP)) -> list[Symmetry]:
    """The requested symmetries (default all eight) with their electrode, row and pixel maps."""
    out = []
    for name in names:
        perm = electrode_permutation(design, name)
        index, sign = protocol.row_map(perm)
        M = np.asarray(SQUARE_GROUP[name], dtype=float)
        out.append(Symmetry(name, M, perm, index, sign, pixel_source(n_pixels, M)))
    return out
