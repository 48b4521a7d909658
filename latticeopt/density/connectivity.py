"""How far apart a density layout puts its electrodes: two-terminal resistances on the network of its cells.

Each cell of the ``n x n`` layout is a node; neighbours across a side (never across a corner) are joined by the
series conductance of their two half cells, ``2 t sigma_a sigma_b / (sigma_a + sigma_b)`` (``t`` the layer's
thickness, ``sigma`` each cell's conductivity from the interpolation law), and each electrode is a node joined to
the rim cells it overlaps by a length ``l`` through its contact impedance and the half cell behind it,
``1 / (z_c / (l t) + (h / 2) / (sigma l t))``. ``R_ij`` is the voltage between electrodes ``i`` and ``j`` per
ampere injected at ``i`` and taken out at ``j``; the measure is

``I = (mean_ij (R_ij / Ru_ij)^p)^(1/p)`` over all pairs ``i < j``, ``Ru`` the uniform layer's.

About 1 for a connected network, huge when a piece of gel holding any electrodes, even one, is joined to the
others only through the insulating floor. The cells' network, not the finite-element electrics, because two cells
that touch only at a corner share a vertical edge of the element mesh and conduct through its nodes there, while
the cast outline separates them: an optimizer bounded by the finite-element resistances joined its pieces by such
corners. Its gradient: ``dR/dg_e = -(du_e)^T W (du_e)`` over the network's edges (``du_e`` the potential
differences of the basis solutions across edge ``e``, ``W`` the weights of the pairs), one factorization for all.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .field import InterpolationLaw, check_density

MM = 1e-3


class CellNetwork:
    """The resistor network of a layout's cells and electrodes (module docstring).

    Parameters
    ----------
    design
        The sensor: size, thickness and electrodes.
    n
        Cells per side.
    law
        The conductivity law of a cell's density.
    sigma_S_per_m, contact_impedance_ohm_m2
        The gel's conductivity and the electrodes' contact impedance.

    Attributes
    ----------
    uniform_resistances : ndarray
        ``Ru_ij`` (ohm), the uniform layer's pair resistances.
    """

    def __init__(self, design, n: int, law: InterpolationLaw, sigma_S_per_m: float, contact_impedance_ohm_m2: float):
        self.n, self.law, self.sigma = int(n), law, float(sigma_S_per_m)
        L, t = design.size_mm, design.thickness_mm
        h = L / self.n
        self._t, self._h, self._zc = t * MM, h * MM, float(contact_impedance_ohm_m2)
        idx = np.arange(self.n * self.n).reshape(self.n, self.n)
        self._edges = np.concatenate([np.column_stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()]),
                                      np.column_stack([idx[:-1, :].ravel(), idx[1:, :].ravel()])])
        cells, lengths, owner = [], [], []
        edges_mm = np.linspace(0.0, L, self.n + 1)
        for k, (cx, cy, _z, nx, ny, axis, width, _h) in enumerate(design.electrodes()):
            centre = cx if int(axis) == 0 else cy
            overlap = np.clip(np.minimum(edges_mm[1:], centre + width / 2)
                              - np.maximum(edges_mm[:-1], centre - width / 2), 0.0, None)
            along = np.flatnonzero(overlap > 1e-12)
            if int(axis) == 0:
                cell = idx[0 if ny < 0 else self.n - 1, along]
            else:
                cell = idx[along, 0 if nx < 0 else self.n - 1]
            cells.append(cell)
            lengths.append(overlap[along] * MM)
            owner.append(np.full(len(along), k))
        self._contact_cell, self._contact_len = np.concatenate(cells), np.concatenate(lengths)
        self._contact_owner = np.concatenate(owner)
        self.n_electrodes = len(design.electrodes())
        self.uniform_resistances = self._solve(np.full(self.n * self.n, self.sigma))[0]

    def _conductances(self, sigma: np.ndarray):
        """Edge and contact conductances (S) and their derivatives in the cells' conductivities."""
        t, a, b = self._t, sigma[self._edges[:, 0]], sigma[self._edges[:, 1]]
        g = 2 * t * a * b / (a + b)
        dg_da, dg_db = 2 * t * b ** 2 / (a + b) ** 2, 2 * t * a ** 2 / (a + b) ** 2
        area = self._contact_len * t
        s = sigma[self._contact_cell]
        r = self._zc / area + 0.5 * self._h / (s * area)
        gc = 1.0 / r
        dgc = gc ** 2 * 0.5 * self._h / (s ** 2 * area)
        return g, (dg_da, dg_db), gc, dgc

    def _solve(self, sigma: np.ndarray):
        """Pair resistances (ohm, ``triu_indices`` order), the basis potentials and the conductances."""
        N, E = self.n * self.n, self.n_electrodes
        g, dg, gc, dgc = self._conductances(sigma)
        i = np.concatenate([self._edges[:, 0], self._contact_cell])
        j = np.concatenate([self._edges[:, 1], N + self._contact_owner])
        w = np.concatenate([g, gc])
        A = sp.coo_matrix((w, (i, j)), shape=(N + E, N + E))
        A = A + A.T
        lap = (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsc()
        # the last electrode grounded: its row and column dropped; currents in at the others
        keep = N + E - 1
        rhs = np.zeros((keep, E - 1))
        rhs[N + np.arange(E - 1), np.arange(E - 1)] = 1.0
        U = np.zeros((N + E, E))
        U[:keep, :E - 1] = spla.splu(lap[:keep, :keep]).solve(rhs)
        T = U[N:N + E]
        p, q = np.triu_indices(E, 1)
        return T[p, p] + T[q, q] - T[p, q] - T[q, p], U, (g, dg, gc, dgc)

    def pair_resistances(self, density: np.ndarray) -> np.ndarray:
        """``R_ij`` (ohm) of every electrode pair ``i < j`` in ``numpy.triu_indices`` order."""
        sigma, _ = self.law.conductivity(check_density(density).ravel(), self.sigma)
        return self._solve(sigma)[0]

    def isolation(self, density: np.ndarray, p: float = 8.0) -> tuple[float, np.ndarray]:
        """The measure ``I`` (module docstring) and its gradient with respect to the cells, shape ``(n, n)``."""
        rho = check_density(density).ravel()
        sigma, dsigma = self.law.conductivity(rho, self.sigma)
        R, U, (g, (dg_da, dg_db), gc, dgc) = self._solve(sigma)
        q = R / self.uniform_resistances
        value = float(np.mean(q ** p)) ** (1.0 / p)
        c = value ** (1.0 - p) * q ** (p - 1.0) / self.uniform_resistances / len(q)  # dI / dR_ij
        E = self.n_electrodes
        a, b = np.triu_indices(E, 1)
        e = np.zeros((len(q), E))
        e[np.arange(len(q)), a], e[np.arange(len(q)), b] = 1.0, -1.0
        W = e.T @ (c[:, None] * e)  # sum_ij c_ij (e_i - e_j)(e_i - e_j)^T
        N = self.n * self.n

        def energy(du):  # -d(sum W_lm T_lm)/dg of each branch: du^T W du
            return np.einsum("kl,lm,km->k", du, W, du)

        s_edge = -energy(U[self._edges[:, 0]] - U[self._edges[:, 1]])
        s_contact = -energy(U[self._contact_cell] - U[N + self._contact_owner])
        d_sigma = (np.bincount(self._edges[:, 0], s_edge * dg_da, minlength=N)
                   + np.bincount(self._edges[:, 1], s_edge * dg_db, minlength=N)
                   + np.bincount(self._contact_cell, s_contact * dgc, minlength=N))
        return value, (d_sigma * dsigma).reshape(self.n, self.n)
