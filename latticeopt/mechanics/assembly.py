"""Vectorised residual and tangent of the P1 neo-Hookean stack, with patch-wise mean dilatation.

Discrete energy (lengths mm, moduli MPa, so forces come out in N)::

    Pi(u) = sum_tets V_e mu_e / 2 (J_e^(-2/3) I1_e - 3)  +  sum_patches V_h U_h(Jbar_h),
    Jbar_h = (sum_{e in h} J_e V_e) / V_h

The deviatoric part lives on every P1 tet (one quadrature point is exact: F is constant per tet). The
volumetric part sees only the mean dilatation ``Jbar`` of a *patch* of tets (Nagtegaal-Parks-Rice mean
dilatation, as in the Q1/P0 hexahedron): on the grid mesher's output a patch is the six Kuhn tets of one
hexahedral cell, so there is one volume constraint per cell (about one per node) instead of one per tet
(about six per node), which is what locks plain P1 tets as ``nu -> 0.5``. ``volumetric="element"`` makes
every tet its own patch (plain P1, locks) for comparison. Evidence: ``benchmarks/bench_locking.py``.

All F-dependent quantities are computed once per tet (``F``, ``J``, ``F^-T``, the spatial gradients
``h_a = F^-T grad N_a``) and the 12 x 12 tet tangents are built from outer products of those, never per
pair of basis functions. Each patch's tet blocks and mean-dilatation block are summed in a dense patch block
whose upper triangle is added to a fixed CSR pattern through an index map built once in ``__init__``, so every
Newton step of every phantom reuses the pattern (and PARDISO's symbolic factorization).

Tangent per tet, with ``g_a`` reference gradients, ``f_a = F g_a``, ``h_a = F^-T g_a``, ``c = V mu J^-2/3``::

    K_ai,bk = c [d_ik g_a.g_b - 2/3 (q_ai h_bk + h_ai q_bk) + I1/3 h_bi h_ak] + U'(Jbar) v_e (h_ai h_bk - h_bi h_ak)
    q = f - I1/6 h,  v_e = J V

plus, per patch, the rank-one block ``U''(Jbar) / V_h  gbar gbar^T`` with ``gbar = sum_e v_e h`` (the
derivative of the patch volume).
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass

import numpy as np

from ..mesh.p1 import hat_gradients
from ..mesh.tetmesh import TetMesh
from ._kernels import kinematics, patch_tangents, tet_forces
from .materials import Materials

log = logging.getLogger(__name__)

VOLUMETRIC = ("patch", "element")


def dilatation_patches(mesh: TetMesh, volumetric: str = "patch") -> np.ndarray:
    """Patch index of every tet, shape ``(M,)``, numbered ``0 .. P-1``; patches never mix regions.

    ``"patch"``: the mesher's own cells when the mesh carries them (:attr:`TetMesh.cells`: the grid mesher's
    hexahedra, the extruded mesher's pairs of prisms in one z layer), split by region. Without them: on a
    tensor-product node set (a block mesh) the hexahedral cell holding each tet's centroid; on other meshes
    the cell of a virtual grid with about six tets per cell, split by region (a heuristic, what tetwild
    meshes get). ``"element"``: every tet alone.
    """
    M = mesh.n_tets
    if volumetric == "element":
        return np.arange(M)
    if mesh.cells is not None:
        cell = mesh.cells
    else:
        nodes = mesh.nodes_mm
        cent = nodes[mesh.tets].mean(axis=1)
        axes = [np.unique(np.round(nodes[:, i], 9)) for i in range(3)]
        if np.prod([len(a) for a in axes]) == mesh.n_nodes:
            edges = axes  # tensor grid: cells are exactly the hexahedra
        else:
            lo, hi = nodes.min(axis=0), nodes.max(axis=0)
            step = (6.0 * np.abs(mesh.tet_volumes_mm3()).mean()) ** (1.0 / 3.0)
            edges = [np.linspace(lo[i], hi[i], max(int(np.ceil((hi[i] - lo[i]) / step)), 1) + 1)
                     for i in range(3)]
        cell = np.zeros(M, dtype=np.int64)
        for i in range(3):
            k = np.clip(np.searchsorted(edges[i], cent[:, i]) - 1, 0, len(edges[i]) - 2)
            cell = cell * (len(edges[i]) - 1) + k
    key = cell * 256 + mesh.region.astype(np.int64)
    _, patch = np.unique(key, return_inverse=True)
    return patch.ravel()


def _upper_pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.triu_indices(n)
    return i, j


@dataclass(frozen=True)
class Evaluation:
    """State of the stack at one displacement field.

    Attributes
    ----------
    energy_Nmm
        Stored energy (N mm); ``inf`` if any tet or patch is inverted.
    residual_N
        Internal nodal forces ``dPi/du``, shape ``(3N,)`` (N), interleaved x, y, z per node.
    data
        Tangent values on :attr:`NeoHookeanOperator.indices` (upper CSR), or None.
    min_J, min_Jbar
        Smallest ``det F`` over tets and smallest mean dilatation over patches.
    """

    energy_Nmm: float
    residual_N: np.ndarray | None
    data: np.ndarray | None
    min_J: float
    min_Jbar: float

    @property
    def inverted(self) -> bool:
        return not (self.min_J > 0 and self.min_Jbar > 0)


class NeoHookeanOperator:
    """Energy, residual and tangent of a labelled mesh with given materials (expensive state, built once).

    Parameters
    ----------
    mesh
        The labelled tet mesh (mm).
    materials
        Neo-Hookean parameters per region.
    volumetric
        ``"patch"`` (mean dilatation per hexahedral cell, default) or ``"element"`` (plain P1).
    """

    def __init__(self, mesh: TetMesh, materials: Materials, volumetric: str = "patch"):
        if volumetric not in VOLUMETRIC:
            raise ValueError(f"volumetric: expected one of {VOLUMETRIC}, got {volumetric!r}")
        self.volumetric = volumetric
        self.n_nodes = mesh.n_nodes
        self.n_dofs = 3 * mesh.n_nodes
        patch = dilatation_patches(mesh, volumetric)
        # Work on tets sorted by patch, so per-patch sums are contiguous and cache friendly.
        self.order = np.argsort(patch, kind="stable")
        self.patch = patch[self.order]
        self.tets = mesh.tets[self.order]
        self.grad, self.vol = hat_gradients(mesh.nodes_mm, self.tets)  # 1/mm, mm^3
        if np.any(self.vol <= 0):
            raise ValueError("mesh: every tet must be positively oriented with positive volume")
        mu, self._kappa_tet = materials.moduli_MPa(mesh.region[self.order])
        self.mu = mu
        P = int(self.patch.max()) + 1
        self.n_patches = P
        self._build_patch_nodes(P)
        self._build_pattern()
        M = mesh.n_tets
        self._set_geometry(self.grad, self.vol)
        log.debug("operator: %d tets, %d patches (max %d nodes), %d dofs, %d upper nonzeros",
                  M, P, self._kmax, self.n_dofs, self.nnz)

    def _set_geometry(self, grad: np.ndarray, vol: np.ndarray) -> None:
        """Everything that depends on the reference node positions (patch-sorted tets)."""
        self.grad, self.vol = grad, vol
        P = self.n_patches
        self.patch_vol = np.bincount(self.patch, vol, minlength=P)
        self.patch_kappa = np.bincount(self.patch, self._kappa_tet * vol, minlength=P) / self.patch_vol

    def with_reference(self, nodes_mm: np.ndarray) -> NeoHookeanOperator:
        """The same operator (pattern, maps, materials shared) on moved reference nodes, same topology."""
        grad, vol = hat_gradients(nodes_mm, self.tets)
        if np.any(vol <= 0):
            raise ValueError("nodes_mm: every tet must keep a positive volume")
        other = copy.copy(self)
        other._set_geometry(grad, vol)
        return other

    def with_moduli(self, mu_MPa: np.ndarray, kappa_MPa: np.ndarray) -> NeoHookeanOperator:
        """The same operator (pattern, maps, reference shared) with shear and bulk moduli given per tet.

        Parameters
        ----------
        mu_MPa, kappa_MPa : ndarray, shape (M,)
            Moduli of every tet in *mesh* order (MPa); the patch bulk modulus is their volume average.
        """
        mu, kappa = (np.asarray(a, dtype=float) for a in (mu_MPa, kappa_MPa))
        ok = mu.shape == kappa.shape == self.order.shape and np.all(mu > 0) and np.all(kappa > 0)
        if not ok:
            raise ValueError(f"mu_MPa, kappa_MPa: expected {len(self.order)} positive values each")
        other = copy.copy(self)
        other.mu, other._kappa_tet = mu[self.order], kappa[self.order]
        other._set_geometry(self.grad, self.vol)
        return other

    # -- one-off structure --------------------------------------------------------------------------
    def _build_patch_nodes(self, P: int) -> None:
        M = len(self.tets)
        key = np.repeat(self.patch, 4) * self.n_nodes + self.tets.ravel()
        ukey, inv = np.unique(key, return_inverse=True)
        upatch = ukey // self.n_nodes
        counts = np.bincount(upatch, minlength=P)
        kmax = int(counts.max())
        start = np.r_[0, np.cumsum(counts)[:-1]]
        slot = np.arange(len(ukey)) - start[upatch]
        self.patch_nodes = np.full((P, kmax), -1, dtype=np.int64)
        self.patch_nodes[upatch, slot] = ukey % self.n_nodes
        self._tet_slot = slot[inv.ravel()].reshape(M, 4)  # local position in the patch of each tet node
        self._kmax = kmax
        self._patch_starts = np.searchsorted(self.patch, np.arange(P + 1))

    def _build_pattern(self) -> None:
        P = self.n_patches
        n, nk = self.n_dofs, 3 * self._kmax
        # patch blocks: upper pairs of the 3k local dofs; every tet pair lies inside its patch's block
        qi, qj = _upper_pairs(nk)
        self._patch_pairs = (qi, qj)
        pdof = np.where(self.patch_nodes[:, :, None] >= 0, 3 * self.patch_nodes[:, :, None] + np.arange(3), -1)
        pdof = pdof.reshape(P, nk)
        rows_p, cols_p = pdof[:, qi], pdof[:, qj]
        valid = (rows_p >= 0) & (cols_p >= 0)
        key_p = np.minimum(rows_p, cols_p) * n + np.maximum(rows_p, cols_p)
        keys, inv = np.unique(key_p[valid], return_inverse=True)
        self.nnz = len(keys)
        pmap = np.full(key_p.shape, self.nnz, dtype=np.int32)  # padding goes to a spare slot
        pmap[valid] = inv.ravel()
        self._patch_map = pmap
        rows, cols = keys // n, keys % n
        # int32 where it fits: scipy and PARDISO take them without a conversion (the constrained tangent was
        # built in 3.5 ms with int64 indices, 1.8 ms with these)
        index = np.int32 if self.nnz < 2**31 - 1 else np.int64
        self.indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=n))].astype(index)
        self.indices = cols.astype(index)
        self.rows = rows
        self.diag_pos = np.searchsorted(keys, np.arange(n) * (n + 1))

    # -- kinematics ---------------------------------------------------------------------------------
    def _kinematics(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``F``, its cofactor ``J F^-T`` (both ``(M, 3, 3)``) and ``J`` of every tet, patch-sorted order."""
        return kinematics(np.ascontiguousarray(u, dtype=float), self.tets, self.grad)

    def deformation_gradient(self, u: np.ndarray) -> np.ndarray:
        """``F`` of every tet in the operator's (patch-sorted) order, shape ``(M, 3, 3)``; ``u`` is (N, 3) mm."""
        return self._kinematics(u)[0]

    def jacobians(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``det F`` per tet in *mesh* order, shape ``(M,)``, and mean dilatation per patch, shape ``(P,)``."""
        J = self._kinematics(u)[2]
        Jbar = np.bincount(self.patch, J * self.vol, minlength=self.n_patches) / self.patch_vol
        out = np.empty_like(J)
        out[self.order] = J
        return out, Jbar

    # -- energy, residual, tangent ------------------------------------------------------------------
    def evaluate(self, u: np.ndarray, residual: bool = True, tangent: bool = True,
                 project: bool = False) -> Evaluation:
        """Energy and, unless inverted, residual and tangent at displacement ``u`` (N, 3) in mm; ``project``: the
        tangent with every patch block's negative eigenvalues set to 0 (positive semidefinite)."""
        F, cof, J = self._kinematics(u)
        v_e = J * self.vol
        Jbar = np.bincount(self.patch, v_e, minlength=self.n_patches) / self.patch_vol
        min_J, min_Jbar = float(J.min()), float(Jbar.min())
        if not (min_J > 0 and min_Jbar > 0):
            return Evaluation(np.inf, None, None, min_J, min_Jbar)
        I1 = np.einsum("eij,eij->e", F, F)
        Jm23 = J ** (-2.0 / 3.0)
        kap = self.patch_kappa
        energy = float(np.dot(self.vol * self.mu, 0.5 * (Jm23 * I1 - 3.0))
                       + np.dot(self.patch_vol * kap, 0.25 * (Jbar ** 2 - 1.0 - 2.0 * np.log(Jbar))))
        if not residual:
            return Evaluation(energy, None, None, min_J, min_Jbar)
        cof /= J[:, None, None]  # now F^-T
        c = self.vol * self.mu * Jm23
        Up = 0.5 * kap * (Jbar - 1.0 / Jbar)
        w = Up[self.patch] * v_e  # U'(Jbar) v_e per tet
        R = np.zeros(self.n_dofs)
        tet_forces(self.grad, F, cof, c, w, I1, self.tets, R)
        if not tangent:
            return Evaluation(energy, R, None, min_J, min_Jbar)
        data = np.zeros(self.nnz + 1)
        qi, qj = self._patch_pairs
        Upp = 0.5 * kap * (1.0 + 1.0 / Jbar ** 2)
        patch_tangents(self.grad, F, cof, c, w, I1, v_e, self._patch_starts, self._tet_slot, Upp / self.patch_vol,
                       qi, qj, self._patch_map, data, project)
        data = data[:-1]
        return Evaluation(energy, R, data, min_J, min_Jbar)

    def principal_stretches(self, u: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Principal stretches (ascending) of the tets selected by ``mask`` (mesh order), shape ``(m, 3)``."""
        F = self.deformation_gradient(u)
        if mask is not None:
            F = F[mask[self.order]]
        C = np.einsum("eki,ekj->eij", F, F)
        return np.sqrt(np.clip(np.linalg.eigvalsh(C), 0.0, None))
