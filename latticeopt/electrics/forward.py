"""Steady current flow in the hydrogel with 16 electrodes: the forward model.

``div(sigma grad u) = 0`` in the hydrogel only (the silicone insulates: no flux through the rest of the
hydrogel's boundary), complete electrode model (CEM) on the electrode patches, P1 elements, one
factorization per state and every drive solved against it. See :mod:`latticeopt.electrics.assembly` for
the equations and the ground.

Conventions
-----------
* Ground: the electrode potentials sum to zero (point mode: the potentials of the electrode nodes).
  Measured differences do not depend on it.
* Drive ``d`` injects ``current_A * drive_currents[d, e]`` into electrode ``e`` (adjacent drive: +I into
  the first electrode of the pair, -I, i.e. out, at the second), so the driving electrode sits at the
  higher potential.
* A measurement row reads ``measure[r] @ U`` (pair ``[N, M]``: ``U[N] - U[M]`` as pyEIT).
* Public lengths are mm; the solver converts the node coordinates to m once, so potentials are in V,
  currents in A, conductivities in S/m, contact impedance in ohm m^2, Jacobians in V / (S/m).

Defaults (documented choices, not measured on the paper's sensor)
-----------------------------------------------------------------
* ``sigma = 1 S/m``: LiCl polyacrylamide hydrogels conduct about 1-10 S/m (reported ranges for such gels); e.g. a
  PAAm/cellulose/LiCl gel keeps 2.25 S/m even at -40 C (Chem. Eng. J. 2021, doi:10.1016/j.cej.2020.127306).
  The paper does not report its gel's conductivity; taking the low end is our assumption (its gel holds
  37 wt% ethylene glycol, which lowers ionic mobility).
* ``z_c = 2e-3 ohm m^2``: Cheng, Isaacson, Newell and Gisser (IEEE TBME 36:918, 1989) fitted effective
  contact impedances of 7.5e-4 to 5.8e-3 ohm m^2 for metal electrodes on saline baths of 3.4 to 0.35 S/m,
  with ``z_c sigma`` between 2.0 and 2.5 mm in all four baths; at ``sigma = 1 S/m`` that is about 2e-3.
  With 4 mm electrodes the dimensionless contact number ``z_c sigma / w = 0.5``
  (:attr:`ForwardModel.contact_number`). The adjacent protocol never reads a driving electrode, so
  ``z_c`` acts only through the current paths: the spread under the drive pair and the shunting of
  current through the passive electrodes.
* ``current = 1 mA``: a usual EIT injection amplitude; voltages scale linearly with it and ``V_rel``
  does not depend on it.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from .. import _validate as v
from ..errors import MeshError, ParameterError
from ..linalg import BACKENDS, SymmetricSolver, pardiso_available
from ..mesh.tetmesh import TetMesh, electrode_name
from .assembly import Topology, element_geometry, unit_stiffness
from .protocol import Protocol

log = logging.getLogger(__name__)

DEFAULT_SIGMA_S_PER_M = 1.0
DEFAULT_CONTACT_IMPEDANCE_OHM_M2 = 2e-3
DEFAULT_CURRENT_A = 1e-3
ELECTRODE_MODES = ("cem", "point")
MM = 1e-3


class _SharedSolver:
    """A factorization shared by models of one topology; remembers whose matrix it currently holds."""

    def __init__(self, A, backend: str):
        self.solver = SymmetricSolver(A, positive_definite=True, backend=backend)
        self.owner: object = None

    def factorize(self, A, owner: object) -> None:
        if self.owner is not owner:
            self.solver.refactor(A)
            self.owner = owner


def _point_nodes(mesh: TetMesh, n_e: int) -> np.ndarray:
    """Per electrode, the patch node nearest to the patch's area-weighted centroid."""
    out = np.empty(n_e, dtype=np.int64)
    for k in range(n_e):
        tri = mesh.facets[electrode_name(k + 1)]
        p = mesh.nodes_mm[tri]
        w = mesh.weights(electrode_name(k + 1)) * np.linalg.norm(
            np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        centre = (p.mean(axis=1) * w[:, None]).sum(0) / w.sum()
        cand = np.unique(tri)
        out[k] = cand[np.argmin(np.linalg.norm(mesh.nodes_mm[cand] - centre, axis=1))]
    if len(np.unique(out)) != n_e:
        raise MeshError("two electrodes share their point node; the mesh is too coarse for point electrodes")
    return out


class ForwardModel:
    """Assembled and factorized current-flow model of one hydrogel state, with all drives solved.

    Parameters
    ----------
    mesh
        A full :class:`TetMesh` (restricted internally to its hydrogel tets) or a hydrogel sub-mesh; node
        coordinates are arbitrary (deformed meshes are solved the same way). Needs facet sets
        ``electrode_1`` ... ``electrode_n`` on the hydrogel.
    sigma_S_per_m
        Conductivity (S/m): a scalar or one value per hydrogel tet (shape ``(n_gel_tets,)``, in the order of
        :attr:`gel_tet_ids`).
    contact_impedance_ohm_m2
        Contact impedance ``z_c`` (ohm m^2), scalar or one per electrode; ignored in point mode.
    protocol
        Drive/measurement :class:`Protocol`; default :meth:`Protocol.adjacent` for the mesh's electrodes.
    current_A
        Drive current amplitude (A).
    electrode_mode
        ``"cem"`` (complete electrode model) or ``"point"`` (each electrode one node, no contact impedance;
        for exact comparison with pyEIT).
    backend
        Sparse solver backend of :class:`~latticeopt.linalg.SymmetricSolver`.

    Attributes
    ----------
    mesh : TetMesh
        The hydrogel mesh solved on.
    node_ids, gel_tet_ids : ndarray of int
        Index in the input mesh of every hydrogel node / tet.
    timings : dict
        Seconds spent in ``geometry``, ``assembly``, ``factorization``, ``solve`` and ``total`` (plus
        ``restrict`` and ``setup`` for a new topology).
    """

    def __init__(self, mesh: TetMesh, sigma_S_per_m=DEFAULT_SIGMA_S_PER_M,
                 contact_impedance_ohm_m2=DEFAULT_CONTACT_IMPEDANCE_OHM_M2, protocol: Protocol | None = None,
                 current_A: float = DEFAULT_CURRENT_A, electrode_mode: str = "cem", backend: str = "auto",
                 _reuse: ForwardModel | None = None):
        t0 = time.perf_counter()
        self.timings: dict[str, float] = {}
        self.electrode_mode = v.choice("electrode_mode", electrode_mode, ELECTRODE_MODES)
        self.current_A = v.real("current_A", current_A, lo=0, lo_open=True)
        if _reuse is not None:
            self.mesh, self.node_ids, self.gel_tet_ids = mesh, _reuse.node_ids, _reuse.gel_tet_ids
        else:
            if not isinstance(mesh, TetMesh):
                raise ParameterError("mesh", "a TetMesh", type(mesh).__name__)
            from ..design import REGION_IDS

            self.gel_tet_ids = np.nonzero(mesh.region == REGION_IDS["hydrogel"])[0]
            if len(self.gel_tet_ids) == 0:
                raise MeshError("the mesh has no hydrogel tets")
            tr = time.perf_counter()
            self.mesh, self.node_ids = mesh.restrict(("hydrogel",))
            self.timings["restrict"] = time.perf_counter() - tr
        n_e = self.mesh.n_electrodes
        if n_e < 2:
            raise MeshError(f"the hydrogel mesh carries {n_e} electrode facet sets; at least 2 are needed")
        self.protocol = protocol if protocol is not None else Protocol.adjacent(n_e)
        if not isinstance(self.protocol, Protocol) or self.protocol.n_electrodes != n_e:
            raise ParameterError("protocol", f"a Protocol for {n_e} electrodes", self.protocol)
        self.sigma = self._check_sigma(sigma_S_per_m)
        self.contact_impedance_ohm_m2 = self._check_zc(contact_impedance_ohm_m2, n_e)
        self.backend = v.choice("backend", backend, BACKENDS)
        self._token = object()  # identifies this model's matrix in the shared factorization

        if _reuse is not None:
            self._topology, self._shared, self.point_nodes = _reuse._topology, _reuse._shared, _reuse.point_nodes
        else:
            ts = time.perf_counter()
            pardiso_available()  # imports pypardiso/MKL once per process here, not inside the factorization time
            tris = self.mesh.electrode_facets()
            empty = [k + 1 for k, t in enumerate(tris) if len(t) == 0]
            if empty:
                raise MeshError(f"electrodes {empty} have no triangles on the hydrogel")
            self.point_nodes = _point_nodes(self.mesh, n_e) if self.electrode_mode == "point" else None
            self._topology = Topology(self.mesh.tets, self.mesh.n_nodes, tris, self.point_nodes)
            self._shared = None
            self.timings["setup"] = time.perf_counter() - ts

        tg = time.perf_counter()
        if _reuse is not None and _reuse.mesh is self.mesh and np.array_equal(
                _reuse.contact_impedance_ohm_m2, self.contact_impedance_ohm_m2):  # only sigma changed
            self._grads, self._vol, self._unit_k, self._bnd = _reuse._grads, _reuse._vol, _reuse._unit_k, _reuse._bnd
        else:
            nodes_m = self.mesh.nodes_mm * MM
            self._grads, self._vol = element_geometry(nodes_m, self.mesh.tets)
            self._unit_k = unit_stiffness(self._grads, self._vol)
            weights = np.concatenate([self.mesh.weights(electrode_name(k + 1)) for k in range(n_e)])
            self._bnd = self._topology.scatter_boundary(
                self._topology.boundary_values(nodes_m, weights, self.contact_impedance_ohm_m2))
        self.timings["geometry"] = time.perf_counter() - tg

        ta = time.perf_counter()
        self._A = self._topology.assemble(self.sigma, self._unit_k, self._bnd)
        self.timings["assembly"] = time.perf_counter() - ta

        tf = time.perf_counter()
        if self._shared is None:
            self._shared = _SharedSolver(self._A, backend)
            self._shared.owner = self._token
        else:
            self._shared.factorize(self._A, self._token)
        self.timings["factorization"] = time.perf_counter() - tf

        ts = time.perf_counter()
        # One solve per electrode for the current pattern e_l - 1/n: every zero-sum current (drives and the
        # adjoint "currents" of the measurement rows) is a combination of these columns.
        rhs = np.zeros((self._topology.ndof, n_e))
        rhs[self._topology.electrode_dofs, :] = np.eye(n_e) - 1.0 / n_e
        self._basis = np.asarray(self._shared.solver.solve(rhs))  # V per A, shape (ndof, n_e)
        self.timings["solve"] = time.perf_counter() - ts
        self.timings["total"] = time.perf_counter() - t0

    # -- checks -----------------------------------------------------------------------------------
    def _check_sigma(self, sigma) -> np.ndarray:
        m = self.mesh.n_tets
        if np.ndim(sigma) == 0:
            return np.full(m, v.real("sigma_S_per_m", sigma, lo=0, lo_open=True))
        s = np.asarray(sigma, dtype=float)
        if s.shape != (m,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ParameterError("sigma_S_per_m", f"a positive scalar or {m} positive finite values "
                                 "(one per hydrogel tet)", f"array of shape {s.shape}, min {np.min(s):g}")
        return s.copy()

    @staticmethod
    def _check_zc(zc, n_e: int) -> np.ndarray:
        if np.ndim(zc) == 0:
            return np.full(n_e, v.real("contact_impedance_ohm_m2", zc, lo=0, lo_open=True))
        z = np.asarray(zc, dtype=float)
        if z.shape != (n_e,) or not np.all(np.isfinite(z)) or np.any(z <= 0):
            raise ParameterError("contact_impedance_ohm_m2", f"a positive scalar or {n_e} positive values",
                                 f"array of shape {z.shape}")
        return z.copy()

    # -- derived models ---------------------------------------------------------------------------
    def with_conductivity(self, sigma_S_per_m) -> ForwardModel:
        """The same geometry with new conductivities: reuses the geometry, pattern and symbolic factorization."""
        return ForwardModel(self.mesh, sigma_S_per_m, self.contact_impedance_ohm_m2, self.protocol,
                            self.current_A, self.electrode_mode, self.backend, _reuse=self)

    def with_nodes(self, nodes_mm: np.ndarray, sigma_S_per_m=None) -> ForwardModel:
        """The same topology on moved nodes (a deformed state); reuses the pattern and symbolic factorization.

        Parameters
        ----------
        nodes_mm : ndarray, shape (n_input_nodes, 3) or (n_gel_nodes, 3)
            New coordinates of the input mesh's nodes (mapped through :attr:`node_ids`) or of the hydrogel
            mesh's nodes.
        sigma_S_per_m
            New conductivities; default: keep this model's.
        """
        nodes = np.asarray(nodes_mm, dtype=float)
        if nodes.ndim == 2 and nodes.shape[1] == 3 and len(nodes) != self.mesh.n_nodes \
                and len(nodes) > self.node_ids.max():
            nodes = nodes[self.node_ids]
        if nodes.shape != self.mesh.nodes_mm.shape:
            raise ParameterError("nodes_mm", f"shape ({self.mesh.n_nodes}, 3) (hydrogel nodes) or the input "
                                 "mesh's node array", f"shape {np.shape(nodes_mm)}")
        sigma = self.sigma if sigma_S_per_m is None else sigma_S_per_m
        return ForwardModel(self.mesh.with_nodes(nodes), sigma, self.contact_impedance_ohm_m2, self.protocol,
                            self.current_A, self.electrode_mode, self.backend, _reuse=self)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """Solve the grounded system for extra right-hand sides, shape ``(n_dof, k)`` or ``(n_dof,)``.

        Unknowns are the hydrogel node potentials followed (CEM) by the electrode potentials. Refactorizes
        (numerically only) if a sibling model holds the shared factorization.
        """
        self._shared.factorize(self._A, self._token)
        return self._shared.solver.solve(rhs)

    # -- results ----------------------------------------------------------------------------------
    @property
    def n_electrodes(self) -> int:
        return self.protocol.n_electrodes

    @property
    def n_dof(self) -> int:
        return self._topology.ndof

    @property
    def transfer_matrix(self) -> np.ndarray:
        """Electrode potentials per unit current pattern ``e_l - 1/n`` (ohm), shape ``(n_e, n_e)``, symmetric."""
        return self._basis[self._topology.electrode_dofs]

    @property
    def pair_resistances(self) -> np.ndarray:
        """Two-terminal transfer resistance (ohm) of every electrode pair ``i < j``, shape ``(n_e (n_e - 1) / 2,)`` in
        ``numpy.triu_indices(n_e, 1)`` order: the voltage between ``i`` and ``j`` per ampere injected at ``i`` and
        taken out at ``j`` (CEM: through both contact impedances). ``e_i - e_j`` is a combination of the solved
        current patterns, so it costs no solve: ``R_ij = T_ii + T_jj - T_ij - T_ji``."""
        T = self.transfer_matrix
        i, j = np.triu_indices(self.n_electrodes, 1)
        return T[i, i] + T[j, j] - T[i, j] - T[j, i]

    @property
    def electrode_potentials(self) -> np.ndarray:
        """Electrode potentials (V) under each drive, shape ``(n_drives, n_electrodes)``."""
        return self.current_A * self.protocol.drive_currents @ self.transfer_matrix.T

    @property
    def voltages(self) -> np.ndarray:
        """Measurements (V), shape ``(n_rows,)`` in protocol row order."""
        U = self.electrode_potentials
        return np.einsum("re,re->r", self.protocol.measure, U[self.protocol.row_drive])

    @property
    def independent_voltages(self) -> np.ndarray:
        """The reciprocity-independent measurements (V), shape ``(len(protocol.independent),)``."""
        return self.voltages[self.protocol.independent]

    @property
    def node_potentials(self) -> np.ndarray:
        """Potential (V) at every hydrogel node under each drive, shape ``(n_drives, n_gel_nodes)``."""
        n = self.mesh.n_nodes
        return self.current_A * self.protocol.drive_currents @ self._basis[:n].T

    def reciprocity_error(self) -> float:
        """``max |V_r - s V_partner| / max |V|`` over rows with a reciprocal partner (0 if none)."""
        p = self.protocol
        has = p.reciprocal >= 0
        if not np.any(has):
            return 0.0
        V = self.voltages
        return float(np.max(np.abs(V[has] - p.reciprocal_sign[has] * V[p.reciprocal[has]])) / np.max(np.abs(V)))

    def basis_gradients(self) -> np.ndarray:
        """Potential gradient (V/m per A) of each basis current pattern in each tet, shape ``(M, n_e, 3)``."""
        phi = self._basis[self.mesh.tets]  # (M, 4, n_e)
        return np.einsum("kid,kil->kld", self._grads, phi)

    def current_density(self, drive: int = 0) -> np.ndarray:
        """Current density ``-sigma grad u`` (A/m^2) in each hydrogel tet under ``drive``, shape ``(M, 3)``."""
        d = v.integer("drive", drive, lo=0, hi=self.protocol.n_drives - 1)
        phi = self._basis[self.mesh.tets] @ (self.current_A * self.protocol.drive_currents[d])  # (M, 4)
        return -self.sigma[:, None] * np.einsum("kid,ki->kd", self._grads, phi)

    def jacobian(self) -> np.ndarray:
        """``dV / d sigma_k`` (V per S/m) by the adjoint method, shape ``(n_rows, n_gel_tets)``."""
        from .jacobian import adjoint_jacobian

        return adjoint_jacobian(self.basis_gradients(), self._vol, self.protocol, self.current_A)

    def pixel_matrix(self, n: int = 48, extent_mm: tuple[float, float, float, float] | None = None):
        """Sparse ``(n_gel_tets, n * n)`` matrix: exact volume fraction of each tet above each pixel.

        See :func:`latticeopt.electrics.pixels.pixel_matrix`; the extent defaults to the design's
        ``[0, L] x [0, L]`` (from ``mesh.info``) or the hydrogel's bounding box.
        """
        from .pixels import default_extent_mm, pixel_matrix

        ext = default_extent_mm(self.mesh) if extent_mm is None else extent_mm
        return pixel_matrix(self.mesh.nodes_mm, self.mesh.tets, n, ext)

    def pixel_jacobian(self, n: int = 48, extent_mm=None) -> np.ndarray:
        """Jacobian on an ``n x n`` pixel grid (V per S/m), shape ``(n_rows, n * n)``, pixel ``iy * n + ix``.

        Column ``p`` is ``sum_k J[:, k] F[k, p]`` with ``F`` from :meth:`pixel_matrix`: the sensitivity to a
        conductivity change of all hydrogel beneath pixel ``p``.
        """
        F = self.pixel_matrix(n, extent_mm)
        return np.asarray((F.T @ self.jacobian().T).T)

    @property
    def electrode_width_mm(self) -> float:
        """Electrode width from the design in ``mesh.info``, else the square root of the mean patch area."""
        design = self.mesh.info.get("design") or {}
        if "electrode_width_mm" in design:
            return float(design["electrode_width_mm"])
        return float(np.sqrt(np.mean(self.mesh.electrode_areas_mm2())))

    @property
    def contact_number(self) -> float:
        """Dimensionless ``z_c sigma / w`` (mean z_c, mean sigma, electrode width w); 0 in point mode."""
        if self.electrode_mode == "point":
            return 0.0
        return float(np.mean(self.contact_impedance_ohm_m2) * np.mean(self.sigma) / (self.electrode_width_mm * MM))

    def summary(self) -> dict:
        """JSON-ready description of the model and its timings."""
        return {"electrode_mode": self.electrode_mode, "protocol": self.protocol.summary(),
                "gel_nodes": self.mesh.n_nodes, "gel_tets": self.mesh.n_tets, "dof": self.n_dof,
                "nnz": self._topology.nnz, "sigma_S_per_m_mean": float(np.mean(self.sigma)),
                "contact_impedance_ohm_m2": self.contact_impedance_ohm_m2.tolist(), "current_A": self.current_A,
                "contact_number": self.contact_number, "solver_backend": self._shared.solver.backend,
                "timings_s": dict(self.timings)}
