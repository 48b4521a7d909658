"""Large-deformation indentation of the sensor stack: load stepping, Newton, step halving.

>>> from latticeopt import LatticeDesign, MeshSettings, mesh_design
>>> from latticeopt.mechanics import indent
>>> from latticeopt.touches import Touch
>>> mesh = mesh_design(LatticeDesign(), MeshSettings(size_mm=6), cache_dir=False)   # default: 2 mm
>>> res = indent(mesh, [Touch(50, 50, 8.75, 4.0)])
>>> len(res.forces_N), res.deformed_mesh.nodes_mm.shape == mesh.nodes_mm.shape
(1, True)

Bottom face fixed, sides free, the indenters of :mod:`latticeopt.mechanics.indenters` on the top. All touches
are driven together: at load factor ``lam`` touch ``i`` is at depth ``lam * depth_i`` (load steps of at most
``max_step_mm`` for the deepest touch). Each load step applies the prescribed displacement increment through
the tangent (so the first iterate is the linearised response, not a crushed top layer) and then iterates on
the residual. By default inexact Newton (``method="newton-krylov"``): every iteration solves the current
tangent by GMRES preconditioned by the latest PARDISO factorization, to a relative residual ``krylov_rtol``,
and refactorizes only when GMRES would need more than ``max_krylov`` back-substitutions -- about one
factorization per load step instead of one per iteration. ``method="newton"`` factorizes every iteration
(quadratic convergence, tested). Timings of both: ``benchmarks/bench_indent.py`` and ``docs/performance.md``. A
backtracking line search (:meth:`TangentSolves._line_search`) never accepts ``det F <= 0`` (nor a patch mean
dilatation <= 0) and demands a decrease of energy or residual. A step has
converged when the residual on the free DOFs is below ``rtol`` times the reaction norm (or ``atol_N``);
intermediate steps use the looser ``step_rtol`` (only the final state is reported). A failed step is
halved (the increment that failed, so that near the final depth a retry is never the same step); below
``min_step_mm``, after 4 failed steps in a row, or after 3 failed attempts at one depth (a press creeping
towards it by accepted halves), the press is rescued once: the failed step again, on projected tangents
(``rescue_newton``; :meth:`TangentSolves._factorize`); if that fails too, a :class:`ConvergenceError` names the
step, the depth reached, the residual and whether elements inverted.

Dirichlet DOFs are eliminated symmetrically inside a fixed sparsity pattern (their rows and columns zeroed,
diagonal kept), so the pattern, and PARDISO's symbolic factorization, is the same for every Newton step,
every load step and every phantom of a mesh: :class:`IndentationSolver` holds it.
"""

from __future__ import annotations

import copy
import logging
import time

import numpy as np

from ..design import REGION_IDS
from ..errors import ConvergenceError
from ..linalg import SymmetricSolver, single_threaded_blas
from ..mesh.tetmesh import TetMesh
from ..touches import Touch, check_touches, touch_name
from .assembly import Evaluation, NeoHookeanOperator
from .indenters import Constraints, conform_punch_edges, flat_faces
from .settings import Converged, IndentationResult, IndentSettings
from .tangent import TangentSolves, _StepFailed

