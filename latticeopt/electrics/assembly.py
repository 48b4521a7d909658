"""Vectorised P1 assembly of the complete-electrode-model system (SI units throughout).

Unknowns: the potential at every hydrogel node, then (CEM only) the potential of every electrode. With
``phi_i`` the P1 hat functions, ``sigma_k`` the conductivity of tet ``k``, ``z_l`` the contact impedance and
``e_l`` the patch of electrode ``l`` (triangles weighted by their covered fraction)::

    K_ij  = sum_k sigma_k int_k grad phi_i . grad phi_j
    B_ij  = sum_l 1/z_l int_{e_l} phi_i phi_j            (node-node, contact)
    C_il  = -1/z_l int_{e_l} phi_i                        (node-electrode)
    D_ll  = |e_l| / z_l                                   (electrode-electrode)

    [K + B  C] [u]   [0]
    [C^T    D] [U] = [I]

The matrix is positive semi-definite with the constants as null space. The ground "sum of electrode
potentials = 0" is imposed exactly by adding ``alpha w w^T`` with ``w`` the indicator of the electrode
unknowns: for currents that sum to zero, the solution of the modified (positive definite) system satisfies
the original equations and ``w . x = 0``. Point-electrode mode keeps only ``K`` and puts ``w`` on the
electrode nodes.

Facet weights (``TetMesh.weights``): a triangle covered by the electrode to a fraction ``f`` enters the
contact integrals with ``f`` times its full-triangle values, i.e. the coverage is taken as spread evenly
over the triangle. Patch areas and total contact conductances are then exact; only the distribution of
contact current inside partially covered triangles (tetwild meshes) is approximated.

The sparsity pattern and the scatter maps depend only on the topology (:class:`Topology`), so models that
differ in conductivity or node positions share them and PARDISO's symbolic factorization.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import MeshError
from ..mesh.p1 import hat_gradients

#: Local index pairs of a tet's 4 x 4 element matrix, row-major.
_I4, _J4 = (a.ravel() for a in np.meshgrid(np.arange(4), np.arange(4), indexing="ij"))
_I3, _J3 = (a.ravel() for a in np.meshgrid(np.arange(3), np.arange(3), indexing="ij"))
#: P1 mass matrix on a triangle of unit area: (1 + delta_ij) / 12.
_TRI_MASS = ((1.0 + (_I3 == _J3)) / 12.0)


def element_geometry(nodes_m: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of the P1 hat functions and volumes of all tets.

    Parameters
    ----------
    nodes_m : ndarray, shape (N, 3)
        Node coordinates (m).
    tets : ndarray, shape (M, 4)
        Positively oriented tets.

    Returns
    -------
    grads : ndarray, shape (M, 4, 3)
        ``grads[k, i]`` is the gradient (1/m) of the hat function of local node ``i`` in tet ``k``.
    vol : ndarray, shape (M,)
        Volumes (m^3).

    Raises
    ------
    MeshError
        If a tet is inverted or flat (a deformation folded the mesh).
    """
    grads, vol = hat_gradients(nodes_m, tets)
    scale = np.abs(vol).max() if len(vol) else 1.0
    bad = vol <= 1e-12 * scale
    if np.any(bad):
        raise MeshError(f"{int(bad.sum())} hydrogel tets are inverted or flat (smallest volume "
                        f"{vol.min() * 1e9:.3g} mm^3); the mesh or its deformation is unusable")
    return grads, vol


def unit_stiffness(grads: np.ndarray, vol: np.ndarray) -> np.ndarray:
    """Element stiffness matrices for unit conductivity, ``vol grad phi_i . grad phi_j``, shape ``(M, 16)`` (S)."""
    return (np.einsum("kid,kjd->kij", grads, grads) * vol[:, None, None]).reshape(len(vol), 16)


