"""Settings and result of an indentation (frozen dataclasses; the solver is :mod:`.indent`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ..linalg import BACKENDS, PRECISIONS
from ..mesh.tetmesh import TetMesh
from .assembly import VOLUMETRIC
from .indenters import IN_PLANE, INDENTERS, PUNCH_EDGES, check_edge_radius
from .materials import Materials

__all__ = ["DOUBLE_ABOVE_KAPPA_OVER_MU", "METHODS", "Converged", "IndentSettings", "IndentationResult",
           "check_rescue_newton"]

METHODS = ("newton", "newton-krylov")
#: ``precision="auto"`` factorizes in double precision when some material's ``kappa / mu`` exceeds this
#: (``nu`` above about 0.4975; the default ``nu = 0.49`` has ``kappa / mu = 50`` and stays in single).
DOUBLE_ABOVE_KAPPA_OVER_MU = 200.0


def check_rescue_newton(rescue_newton, name: str = "rescue_newton") -> int:
    """``rescue_newton`` validated: an integer from 0 (no rescue) to 1000 iterations per load step."""
    return v.integer(name, rescue_newton, lo=0, hi=1000)


@dataclass(frozen=True)
class IndentSettings:
    """How to indent.

    Parameters
    ----------
    materials
        Neo-Hookean parameters per region.
    indenter
        ``"flat"`` (flat-ended punch, default) or ``"sphere"`` (hemispherical tip of the touch radius).
    in_plane
        Flat punch only: ``"bonded"`` (no slip, default) or ``"frictionless"``. The sphere is frictionless.
    punch_edge
        Flat punch only: ``"conforming"`` (default: top-surface nodes near each rim are moved onto it before
        the solve, so results move continuously with the touch; see
        :func:`~latticeopt.mechanics.indenters.conform_punch_edges`) or ``"nodal"`` (the disc holds the top
        nodes inside it, a staircase of cells).
    edge_radius_mm
        Flat punch only: radius of the punch's rounded rim (mm, ``0 <= e <= 20``); 0 (default): a sharp edge. The
        flat face ``rho <= r - e`` holds the top nodes as ``in_plane`` says, the rounding touches the nodes under
        it without friction (:mod:`latticeopt.mechanics.indenters`); a touch narrower than ``e`` gets a
        hemispherical tip. Its effect on V_rel and on deep presses: ``docs/verification.md``.
    volumetric
        ``"patch"`` (mean dilatation per hexahedral cell, locking-free, default) or ``"element"`` (plain P1).
    max_step_mm
        Largest depth increment of the deepest touch per load step (mm). With exact Newton 0.75 mm measured
        fastest (2.2-2.5x faster than 1.0 on six random phantoms at 2 mm); with the default inexact Newton
        1.0 mm is 5-12 % faster than 0.75 and 0.6 is 6-10 % slower (six random phantoms, two seeds).
    min_step_mm
        Step halving gives up below this increment (mm), after 4 failed load steps in a row (a sixteenth of
        the increment that failed first), or after 3 failed attempts at one depth with accepted halves between
        them.
    max_newton
        Newton iterations per load step before the step counts as failed; None (default): 40, or 60 when some
        material's ``kappa / mu`` exceeds :data:`DOUBLE_ABOVE_KAPPA_OVER_MU`. Where the tangent is indefinite the
        iterations wander (the energy line search lets the residual rise tenfold) before Newton's fast
        convergence returns. At nu = 0.49 the deepest paper presses into t = 1 need up to 17 in their last load
        step: with 12, phantom 1:13 on w = 2, t = 1 crept to within 6 um of its 4.98 mm and failed after 12
        halvings; with 40 it converges after one (docs/verification.md). Near incompressibility the w = 0,
        t = 3 press to 4 mm at hydrogel nu = 0.4999 failed its last step after 7 halvings with 12 and converged
        with 30 (194 s); three two-touch presses of the paper phantoms stalled within 3 um of their final depth
        with 30 and converged with 60.
    rescue_newton
        A press about to give up (by the rules of ``min_step_mm``) is rescued once: its failed step is tried
        again with indefinite tangents projected (each patch block's negative eigenvalues set to 0) instead of
        shifted, and with up to this many iterations per load step from then on; if that step fails too, it gives
        up. None (default): 4 x ``max_newton``; 0: no rescue. The 8.9 mm presses into the 9 mm stack under a sharp
        punch that give up without it needed 55 and 102 projected iterations in one step (docs/verification.md).
        Presses that converge without it are untouched.
    rtol
        Converged when ``|R_free| <= rtol * |R_constrained|`` ...
    atol_N
        ... or ``|R_free| <= atol_N`` (N).
    step_rtol
        The looser ``rtol`` of intermediate load steps (only the final state must be accurate; each step's
        start is re-equilibrated anyway). 3e-2 against 1e-3: 11-12 % faster on six random phantoms at 2 mm
        (two seeds), with the same failures on 24 phantoms of four extreme designs; with exact Newton 1e-1
        once failed a phantom that 1e-3 solved.
    method
        ``"newton-krylov"`` (default): inexact Newton. Each iteration solves the current tangent by GMRES
        preconditioned by the latest factorization, and refactorizes only when GMRES would need more than
        ``max_krylov`` iterations (the factorization has gone stale). ``"newton"``: a new factorization every
        iteration (exact Newton), the reference the tests check quadratic convergence on. Measured at the 2 mm mesh
        (``benchmarks/bench_indent.py``, ``docs/performance.md``): 6.5 s against 14.3 s for one 4 mm press.
        Limited-memory BFGS and a secant predictor were measured too (31.4 s, and slower) and are not offered.
    krylov_rtol
        ``"newton-krylov"``: GMRES stops at this relative residual (forcing term), or at half the Newton
        tolerance if that is looser.
    max_krylov
        ``"newton-krylov"``: GMRES iterations (back-substitutions) before a refactorization; GMRES gives up
        earlier when its rate so far cannot reach the tolerance within them.
    backend
        Sparse solver: ``"auto"`` (PARDISO if installed), ``"pardiso"`` or ``"scipy"``.
    precision
        Factorization in ``"single"`` or ``"double"`` precision, or ``"auto"`` (default): single unless some
        material's ``kappa / mu`` exceeds :data:`DOUBLE_ABOVE_KAPPA_OVER_MU` (the tangent and residual are always
        assembled in double). The factorization only steers the iterations; convergence is judged on the
        double-precision residual, so the converged state is the same to ``rtol``
        (``tests/test_mechanics_indent.py``), at about 0.55x the factorization time. Near incompressibility
        float32 is not enough: the tangent's condition number grows with ``kappa / mu`` and at ``nu = 0.499``
        (``kappa / mu = 500``) single-precision Cholesky of the converged, positive definite tangent of the
        w = 4, t = 3 press already failed (a spurious negative pivot; its LDL^T reported 4 negative
        eigenvalues where the double-precision one reported none) and the press stalled at 3.75 mm.
    """

    materials: Materials = field(default_factory=Materials)
    indenter: str = "flat"
    in_plane: str = "bonded"
    punch_edge: str = "conforming"
    volumetric: str = "patch"
    edge_radius_mm: float = 0.0
    max_step_mm: float = 1.0
    min_step_mm: float = 0.01
    max_newton: int | None = None
    rescue_newton: int | None = None
    rtol: float = 1e-6
    atol_N: float = 1e-10
    step_rtol: float = 3e-2
    method: str = "newton-krylov"
    krylov_rtol: float = 0.1
    max_krylov: int = 16
    backend: str = "auto"
    precision: str = "auto"

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not isinstance(self.materials, Materials):
            raise ParameterError("materials", "a latticeopt.mechanics.Materials", self.materials)
        set_(self, "indenter", v.choice("indenter", self.indenter, INDENTERS))
        set_(self, "in_plane", v.choice("in_plane", self.in_plane, IN_PLANE))
        set_(self, "punch_edge", v.choice("punch_edge", self.punch_edge, PUNCH_EDGES))
        set_(self, "volumetric", v.choice("volumetric", self.volumetric, VOLUMETRIC))
        set_(self, "edge_radius_mm", check_edge_radius(self.edge_radius_mm, self.indenter))
        set_(self, "backend", v.choice("backend", self.backend, BACKENDS))
        set_(self, "precision", v.choice("precision", self.precision, PRECISIONS + ("auto",)))
        set_(self, "max_step_mm", v.real("max_step_mm", self.max_step_mm, lo=0, lo_open=True))
        set_(self, "min_step_mm", v.real("min_step_mm", self.min_step_mm, lo=0, lo_open=True, hi=self.max_step_mm))
        if self.max_newton is None:
            set_(self, "max_newton", 60 if self._max_kappa_over_mu() > DOUBLE_ABOVE_KAPPA_OVER_MU else 40)
        set_(self, "max_newton", v.integer("max_newton", self.max_newton, lo=1, hi=200))
        if self.rescue_newton is None:
            set_(self, "rescue_newton", 4 * self.max_newton)
        set_(self, "rescue_newton", check_rescue_newton(self.rescue_newton))
        set_(self, "rtol", v.real("rtol", self.rtol, lo=0, lo_open=True, hi=1e-1))
        set_(self, "atol_N", v.real("atol_N", self.atol_N, lo=0))
        set_(self, "step_rtol", v.real("step_rtol", self.step_rtol, lo=0, lo_open=True, hi=1e-1))
        set_(self, "method", v.choice("method", self.method, METHODS))
        set_(self, "krylov_rtol", v.real("krylov_rtol", self.krylov_rtol, lo=0, lo_open=True, hi=0.5))
        set_(self, "max_krylov", v.integer("max_krylov", self.max_krylov, lo=3, hi=200))

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    @property
    def factorization_precision(self) -> str:
        """``precision`` with ``"auto"`` resolved against the materials' ``kappa / mu``."""
        if self.precision != "auto":
            return self.precision
        return "double" if self._max_kappa_over_mu() > DOUBLE_ABOVE_KAPPA_OVER_MU else "single"

    def _max_kappa_over_mu(self) -> float:
        m = self.materials
        return max(mat.kappa_MPa / mat.mu_MPa for mat in (m.silicone, m.hydrogel))