log = logging.getLogger(__name__)
# Krylov forcing term of a load step's first iteration: its right-hand side is the lift of the prescribed
# increment, far larger than the residual it leaves, so it needs a tighter relative tolerance than
# ``krylov_rtol`` (1e-2 here took 199 Newton iterations on six random phantoms, 1e-3 took 168)
_JUMP_RTOL = 1e-3
# Failed load steps in a row (from one depth) after which a press counts as unable to make progress: the
# increment is then a sixteenth of the one that failed first, where halving on to ``min_step_mm`` costs up to 3
# more failed Newton attempts from a 1 mm step. The deep paper presses that converge after halvings needed at
# most 2 in a row (docs/verification.md)
STALL_HALVINGS = 4
# Failed attempts at one target depth (with accepted halves between them) after which a press counts as creeping
# towards a depth it cannot reach. Each retry starts half as far from the target as the last; when the third
# still fails, halving on costs a full Newton attempt per remaining halving (down to ``min_step_mm``): 4 more
# attempts of 40 iterations for a 9 mm stack pressed to 8.9 mm on the paper mesh. The deep paper presses that
# converge failed at most twice at their final depth (1:95 on w = 2, t = 1; docs/verification.md)
TARGET_FAILURES = 3
# A GMRES increment through the last factorization solves the current tangent, but where that tangent is
# indefinite it falls back to the shifted system of the factorization, whose shift belongs to an older state: a
# descent direction that can stall. Seen on deep presses: the residual flat at 2x the tolerance for 30 iterations,
# three attempts in a row, where exact Newton converged (docs/verification.md). So after this many GMRES
# iterates in a row that did not lower the residual below ``_STALL_RATIO`` of the previous one, the next
# iteration refactorizes. A press whose GMRES iterates keep converging follows exactly the path it did before.
_STALL_ITERATES, _STALL_RATIO = 2, 0.9
# load factors this close to 1 are the final depth (a relative 1e-9 of it: far below any load step)
_ROUND_OFF = 1e-9


