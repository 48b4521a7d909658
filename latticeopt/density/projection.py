"""From free design variables to a density layout: symmetry, a minimum-feature filter, a smoothed Heaviside
projection and gel pads at the electrodes; with the chain rule back (for free-form optimization).

``x`` (one value per symmetry orbit of cells) -> ``rho0 = S x`` (the full ``n x n`` field) -> ``rho_f = H rho0``
(cone filter of radius ``r``: every feature narrower than about ``r`` is smoothed out) -> ``rho = P_beta(rho_f)``
(smoothed Heaviside, threshold ``eta``, sharpness ``beta``, raised in steps during an optimization so that the
result is 0/1) -> pads: cells under an electrode's footprint kept at 1 (every electrode joined to gel).
Refs: Bourdin (2001) and Bruns and Tortorelli (2001) for the filter, Wang, Lazarov and Sigmund (2011) for the
projection with ``eta`` (the robust-design form).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .. import _validate as v

SYMMETRIES = ("none", "mirror", "d4")


def symmetry_matrix(n: int, symmetry: str) -> sp.csr_matrix:
    """``(n*n, k)`` 0/1 matrix mapping one value per orbit of cells to the full field (``rho = S x``).

    ``"mirror"``: mirror symmetric in ``x`` and in ``y``; ``"d4"``: the square's eight symmetries (mirrors and
    quarter turns), the symmetry of a square sensor with symmetric electrodes.
    """
    symmetry = v.choice("symmetry", symmetry, SYMMETRIES)
    i, j = np.divmod(np.arange(n * n), n)
    images = [(i, j)]
    if symmetry in ("mirror", "d4"):
        images += [(n - 1 - i, j), (i, n - 1 - j), (n - 1 - i, n - 1 - j)]
    if symmetry == "d4":
        images += [(b, a) for a, b in images]
    orbit_key = np.min(np.stack([a * n + b for a, b in images]), axis=0)
    _, orbit = np.unique(orbit_key, return_inverse=True)
    return sp.csr_matrix((np.ones(n * n), (np.arange(n * n), orbit.ravel())), shape=(n * n, orbit.max() + 1))


def cone_filter(n: int, size_mm: float, radius_mm: float) -> sp.csr_matrix:
    """``(n*n, n*n)`` row-normalised cone filter: weights ``max(0, r - |c_i - c_j|)`` between cell centres."""
    h = size_mm / n
    reach = int(np.floor(radius_mm / h))
    i, j = np.divmod(np.arange(n * n), n)
    rows, cols, vals = [], [], []
    for di in range(-reach, reach + 1):
        for dj in range(-reach, reach + 1):
            w = radius_mm - h * np.hypot(di, dj)
            if w <= 0:
                continue
            ok = (i + di >= 0) & (i + di < n) & (j + dj >= 0) & (j + dj < n)
            rows.append(np.flatnonzero(ok))
            cols.append(((i + di) * n + j + dj)[ok])
            vals.append(np.full(ok.sum(), w))
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n * n, n * n))
    return sp.diags(1.0 / np.asarray(W.sum(axis=1)).ravel()) @ W


def heaviside(rho: np.ndarray, beta: float, eta: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed Heaviside ``(tanh(beta eta) + tanh(beta (rho - eta))) / (tanh(beta eta) + tanh(beta (1 - eta)))``
    and its derivative; maps [0, 1] onto [0, 1], steeper as ``beta`` grows."""
    den = np.tanh(beta * eta) + np.tanh(beta * (1.0 - eta))
    t = np.tanh(beta * (rho - eta))
    return (np.tanh(beta * eta) + t) / den, beta * (1.0 - t ** 2) / den


def electrode_pads(design, n: int, depth_mm: float) -> np.ndarray:
    """Cells (``(n, n)`` bool) that overlap an electrode's footprint reaching ``depth_mm`` into the sensor."""
    L = design.size_mm
    c = (np.arange(n) + 0.5) * L / n
    X, Y = np.meshgrid(c, c)
    half = 0.5 * L / n
    out = np.zeros((n, n), dtype=bool)
    for cx, cy, _cz, nx, ny, axis, width, _h in design.electrodes():
        along, across = (X, Y) if int(axis) == 0 else (Y, X)
        centre_a, centre_c = (cx, cy) if int(axis) == 0 else (cy, cx)
        inward = -(ny if int(axis) == 0 else nx)  # the outward normal's component across the side, flipped
        near = np.abs(along - centre_a) < width / 2 + half
        depth = (across - centre_c) * np.sign(inward)
        out |= near & (depth > -half) & (depth < depth_mm + half)
    return out


@dataclass(frozen=True, eq=False)
class FreeForm:
    """The map from design variables to a density layout (module docstring).

    Parameters
    ----------
    design
        The sensor (size, electrodes).
    n
        Cells per side.
    symmetry
        ``"none"``, ``"mirror"`` or ``"d4"``.
    min_feature_mm
        Filter radius: the smallest channel or island the layout keeps (mm), ``>= 0`` (0: no filter).
    pad_mm
        Gel pads at the electrodes this deep (mm); 0: none.
    eta
        Projection threshold.
    """

    design: object
    n: int
    symmetry: str = "d4"
    min_feature_mm: float = 4.0
    pad_mm: float = 4.0
    eta: float = 0.5

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "symmetry", v.choice("symmetry", self.symmetry, SYMMETRIES))
        set_(self, "min_feature_mm", v.real("min_feature_mm", self.min_feature_mm, lo=0.0,
                                            hi=self.design.size_mm / 4))
        set_(self, "pad_mm", v.real("pad_mm", self.pad_mm, lo=0.0, hi=self.design.size_mm / 2))
        set_(self, "eta", v.real("eta", self.eta, lo=0.05, hi=0.95))
        set_(self, "_S", symmetry_matrix(self.n, self.symmetry))
        h = self.design.size_mm / self.n
        set_(self, "_H", cone_filter(self.n, self.design.size_mm, self.min_feature_mm) if self.min_feature_mm > h
             else sp.identity(self.n * self.n, format="csr"))
        set_(self, "_pads", electrode_pads(self.design, self.n, self.pad_mm).ravel() if self.pad_mm > 0
             else np.zeros(self.n * self.n, dtype=bool))

    @property
    def n_variables(self) -> int:
        return self._S.shape[1]

    def variables_of(self, density: np.ndarray) -> np.ndarray:
        """Orbit means of a full ``(n, n)`` density: a start for the variables."""
        counts = np.asarray(self._S.sum(axis=0)).ravel()
        return (self._S.T @ np.asarray(density, dtype=float).ravel()) / counts

    def density(self, x: np.ndarray, beta: float) -> np.ndarray:
        """The ``(n, n)`` density of variables ``x`` at projection sharpness ``beta``."""
        return self._forward(x, beta)[0].reshape(self.n, self.n)

    def _forward(self, x, beta):
        rho_f = self._H @ (self._S @ np.asarray(x, dtype=float))
        rho, d = heaviside(rho_f, beta, self.eta)
        rho = np.where(self._pads, 1.0, np.clip(rho, 0.0, 1.0))  # the projection's round-off can pass 1 by 1e-16
        return rho, np.where(self._pads, 0.0, d)

    def gradient(self, x: np.ndarray, beta: float, grad_density: np.ndarray) -> np.ndarray:
        """Chain rule: ``d f / d x`` from ``d f / d rho`` (shape ``(n, n)``) at ``x``."""
        _, d = self._forward(x, beta)
        return self._S.T @ (self._H.T @ (d * np.asarray(grad_density, dtype=float).ravel()))