def triangle_areas_m2(nodes_m: np.ndarray, tris: np.ndarray) -> np.ndarray:
    a, b, c = (nodes_m[tris[:, i]] for i in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


class Topology:
    """Sparsity pattern of the system of one hydrogel mesh topology, with the scatter maps into it.

    Parameters
    ----------
    tets : ndarray, shape (M, 4)
    n_nodes : int
    electrode_tris : list of ndarray, shape (K_l, 3)
        Triangles of each electrode patch (node indices of the hydrogel mesh).
    point_nodes : ndarray of int, shape (n_electrodes,), or None
        Point-electrode mode: the node of each electrode; None for the complete electrode model.

    Raises
    ------
    MeshError
        If a piece of the hydrogel touches no electrode (its potential would float).
    """

    def __init__(self, tets: np.ndarray, n_nodes: int, electrode_tris: list[np.ndarray],
                 point_nodes: np.ndarray | None):
        self.n_nodes = int(n_nodes)
        self.n_tets = len(tets)
        self.n_electrodes = len(electrode_tris)
        self.mode = "point" if point_nodes is not None else "cem"
        self.tets = tets
        L, n = self.n_electrodes, self.n_nodes
        self.tris = np.concatenate(electrode_tris) if electrode_tris else np.zeros((0, 3), np.int64)
        self.tri_electrode = np.concatenate([np.full(len(t), l) for l, t in enumerate(electrode_tris)])
        self.ndof = n + L if self.mode == "cem" else n
        self.electrode_dofs = n + np.arange(L) if self.mode == "cem" else np.asarray(point_nodes, np.int64)
        self._check_connected(electrode_tris)

        rows = [tets[:, _I4].ravel()]
        cols = [tets[:, _J4].ravel()]
        if self.mode == "cem":
            T, lab = self.tris, n + self.tri_electrode
            rows += [T[:, _I3].ravel(), T.ravel(), np.repeat(lab, 3), lab]
            cols += [T[:, _J3].ravel(), np.repeat(lab, 3), T.ravel(), lab]
        g = self.electrode_dofs
        rows.append(np.repeat(g, L))
        cols.append(np.tile(g, L))
        sizes = np.cumsum([0] + [len(r) for r in rows])
        keys = np.concatenate(rows) * self.ndof + np.concatenate(cols)
        uniq, inverse = np.unique(keys, return_inverse=True)
        self.nnz = len(uniq)
        self.indices = (uniq % self.ndof).astype(np.int32)
        self.indptr = np.searchsorted(uniq // self.ndof, np.arange(self.ndof + 1)).astype(np.int32)
        self.map_tet = inverse[: sizes[1]]
        self.map_bnd = inverse[sizes[1]: sizes[-2]]
        self.map_gnd = inverse[sizes[-2]:]
        self.map_gnd_diag = self.map_gnd[np.arange(L) * (L + 1)]

    def _check_connected(self, electrode_tris: list[np.ndarray]) -> None:
        t = self.tets
        r = np.repeat(t, 4, axis=1).ravel()
        c = np.tile(t, (1, 4)).ravel()
        graph = sp.coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(self.n_nodes, self.n_nodes))
        n_comp, label = connected_components(graph, directed=False)
        if n_comp == 1:
            return
        if self.mode == "cem":
            touched = np.unique(label[np.concatenate([e.ravel() for e in electrode_tris])])
        else:
            touched = np.unique(label[self.electrode_dofs])
        used = np.unique(label[t.ravel()])
        floating = np.setdiff1d(used, touched)
        if len(floating):
            raise MeshError(f"the hydrogel mesh has {len(floating)} piece(s) that touch no electrode "
                            f"({n_comp} pieces in all); their potential is undefined")

    def boundary_values(self, nodes_m: np.ndarray, weights: np.ndarray, z_ohm_m2: np.ndarray) -> np.ndarray:
        """Values of the contact terms (B, C, C^T, D) in the order of :attr:`map_bnd` (CEM only).

        ``weights`` is the covered fraction of each electrode triangle (``(K,)``, concatenated over
        electrodes); ``z_ohm_m2`` the contact impedance per electrode.
        """
        if self.mode != "cem":
            return np.zeros(0)
        ac = triangle_areas_m2(nodes_m, self.tris) * weights / z_ohm_m2[self.tri_electrode]  # S per triangle
        third = np.repeat(-ac / 3.0, 3)
        return np.concatenate([(ac[:, None] * _TRI_MASS).ravel(), third, third, ac])

    def matrix(self, data: np.ndarray) -> sp.csr_matrix:
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.ndof, self.ndof))

    def assemble(self, sigma: np.ndarray, unit_k: np.ndarray, bnd_data: np.ndarray) -> sp.csr_matrix:
        """The grounded system matrix for element conductivities ``sigma`` (S/m).

        ``unit_k`` is :func:`unit_stiffness`, ``bnd_data`` the contact terms already scattered
        (``np.bincount(map_bnd, boundary_values)``).
        """
        data = np.bincount(self.map_tet, weights=(unit_k * sigma[:, None]).ravel(), minlength=self.nnz)
        data += bnd_data
        # alpha of the order of the diagonal at the ground rows keeps the modified system well scaled.
        alpha = float(np.mean(data[self.map_gnd_diag]))
        data[self.map_gnd] += alpha
        return self.matrix(data)

    def scatter_boundary(self, values: np.ndarray) -> np.ndarray:
        return np.bincount(self.map_bnd, weights=values, minlength=self.nnz) if len(values) \
            else np.zeros(self.nnz)