class IndentationSolver(TangentSolves):
    """Indentation of one mesh: operator, sparsity pattern and symbolic factorization built once.

    Build one per mesh (design) and call :meth:`solve` for every phantom; :func:`indent` is the one-shot
    wrapper.

    Parameters
    ----------
    mesh
        Labelled tet mesh with ``top`` and ``bottom`` facet sets (mm).
    settings
        Materials, indenter and Newton settings.
    """

    def __init__(self, mesh: TetMesh, settings: IndentSettings | None = None):
        t0 = time.perf_counter()
        self.mesh = mesh
        self.settings = settings = settings or IndentSettings()
        for name in ("top", "bottom"):
            if name not in mesh.facets or len(mesh.facets[name]) == 0:
                raise ValueError(f"mesh: expected a non-empty facet set {name!r}")
        self.op = NeoHookeanOperator(mesh, settings.materials, settings.volumetric)
        self.top_nodes = np.unique(mesh.facets["top"])
        self.bottom_nodes = np.unique(mesh.facets["bottom"])
        lo, hi = mesh.nodes_mm.min(axis=0), mesh.nodes_mm.max(axis=0)
        self.x_range, self.y_range = (float(lo[0]), float(hi[0])), (float(lo[1]), float(hi[1]))
        self.thickness_mm = float(mesh.nodes_mm[self.top_nodes, 2].mean() - mesh.nodes_mm[self.bottom_nodes, 2].mean())
        self._gel = mesh.region == REGION_IDS["hydrogel"]
        # nodes a conforming punch rim may move: top surface, off the sensor's rim, off the hydrogel
        xy = mesh.nodes_mm[:, :2]
        self._movable = np.zeros(mesh.n_nodes, dtype=bool)
        self._movable[self.top_nodes] = True
        self._movable[mesh.tets[self._gel].ravel()] = False
        self._movable &= (xy[:, 0] > lo[0]) & (xy[:, 0] < hi[0]) & (xy[:, 1] > lo[1]) & (xy[:, 1] < hi[1])
        n = self.op.n_dofs
        self._ev0 = self.op.evaluate(np.zeros((mesh.n_nodes, 3)))
        isD = np.zeros(n, dtype=bool)
        isD[(3 * self.bottom_nodes[:, None] + np.arange(3)).ravel()] = True
        self._zeroed_for = self._zeroed = None  # see _constrained
        # symbolic analysis only: every phantom factorizes its own tangent (same pattern)
        # Cholesky: an indefinite tangent is reported (PARDISO error -4) and shifted in _factorize, so that every
        # direct Newton increment is a descent direction of the energy
        self.linear = SymmetricSolver(self._matrix(self._ev0.data, isD), positive_definite=True,
                                      backend=settings.backend, factorize=False,
                                      precision=settings.factorization_precision)
        self._adjoint_factor = None  # the converged state whose own tangent ``linear`` holds (adjoint solves)
        self._shift = 0.0  # relative diagonal shift of the current factorization (0: the tangent itself)
        self._project = self._projected = False  # see solve's rescue and TangentSolves._factorize
        self._max_newton = settings.max_newton
        self._warned_bare_rounding = False  # see solve
        self.setup_seconds = time.perf_counter() - t0
        log.info("indentation solver: %d dofs, %d nonzeros, %s, set up in %.2f s", n, self.op.nnz,
                 self.linear.backend, self.setup_seconds)

    # -- one phantom ----------------------------------------------------------------------------------
    def with_moduli(self, mu_MPa: np.ndarray, kappa_MPa: np.ndarray) -> IndentationSolver:
        """This solver with shear and bulk moduli given per tet (mesh order, MPa), sharing the sparsity pattern and
        the symbolic factorization (a density layout's materials, :mod:`latticeopt.density`)."""
        other = copy.copy(self)
        other.op = self.op.with_moduli(mu_MPa, kappa_MPa)
        other._ev0 = other.op.evaluate(np.zeros((self.mesh.n_nodes, 3)))
        other._adjoint_factor = None
        return other

    @single_threaded_blas()
    def solve(self, touches, u0: np.ndarray | None = None, progress=None) -> IndentationResult:
        """Indent with ``touches`` (Touch objects or ``(x, y, r, d)`` sequences, mm); see the module docstring.

        ``u0`` (shape ``(N, 3)``, mm): a displacement to start Newton from at full depth, the converged state
        of the same touches on a nearby design (an optimizer's previous iterate). The press is then solved in
        one load step when that converges, and by the usual load stepping from zero when it does not.
        ``progress(depth_mm, final_depth_mm)``, if given, is called after every accepted load step (deepest touch).
        """
        t_start = time.perf_counter()
        s = self.settings
        touches = check_touches(touches, self.x_range, self.y_range, self.thickness_mm)
        self._clock = {"assembly": 0.0, "factorization": 0.0, "solve": 0.0, "krylov": 0.0}
        self._n_krylov = self._n_shifted = self._n_projected = 0
        self._project, self._max_newton, rescued = False, s.max_newton, False
        ref, self._op, ev = self.mesh.nodes_mm, self.op, self._ev0
        if s.indenter == "flat" and s.punch_edge == "conforming":
            # the rim a bonded punch holds is its flat face's: inside the rounding, if any
            ref = conform_punch_edges(self.mesh.nodes_mm, self.mesh.tets, self.mesh.facets["top"], self._movable,
                                      flat_faces(touches, s.indenter, s.edge_radius_mm))
        n_moved = int(np.count_nonzero(np.any(ref != self.mesh.nodes_mm, axis=1)))
        if n_moved:  # a new reference geometry: its own operator and undeformed tangent
            self._op = self.op.with_reference(ref)
            ev = self._evaluate(np.zeros_like(ref))
        cons = Constraints(ref, self.top_nodes, self.bottom_nodes, touches, s.indenter, s.in_plane,
                           s.edge_radius_mm)
        # once per solver: a sweep presses one mesh many times
        bare = [] if self._warned_bare_rounding else cons.bare_roundings()
        if bare:
            self._warned_bare_rounding = True
            r, e = touches[bare[0]].radius_mm, s.edge_radius_mm
            log.warning("edge_radius_mm = %g mm: no top-surface node lies under the rounded edge of %s (%g-%g mm from "
                        "its centre), so it presses as a sharp punch of radius %g mm; top elements of about %g mm "
                        "(mesh size_mm, --mesh-size) resolve the rounding (docs/verification.md, \"Rounded punch "
                        "edge\")", e, touch_name(bare[0]), r - e, r, r - e, e)
        self._n_solves = self._n_factor = 0
        self._adjoint_factor = None
        self._factor_isD = None  # Dirichlet set of the current factorization (none yet for this phantom)
        u = np.zeros((self.mesh.n_nodes, 3))
        d_max = max(t.depth_mm for t in touches)
        lam, history, halvings = 0.0, [], 0
        dlam_max = 1.0 if d_max == 0 else min(1.0, s.max_step_mm / d_max)
        dlam = dlam_max
        warm, warm_ok = u0 is not None and d_max > 0, False
        if warm:
            u0 = np.asarray(u0, dtype=float)
            if u0.shape != u.shape or not np.all(np.isfinite(u0)):
                raise ValueError(f"u0: expected a finite array of shape {u.shape}, got {u0.shape}")
            ev0 = self._evaluate(u0)
            try:
                if ev0.inverted:
                    raise _StepFailed("the start inverts elements", np.inf, ev0.min_J)
                u, ev, norms = self._newton(u0.copy(), ev0, cons, 1.0, final=True)
                lam, warm_ok = 1.0, True
                history.append(tuple(norms))
                if progress is not None:
                    progress(d_max, d_max)
            except _StepFailed as exc:
                log.info("warm start failed (%s); load stepping from zero", exc.reason)
                self._factor_isD = None
                u = np.zeros_like(u)
        stuck = 0  # failed steps since the last accepted one
        failed_at: dict[float, int] = {}  # failed attempts per target load factor
        while lam < 1.0 and d_max > 0:
            # increments (1 / n of the depth, or halves of what was left) add up to the final depth only to
            # round-off: a step ending that close to it is the final step, solved to ``rtol``; otherwise a step of
            # 1e-16 mm would follow it, whose failure could not be halved (below ``min_step_mm``)
            lam_new = 1.0 if lam + dlam > 1.0 - _ROUND_OFF else lam + dlam
            active = [a.copy() for a in cons.active]
            try:
                # the step starts from the last converged state; Newton applies the prescribed increment
                u_new, ev_new, norms = self._newton(u, ev, cons, lam_new, final=lam_new >= 1.0)
            except _StepFailed as exc:
                halvings += 1
                self._factor_isD = None  # that factorization belongs to a rejected state
                cons.active = active
                log.info("load step to %.4g mm failed (%s, residual %.3g N); halving", lam_new * d_max,
                         exc.reason, exc.residual)
                log.debug("free-residual norms of the failed step: %s", exc.norms)
                # halve the increment that failed, not the nominal one: near the end of the press the nominal
                # increment can exceed what is left, and halving it would retry the same step
                dlam = 0.5 * (lam_new - lam)
                stuck += 1
                failed_at[lam_new] = at_target = failed_at.get(lam_new, 0) + 1
                if dlam * d_max < s.min_step_mm or stuck >= STALL_HALVINGS or at_target >= TARGET_FAILURES:
                    if s.rescue_newton and not self._project:
                        # rescue: the failed step once more, on projected tangents with a larger budget; its
                        # failure (counted with the ones above) ends the press
                        self._project, self._max_newton, rescued = True, s.rescue_newton, True
                        dlam = lam_new - lam
                        log.info("load step to %.4g mm: no progress; rescued with projected tangents (up to %d "
                                 "iterations)", lam_new * d_max, s.rescue_newton)
                        continue
                    inv = f"; an element inverted (min det F = {exc.min_J:.3g})" if exc.min_J <= 0 else ""
                    why = (f"; no progress: {stuck} failed steps in a row" if stuck >= STALL_HALVINGS else
                           f"; no progress: {at_target} failed attempts at this depth" if at_target >= TARGET_FAILURES
                           else "")
                    # the budget that ended a rescue, and where to change it
                    rescue = (f"; rescued with projected tangents before, up to {s.rescue_newton} iterations a step "
                              f"(rescue_newton; [physics] mechanics_rescue_newton)" if rescued else "")
                    # the sharp rim shears the material under it by the whole depth within one element
                    hint = ("; the punch's edge is sharp: a rounded one (edge_radius_mm, --edge-radius) lets deep "
                            "presses converge that a sharp one cannot (docs/verification.md, \"Rounded punch edge\")"
                            if s.indenter == "flat" and s.edge_radius_mm == 0 else "")
                    raise ConvergenceError(
                        f"indentation did not converge: load step {len(history) + 1} from depth "
                        f"{lam * d_max:.4g} mm towards {lam_new * d_max:.4g} mm of {d_max:.4g} mm failed after "
                        f"{halvings} step halvings ({exc.reason}; residual {exc.residual:.3g} N{inv}{why}{rescue})"
                        f"{hint}"
                    ) from None
                continue
            u, ev, lam = u_new, ev_new, lam_new
            stuck = 0
            history.append(tuple(norms))
            if progress is not None:
                progress(lam * d_max, d_max)
            if len(norms) <= 4:
                dlam = min(dlam * 2.0, dlam_max)
        forces = cons.forces_N(ev.residual_N)
        J, _ = self._op.jacobians(u)
        if self._gel.any():
            st = self._op.principal_stretches(u, self._gel)
            smax, smin = float(st.max()), float(st.min())
        else:
            smax = smin = float("nan")
        total = time.perf_counter() - t_start
        clock = dict(self._clock)
        clock["other"] = total - sum(clock.values())
        clock["total"] = total
        clock["setup"] = self.setup_seconds
        stats = {"backend": self.linear.backend, "n_dofs": self.op.n_dofs, "nnz_upper": self.op.nnz,
                 "n_factorizations": self._n_factor, "shifted_factorizations": self._n_shifted,
                 "krylov_iterations": self._n_krylov, "projected_factorizations": self._n_projected,
                 "rescued": rescued, "precision": self.linear.precision, "method": s.method,
                 "volumetric": s.volumetric, "indenter": s.indenter, "in_plane": s.in_plane, "punch_edge": s.punch_edge,
                 "edge_radius_mm": s.edge_radius_mm,
                 "moved_reference_nodes": n_moved, "contact_nodes": [int(len(n)) for n in cons.contact_nodes()]}
        D = cons.dirichlet(1.0)[0]
        state = Converged(op=self._op, evaluation=ev if ev.data is not None else self._evaluate(u), dofs=D,
                          contact_nodes=tuple(cons.contact_nodes()), warm_start=warm_ok)
        return IndentationResult(
            touches=touches, state=state, displacement_mm=u, deformed_mesh=self.mesh.with_nodes(ref + u),
            forces_N=forces, newton_steps=self._n_solves, load_steps=len(history), step_halvings=halvings,
            max_hydrogel_stretch=smax, min_hydrogel_stretch=smin, min_det_F=float(J.min()),
            residual_norms=tuple(history), timings=clock, solver=stats)

    def _newton(self, u: np.ndarray, ev: Evaluation, cons: Constraints, lam: float, final: bool = True):
        """Solve one load step from ``u`` (with its evaluation ``ev``) to load factor ``lam``.

        ``method="newton-krylov"``: GMRES on the current tangent through the latest factorization, refactorizing
        when GMRES would take too long; ``method="newton"``: a fresh tangent factorization every iteration.
        """
        s = self.settings
        rtol = s.rtol if final else max(s.rtol, s.step_rtol)
        n = self.op.n_dofs
        cons.start_step(u, lam)
        norms: list[float] = []
        first = 0  # start of the iterates the divergence test compares
        refactor_next = False
        krylov = s.method == "newton-krylov"
        stalled = 0  # GMRES iterates in a row that did not lower the residual to _STALL_RATIO of the one before
        max_newton = self._max_newton
        for it in range(max_newton + 1):
            D, vals = cons.dirichlet(lam)
            isD = np.zeros(n, dtype=bool)
            isD[D] = True
            # a factorization for this Dirichlet set exists (the sphere's contact set may have changed)
            fresh = self._factor_isD is not None and np.array_equal(isD, self._factor_isD)
            jump = vals - u.ravel()[D]
            R = ev.residual_N
            r_free = float(np.linalg.norm(R[~isD]))
            norms.append(r_free)
            if not np.isfinite(r_free):
                raise _StepFailed("non-finite residual", r_free, ev.min_J)
            tol = max(rtol * float(np.linalg.norm(R[isD])), s.atol_N)
            if not np.any(jump) and r_free <= tol:
                if ev.data is None and (not final or cons.has_contact):
                    ev = self._evaluate(u, tangent=True)  # the next step (or the contact update) needs it
                if not cons.has_contact or not cons.update_active(u, R, lam, ev.data[self.op.diag_pos]):
                    return u, ev, norms
                first = len(norms)  # the contact set changed: solve again, judging divergence afresh
                continue
            if it == max_newton:
                raise _StepFailed(f"no convergence in {max_newton} iterations", r_free, ev.min_J, tuple(norms))
            # (not in a rescue: projected increments descend in energy, and a residual rising on the way is no sign
            # of divergence there)
            if not self._project and len(norms) > first + 3 and r_free > 1e3 * min(norms[first + 1:]):
                raise _StepFailed("residual diverging", r_free, ev.min_J, tuple(norms))
            # Newton: the load increment of a new step goes through the factorization of the last iterate of
            # the previous step (its tangent differs from the converged one by O(residual)): one factorization
            # fewer per load step
            reuse = s.method == "newton" and it == 0 and fresh and bool(np.any(jump))
            exact = (s.method == "newton" and not reuse) or not fresh or refactor_next
            if krylov and not exact:  # GMRES on the current tangent through the last factorization
                if ev.data is None:
                    ev = self._evaluate(u, tangent=True)
                # a residual below half the tolerance is all the next iterate needs
                du = self._krylov_solve(ev, isD, D, jump, R, _JUMP_RTOL if np.any(jump) else s.krylov_rtol,
                                        0.5 * tol)
                exact = du is None  # the factorization is too stale: refactorize instead
            gmres_step = krylov and not exact and not np.any(jump)  # a load increment raises the residual
            if exact:
                if ev.data is None:
                    ev = self._evaluate(u, tangent=True)
                du = self._linear_solve(ev, isD, D, jump, R, u=u)
                self._factor_isD = isD
                refactor_next = False
            elif not krylov:
                # exact Newton's load increment through the previous factorization (one back-substitution); the
                # tangent changes most over it, so the next iteration refactorizes
                if ev.data is None:
                    ev = self._evaluate(u, tangent=True)
                du = self._linear_solve(ev, isD, D, jump, R, refactor=False)
                refactor_next = True
            try:
                ev_new, u_new = self._line_search(u, du, ev, np.any(jump), isD)
            except _StepFailed as exc:
                if exact:
                    exc.norms = tuple(norms)
                    raise
                refactor_next = True  # an increment through a stale factorization failed: retry with a fresh one
                continue
            if gmres_step and float(np.linalg.norm(ev_new.residual_N[~isD])) > _STALL_RATIO * r_free:
                stalled += 1
                if stalled >= _STALL_ITERATES:
                    refactor_next, stalled = True, 0
            else:
                stalled = 0
            u, ev = u_new, ev_new
        # only a last iteration whose residual converged while the contact set changed again ends up here
        raise _StepFailed(f"no convergence in {max_newton} iterations (the contact set still changing)", r_free,
                          ev.min_J, tuple(norms))


def indent(mesh: TetMesh, touches, settings: IndentSettings | None = None, progress=None) -> IndentationResult:
    """Indent ``mesh`` with ``touches`` (see :class:`IndentationSolver`; builds one and solves once).

    Parameters
    ----------
    mesh
        Labelled tet mesh (mm) with ``top`` and ``bottom`` facet sets.
    touches
        :class:`~latticeopt.touches.Touch` objects or ``(x, y, radius, depth)`` sequences (mm); checked
        against the mesh's top surface and thickness before any solve.
    settings
        :class:`IndentSettings`; defaults to ``IndentSettings()``.
    progress
        Called as ``progress(depth_mm, final_depth_mm)`` after every accepted load step (optional).

    Returns
    -------
    IndentationResult
    """
    settings = settings or IndentSettings()
    lo, hi = mesh.nodes_mm.min(axis=0), mesh.nodes_mm.max(axis=0)
    check_touches(touches, (lo[0], hi[0]), (lo[1], hi[1]), float(hi[2] - lo[2]))  # fail before any setup
    return IndentationSolver(mesh, settings).solve(touches, progress=progress)


__all__ = ["IndentSettings", "IndentationResult", "IndentationSolver", "indent", "Touch"]
