"""Coupled simulation of a density layout, with adjoint gradients of ``V_rel``, the punch force and the gel's
stretch with respect to the density cells.

>>> import numpy as np
>>> from latticeopt import LatticeDesign, MeshSettings
>>> from latticeopt.density import DensityModel
>>> from latticeopt.touches import Touch
>>> model = DensityModel(LatticeDesign(thickness_mm=3), 8, MeshSettings(size_mm=6))
>>> ev = model.evaluate(np.full((8, 8), 0.7), [[Touch(50, 50, 12.0, 2.0)]])
>>> ev.dv_rel_ddensity.shape, bool(ev.v_rel > 0)
((8, 8), True)

For one press, ``V_rel = mean_r |V_r - Vref_r| / |Vref_r|`` depends on the density through the reference
conductivities, the deformed conductivities and the deformed geometry. Its gradient is the sum of

* the electrics at fixed geometry: ``sum_r a_r dV_r/dsigma + b_r dVref_r/dsigma`` with ``a = dV_rel/dV``,
  ``b = dV_rel/dVref`` (:func:`~latticeopt.electrics.sensitivity.weighted_sensitivities`, no extra solve), times
  ``dsigma/drho``;
* the mechanics: ``-lambda^T dR/dm dm/drho`` with ``K_ff lambda_f = dV_rel/du`` (the electrics' derivative with
  respect to the deformed nodes), one solve on the converged tangent
  (:meth:`~latticeopt.mechanics.IndentationSolver.adjoint_solve`, :mod:`latticeopt.mechanics.sensitivity`).

The force and the stretch measure take one more solve each. :class:`DensityEvaluation` keeps the two parts of the
``V_rel`` gradient apart (``electrics`` and ``mechanics``), so each can be checked on its own.
"""

from __future__ import annotations

import contextlib
import hashlib
import pickle
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..coupled import PhysicsSettings
from ..design import LatticeDesign
from ..electrics.forward import ForwardModel
from ..electrics.sensitivity import weighted_sensitivities
from ..errors import ParameterError
from ..execution import run_tasks
from ..linalg import single_threaded_blas
from ..mechanics.indent import IndentationSolver
from ..mechanics.sensitivity import moduli_sensitivity, stretch_pnorm
from ..mesh import MeshSettings
from ..metric import relative_change_partials
from ..touches import Touch
from .connectivity import CellNetwork
from .field import InterpolationLaw, check_density
from .mesh import cell_matrix, density_mesh


@dataclass(frozen=True, eq=False)
class PressResult:
    """One press of a density layout (mm, N, V); gradients per density cell, shape ``(n, n)``."""

    v_rel: float
    force_N: float
    stretch: float
    voltages: np.ndarray
    newton_steps: int
    warm_start: bool
    dv_rel: np.ndarray | None = None
    dv_rel_electrics: np.ndarray | None = None
    dv_rel_mechanics: np.ndarray | None = None
    dforce: np.ndarray | None = None
    dstretch: np.ndarray | None = None
    displacement_mm: np.ndarray | None = field(default=None, repr=False)
    timings: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class DensityEvaluation:
    """A density layout over a list of phantoms: means over the phantoms and each press.

    Attributes
    ----------
    v_rel, force_N, stretch
        Means over the phantoms of ``V_rel``, the total punch force (N) and the gel's smooth maximum stretch.
    dv_rel_ddensity, dforce_ddensity, dstretch_ddensity
        Their gradients with respect to the density cells, shape ``(n, n)`` (None without ``gradient``).
    presses
        One :class:`PressResult` per phantom.
    reference_voltages
        The untouched layout's measurements, shape ``(n_rows,)``.
    """

    v_rel: float
    force_N: float
    stretch: float
    dv_rel_ddensity: np.ndarray | None
    dforce_ddensity: np.ndarray | None
    dstretch_ddensity: np.ndarray | None
    presses: tuple
    reference_voltages: np.ndarray

    def summary(self) -> dict:
        return {"v_rel": self.v_rel, "force_N": self.force_N, "stretch": self.stretch,
                "presses": [{"v_rel": p.v_rel, "force_N": p.force_N, "stretch": p.stretch,
                             "newton_steps": p.newton_steps, "warm_start": p.warm_start, "timings": p.timings,
                             "counts": p.counts}
                            for p in self.presses]}