@dataclass(frozen=True, eq=False)
class Converged:
    """The converged state of an indentation, what an adjoint solve needs (see
    :meth:`~latticeopt.mechanics.IndentationSolver.adjoint_solve`).

    Attributes
    ----------
    op
        The phantom's :class:`~latticeopt.mechanics.assembly.NeoHookeanOperator` (its reference nodes).
    evaluation
        Residual and tangent at the converged displacement.
    dofs
        The constrained DOFs (bottom face and indenters), sorted.
    contact_nodes
        Top nodes held by each indenter.
    warm_start
        True when the press converged in one step from a given start (``solve(..., u0=...)``).
    """

    op: object
    evaluation: object
    dofs: np.ndarray
    contact_nodes: tuple
    warm_start: bool = False


@dataclass(frozen=True, eq=False)
class IndentationResult:
    """Outcome of one indentation (mm, N).

    Attributes
    ----------
    touches
        The validated touches.
    displacement_mm
        Nodal displacement from the reference configuration, shape ``(N, 3)``. With a conforming punch edge
        the reference is the mesh with the top nodes near each rim moved onto it (``deformed_mesh.nodes_mm -
        displacement_mm``; hydrogel nodes never move).
    deformed_mesh
        ``mesh.with_nodes(reference + u)``: region labels and facet sets (electrodes) intact.
    forces_N
        Force of every indenter (N, positive pushing down), shape ``(n_touches,)``.
    newton_steps
        Linear solves (Newton iterations) over all load steps.
    load_steps
        Accepted load steps.
    step_halvings
        Load steps that failed and were retried at half the increment.
    max_hydrogel_stretch, min_hydrogel_stretch
        Largest / smallest principal stretch over hydrogel tets (NaN if the mesh has none).
    min_det_F
        Smallest ``det F`` over all tets (> 0: no tet inverted).
    residual_norms
        Free-DOF residual norm (N) at every Newton iterate, one tuple per accepted load step.
    timings
        Seconds: ``assembly`` (incl. line-search evaluations), ``factorization``, ``solve``, ``other``, ``total``.
    solver
        Backend, DOFs, nonzeros, factorizations, settings summary.
    state
        The :class:`Converged` state (for adjoint solves).
    """

    touches: tuple
    displacement_mm: np.ndarray
    deformed_mesh: TetMesh
    forces_N: np.ndarray
    newton_steps: int
    load_steps: int
    step_halvings: int
    max_hydrogel_stretch: float
    min_hydrogel_stretch: float
    min_det_F: float
    residual_norms: tuple
    timings: dict
    solver: dict
    state: Converged | None = field(default=None, repr=False)

    def summary(self) -> dict:
        """JSON-ready scalars (no fields)."""
        return {"touches": [t.as_dict() for t in self.touches], "forces_N": self.forces_N.tolist(),
                "newton_steps": self.newton_steps, "load_steps": self.load_steps,
                "step_halvings": self.step_halvings, "max_hydrogel_stretch": self.max_hydrogel_stretch,
                "min_hydrogel_stretch": self.min_hydrogel_stretch, "min_det_F": self.min_det_F,
                "max_displacement_mm": float(np.abs(self.displacement_mm).max()),
                "seconds": self.timings["total"], "timings": dict(self.timings), "solver": dict(self.solver)}

    def to_vtu(self, path) -> None:
        """Write the deformed mesh with ``displacement_mm`` (points) and ``det_F`` (tets) for ParaView."""
        self.deformed_mesh.to_vtu(path, point_data={"displacement_mm": self.displacement_mm},
                                  cell_data={"det_F": self.det_F()})

    def det_F(self) -> np.ndarray:
        """Volume ratio ``det F`` of every tet, shape ``(M,)``."""
        ref = self.deformed_mesh.with_nodes(self.deformed_mesh.nodes_mm - self.displacement_mm)
        return self.deformed_mesh.tet_volumes_mm3() / ref.tet_volumes_mm3()