class _Reference(NamedTuple):
    """The untouched layout of one density, shared by its presses."""

    solver: IndentationSolver  # with this density's moduli
    ref: ForwardModel  # the electrics on the undeformed mesh
    v_ref: np.ndarray  # its voltages (V), shape (n_rows,)
    w_stretch: np.ndarray  # per-tet weights of the stretch measure, shape (n_tets,)
    derivs: tuple  # d(mu, kappa, sigma)/d(rho) per layer tet


class DensityModel:
    """Mesh, cell map, mechanics pattern and electrics topology of density layouts of ``n x n`` cells.

    Parameters
    ----------
    design
        The sensor: size, stack (``thickness_mm`` is the conductive layer's) and electrodes; its layout is
        replaced by the density.
    n_cells
        Density cells per side.
    mesh_settings
        ``size_mm`` and ``layer_cells`` of the mesh (:func:`~latticeopt.density.mesh.density_mesh`).
    physics
        :class:`~latticeopt.coupled.PhysicsSettings`; the gel and silicone moduli are the two ends of the
        interpolation. Only ``conductivity_law = "geometry"``.
    law
        :class:`~latticeopt.density.field.InterpolationLaw`.
    sharp_from : ndarray, shape (n, n), optional
        A density whose jumps become grid lines (:func:`~latticeopt.density.mesh.density_mesh`): what
        ``simulate --density`` passes, so a sharp layout is meshed at its edges. An optimizer leaves it out (its
        mesh stays fixed while the density changes).
    """

    def __init__(self, design: LatticeDesign, n_cells: int, mesh_settings: MeshSettings | None = None,
                 physics: PhysicsSettings | None = None, law: InterpolationLaw | None = None,
                 sharp_from: np.ndarray | None = None):
        t0 = time.perf_counter()
        # what a worker process needs to build the same model (``evaluate(..., jobs > 1)``)
        self._spec = (design, n_cells, mesh_settings, physics, law, sharp_from)
        self._prepared: tuple = (None, None)
        self.physics = physics or PhysicsSettings()
        if self.physics.conductivity_law != "geometry":
            raise ParameterError("conductivity_law", "'geometry' for density layouts", self.physics.conductivity_law)
        self.law = law or InterpolationLaw()
        self.n = check_density(np.zeros((n_cells, n_cells)), "n_cells").shape[0]
        self.mesh = density_mesh(design, self.n, mesh_settings,
                                 None if sharp_from is None else check_density(sharp_from, "sharp_from"))
        self.cells, self.layer_tets = cell_matrix(self.mesh, self.n)
        self._layer_volumes = np.abs(self.mesh.tet_volumes_mm3()[self.layer_tets])  # the stretch measure's weights
        indent = self.physics.indent_settings()
        m = indent.materials
        self._ends = {"mu": (m.silicone.mu_MPa, m.hydrogel.mu_MPa),
                      "kappa": (m.silicone.kappa_MPa, m.hydrogel.kappa_MPa)}
        mu, kappa = m.moduli_MPa(self.mesh.region)
        self._mu0, self._kappa0 = mu, kappa
        self.mechanics = IndentationSolver(self.mesh, indent)
        p = self.physics
        self.electrics = ForwardModel(self.mesh, p.sigma_S_per_m, p.contact_impedance_ohm_m2, current_A=p.current_A)
        if not np.array_equal(self.electrics.gel_tet_ids, self.layer_tets):
            raise AssertionError("the electrics' tets are the conductive layer's")  # pragma: no cover
        self.network = CellNetwork(design, self.n, self.law, p.sigma_S_per_m, p.contact_impedance_ohm_m2)
        self.setup_seconds = time.perf_counter() - t0

    def materials(self, density: np.ndarray):
        """Per-tet ``(mu, kappa, sigma)`` and their derivatives in the tet density, for ``density`` (n, n)."""
        rho = self.cells @ check_density(density).ravel()
        mu, kappa = self._mu0.copy(), self._kappa0.copy()
        mu[self.layer_tets], dmu = self.law.modulus(rho, *self._ends["mu"])
        kappa[self.layer_tets], dkappa = self.law.modulus(rho, *self._ends["kappa"])
        sigma, dsigma = self.law.conductivity(rho, self.physics.sigma_S_per_m)
        return rho, (mu, kappa, sigma), (dmu, dkappa, dsigma)

    def isolation(self, density: np.ndarray, p: float = 8.0) -> tuple[float, np.ndarray]:
        """How far apart the untouched layout puts its electrodes, against the uniform layer, and its gradient.

        ``I = (mean_ij (R_ij / Ru_ij)^p)^(1/p)`` over every pair of electrodes ``i < j`` (120 for 16), ``R_ij`` the
        two-terminal resistance between ``i`` and ``j`` on the network of the layout's cells
        (:class:`~latticeopt.density.connectivity.CellNetwork`: cells joined across their sides only, as the cast
        outline joins them) and ``Ru_ij`` the uniform layer's. About 1 for a connected network; huge when some
        electrodes sit on a piece of gel joined to the others only through the insulating floor, whichever
        electrodes that piece holds. Within a factor ``120^(1/p)`` (1.8 at ``p = 8``) of the worst pair's ratio. A
        bound on it keeps an optimized layout one network. No press; one sparse factorization of ``n^2`` cells.

        Returns
        -------
        value : float
        gradient : ndarray, shape (n, n)
        """
        return self.network.isolation(density, p)

    @single_threaded_blas()
    def evaluate(self, density: np.ndarray, phantoms, gradient: bool = True,
                 warm: list[np.ndarray | None] | None = None, jobs: int = 1) -> DensityEvaluation:
        """``V_rel``, force and stretch of ``density`` over ``phantoms`` (lists of touches), with gradients.

        Parameters
        ----------
        density : ndarray, shape (n, n)
        phantoms
            A list of phantoms, each a list of :class:`~latticeopt.touches.Touch` (or ``(x, y, r, d)``).
        gradient
            Compute the adjoint gradients.
        warm
            Per phantom, a displacement to start Newton from (``PressResult.displacement_mm`` of a nearby
            density), or None.
        jobs
            Worker processes pressing the phantoms side by side (:func:`~latticeopt.execution.run_tasks`; each
            worker builds this model once and keeps it for later calls). Every press is the same computation
            whichever process runs it, so the result does not depend on ``jobs``.
        """
        phantoms = [[t if isinstance(t, Touch) else Touch(*t) for t in touches] for touches in phantoms]
        warm = [None] * len(phantoms) if warm is None else list(warm)
        if len(warm) != len(phantoms):
            raise ParameterError("warm", f"one displacement (or None) per phantom ({len(phantoms)})", len(warm))
        jobs = min(int(jobs), len(phantoms))
        if jobs <= 1:
            prepared = self._prepare(density)
            v_ref = prepared.v_ref
            presses = [self._press(prepared, touches, u0, gradient) for touches, u0 in zip(phantoms, warm)]
        else:
            presses = [None] * len(phantoms)
            tasks = ((k, (self._spec, density, touches, u0, gradient))
                     for k, (touches, u0) in enumerate(zip(phantoms, warm)))
            with contextlib.closing(run_tasks(_press_in_worker, tasks, jobs=jobs)) as done:
                for k, (press, reference) in done:
                    presses[k], v_ref = press, reference

        def mean(name):
            return None if not gradient else np.mean([getattr(p, name) for p in presses], axis=0)

        return DensityEvaluation(
            v_rel=float(np.mean([p.v_rel for p in presses])), force_N=float(np.mean([p.force_N for p in presses])),
            stretch=float(np.mean([p.stretch for p in presses])), dv_rel_ddensity=mean("dv_rel"),
            dforce_ddensity=mean("dforce"), dstretch_ddensity=mean("dstretch"), presses=tuple(presses),
            reference_voltages=v_ref)

    @single_threaded_blas()
    def reference_voltages(self, density: np.ndarray) -> np.ndarray:
        """The untouched layout's measurements (V), shape ``(n_rows,)``: the rows V_rel divides by. One electrics
        solve, no press."""
        return self._prepare(density).v_ref.copy()

    def _prepare(self, density: np.ndarray) -> _Reference:
        """The untouched layout of ``density`` (what :meth:`_press` needs), kept for the last density: the random
        phantoms and the probes of one iterate share it."""
        key = np.asarray(density, dtype=float).tobytes()
        if self._prepared[0] != key:
            rho, (mu, kappa, sigma), derivs = self.materials(density)
            ref = self.electrics.with_conductivity(sigma)
            w_stretch = np.zeros(self.mesh.n_tets)
            w_stretch[self.layer_tets] = rho * self._layer_volumes
            self._prepared = key, _Reference(self.mechanics.with_moduli(mu, kappa), ref, ref.voltages, w_stretch,
                                             derivs)
        return self._prepared[1]

    def _to_cells(self, per_tet: np.ndarray) -> np.ndarray:
        return (self.cells.T @ per_tet).reshape(self.n, self.n)

    def _press(self, prepared: _Reference, touches, u0, gradient) -> PressResult:
        solver, ref, v_ref, w_stretch, derivs = prepared
        t0 = time.perf_counter()
        ind = solver.solve(touches, u0=u0)
        t1 = time.perf_counter()
        deformed = ref.with_nodes(ind.deformed_mesh.nodes_mm)
        v = deformed.voltages
        v_rel, a, b = relative_change_partials(v, v_ref, self.physics.measurement_floor_rel)
        st = ind.state
        u = ind.displacement_mm
        p_s = self.law.stretch_exponent
        stretch, dS_du, dS_dw = stretch_pnorm(st.op, u, w_stretch, p_s)
        force = float(np.sum(ind.forces_N))
        t2 = time.perf_counter()
        counts = {"newton_steps": ind.newton_steps, "load_steps": ind.load_steps,
                  "factorizations": ind.solver["n_factorizations"],
                  "krylov_iterations": ind.solver["krylov_iterations"]}
        out = dict(v_rel=v_rel, force_N=force, stretch=stretch, voltages=v, newton_steps=ind.newton_steps,
                   warm_start=st.warm_start, displacement_mm=u, counts=counts)
        if not gradient:
            return PressResult(**out, timings={"mechanics": t1 - t0, "electrics": t2 - t1, "total": t2 - t0})
        dmu, dkappa, dsigma = derivs
        lt = self.layer_tets
        # a, b: the partials of V_rel in V and in Vref (relative_change_partials above)
        ds_def, dx_def = weighted_sensitivities(deformed, a)
        ds_ref, _ = weighted_sensitivities(ref, b)
        electrics = self._to_cells((ds_def + ds_ref) * dsigma)
        g_u = np.zeros((self.mesh.n_nodes, 3))
        g_u[ref.node_ids] = dx_def

        before = solver.linear_counts
        lam = solver.adjoint_solve(ind, g_u.ravel())
        # total force = sum over the held top nodes of -R_z: c = -e_z there
        c = np.zeros(3 * self.mesh.n_nodes)
        for nodes in st.contact_nodes:
            c[3 * nodes + 2] = -1.0
        y = solver.adjoint_solve(ind, np.zeros_like(c), values=c[st.dofs])
        lam_s = solver.adjoint_solve(ind, dS_du)
        s_mu, s_kappa = moduli_sensitivity(st.op, u, np.stack([lam, y, lam_s]))
        mechanics, dforce, dstretch_m = (self._to_cells(s_mu[k, lt] * dmu + s_kappa[k, lt] * dkappa) for k in range(3))
        mechanics = -mechanics
        dstretch = self._to_cells(dS_dw[lt] * self._layer_volumes) - dstretch_m
        t3 = time.perf_counter()
        after = solver.linear_counts
        counts.update(adjoint_krylov_iterations=after["krylov_iterations"] - before["krylov_iterations"],
                      adjoint_factorizations=after["factorizations"] - before["factorizations"])
        return PressResult(**out, dv_rel=electrics + mechanics, dv_rel_electrics=electrics,
                           dv_rel_mechanics=mechanics, dforce=dforce, dstretch=dstretch,
                           timings={"mechanics": t1 - t0, "electrics": t2 - t1, "gradient": t3 - t2,
                                    "total": t3 - t0})


#: The model a worker process built for the last ``spec`` it was sent (``evaluate(..., jobs > 1)``).
_WORKER_MODEL: dict = {}


def _press_in_worker(spec: tuple, density: np.ndarray, touches: list, u0, gradient: bool):
    """One press in a worker process: ``(PressResult, reference voltages)``."""
    key = hashlib.sha256(pickle.dumps(spec)).hexdigest()
    if key not in _WORKER_MODEL:
        _WORKER_MODEL.clear()
        _WORKER_MODEL[key] = DensityModel(*spec)
    model = _WORKER_MODEL[key]
    prepared = model._prepare(density)
    return model._press(prepared, touches, u0, gradient), prepared.v_ref
