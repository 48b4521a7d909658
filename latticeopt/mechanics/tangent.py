"""Linear algebra of the indentation's Newton iterations: the constrained tangent, its factorization (shifted
when indefinite, projected in a rescue), Newton increments by a direct solve or by GMRES through an older
factorization, and the line search that accepts a fraction of an increment.

:class:`TangentSolves` is a mixin of :class:`latticeopt.mechanics.indent.IndentationSolver`, which owns the state
it works on: ``op`` (the operator and its fixed sparsity pattern), ``_op`` (the phantom's operator), ``linear``
(the :class:`~latticeopt.linalg.SymmetricSolver` holding the symbolic and numeric factorization), ``settings``,
the current diagonal shift ``_shift``, whether indefinite tangents are projected instead (``_project``, a
press's rescue) and whether the current factorization is such a projection (``_projected``), the cached
constrained positions ``_zeroed`` / ``_zeroed_for`` and the counters ``_clock``, ``_n_factor``, ``_n_shifted``,
``_n_projected``, ``_n_krylov``, ``_n_solves``. Dirichlet DOFs are eliminated symmetrically inside the fixed
pattern (rows and columns zeroed, diagonal kept), so every factorization reuses one symbolic analysis.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import scipy.sparse as sp

from ..errors import ConvergenceError
from ..linalg import gmres
from .assembly import Evaluation

log = logging.getLogger(__name__)


class _StepFailed(Exception):
    """A load step failed (why, the free residual in N, the smallest det F): the caller halves the step."""

    def __init__(self, reason: str, residual: float, min_J: float, norms: tuple = ()):
        super().__init__(reason)
        self.reason, self.residual, self.min_J, self.norms = reason, residual, min_J, norms


class TangentSolves:
    """Newton increments on the constrained tangent (see the module docstring for the state it needs)."""

    def _constrained(self, data: np.ndarray, isD: np.ndarray) -> np.ndarray:
        """Tangent values with constrained rows and columns zeroed (diagonal kept), on the operator's pattern."""
        op = self.op
        if self._zeroed_for is None or not np.array_equal(isD, self._zeroed_for):
            # off-diagonal entries in a constrained row or column; the set rarely changes (7 ms to find it)
            pos = np.flatnonzero(isD[op.rows] | isD[op.indices])
            self._zeroed = pos[op.rows[pos] != op.indices[pos]]
            self._zeroed_for = isD.copy()
        out = data.copy()
        out[self._zeroed] = 0.0
        return out

    def _matrix(self, data: np.ndarray, isD: np.ndarray) -> sp.csr_matrix:
        """:meth:`_constrained` as the upper-triangle CSR matrix: same pattern every time."""
        op = self.op
        return sp.csr_matrix((self._constrained(data, isD), op.indices, op.indptr), shape=(op.n_dofs, op.n_dofs))

    def _free_rhs(self, ev: Evaluation, D: np.ndarray, jump: np.ndarray, R: np.ndarray) -> np.ndarray:
        """``-R - K lift(jump)``: the Newton right-hand side on the free DOFs (constrained rows still to set)."""
        rhs = -R.copy()
        if np.any(jump):
            lift = np.zeros(self.op.n_dofs)
            lift[D] = jump
            rhs -= self._symmetric_operator(ev.data)(lift)
        return rhs

    def _symmetric_operator(self, data: np.ndarray):
        """``x -> K x`` for the symmetric matrix whose upper-triangle values on the operator's pattern are
        ``data`` (the sparse matrix is built once, for GMRES's many products)."""
        op = self.op
        U = sp.csr_matrix((data, op.indices, op.indptr), shape=(op.n_dofs, op.n_dofs))
        diag = data[op.diag_pos]
        return lambda x: U @ x + U.T @ x - diag * x

    def _linear_solve(self, ev: Evaluation, isD: np.ndarray, D: np.ndarray, jump: np.ndarray,
                      R: np.ndarray, refactor: bool = True, u: np.ndarray | None = None) -> np.ndarray:
        """Newton increment: ``K du = -R`` on the free DOFs, ``du = jump`` on the constrained ones
        (symmetric elimination; the factorization reuses the symbolic analysis). ``u``: the state of ``ev``,
        which a projected tangent is assembled at (see :meth:`_factorize`)."""
        rhs = self._free_rhs(ev, D, jump, R)
        rhs[D] = ev.data[self.op.diag_pos[D]] * jump
        t = time.perf_counter()
        if refactor:
            self._factorize(ev.data, isD, u)
        t1 = time.perf_counter()
        du = self.linear.solve(rhs).ravel()
        self._clock["factorization"] += t1 - t
        self._clock["solve"] += time.perf_counter() - t1
        self._n_solves += 1
        du[D] = jump  # exact, whatever the solver's rounding
        return du

    def _factorize(self, data: np.ndarray, isD: np.ndarray, u: np.ndarray | None = None) -> None:
        """Cholesky of the constrained tangent; if it is indefinite, of the tangent with its free diagonal
        scaled by ``1 + sigma``, the smallest ``sigma`` of 1e-3, 1e-2, ... that is positive definite
        (Levenberg-Marquardt; Nocedal and Wright, Numerical Optimization, 2006, Alg. 3.3).

        Why: Newton iterates of a nearly incompressible stack leave the constraint surface at second order in
        the step, and the large pressures that follow make the tangent indefinite between converged states
        (at ``nu = 0.499``, w = 4, t = 3, a 4 mm press: up to 117 negative eigenvalues during the iterations of
        a load step, none at its converged states). The unshifted increment is then not a descent direction
        and the iterations wandered until the step was halved below ``min_step_mm``. The shifted increment
        is one, so the energy line search always makes progress; near the solution the tangent is positive
        definite again and Newton's fast convergence returns (no shift).

        With ``_project`` set (a press's rescue, :class:`~latticeopt.mechanics.indent.IndentationSolver`) and the
        state ``u`` given, an indefinite tangent is replaced by the projected one (each patch block's negative
        eigenvalues set to 0), and only that is shifted if Cholesky still rejects it: on the deepest presses the
        shifted increments diverge where the projected ones lower the energy at every iteration
        (docs/performance.md, "Indefinite tangents")."""
        A = self._matrix(data, isD)
        self._n_factor += 1
        self._projected = False
        if self.linear.backend != "pardiso":  # LU factorizes indefinite matrices; no inertia to test
            self.linear.refactor(A)
            self._shift = 0.0
            return
        from pypardiso.pardiso_wrapper import PyPardisoError

        if self._project and u is not None:
            try:
                self.linear.refactor(A)
                self._shift = 0.0
                return
            except PyPardisoError:
                pass
            t = time.perf_counter()
            A = self._matrix(self._op.evaluate(u, project=True).data, isD)
            self._clock["assembly"] += time.perf_counter() - t
            self._n_factor += 1
            self._n_projected += 1
            self._projected = True
        diag = A.data[self.op.diag_pos].copy()
        free = ~isD
        for sigma in (0.0, 1e-3, 1e-2, 1e-1, 1.0, 10.0):
            if sigma:
                A.data[self.op.diag_pos[free]] = diag[free] * (1.0 + sigma)
                self._n_factor += 1
            try:
                self.linear.refactor(A)
            except PyPardisoError:
                continue
            self._shift = sigma
            if sigma:
                self._n_shifted += 1
                log.debug("indefinite tangent: diagonal shifted by %g", sigma)
            return
        raise _StepFailed("tangent indefinite even with its diagonal shifted by 10", np.nan, np.nan)

    def _krylov_solve(self, ev: Evaluation, isD: np.ndarray, D: np.ndarray, jump: np.ndarray, R: np.ndarray,
                      rtol: float, atol: float) -> np.ndarray | None:
        """The Newton increment of :meth:`_linear_solve` by GMRES on the current tangent, preconditioned by the
        latest factorization, to ``|residual| <= max(rtol |rhs|, atol)``; None when that would take more than
        ``max_krylov`` iterations."""
        t = time.perf_counter()
        b = self._free_rhs(ev, D, jump, R)
        b[D] = 0.0  # du = jump there exactly; GMRES solves for the free part
        data = self._constrained(ev.data, isD)

        def precondition(r):
            return self.linear.solve(r).ravel()

        atol = max(rtol * float(np.linalg.norm(b)), atol)
        du, its, ok = gmres(self._symmetric_operator(data), b, precondition, atol, self.settings.max_krylov)
        self._n_krylov += its
        if ok and self._projected and not np.any(jump) and float(R @ du) >= 0.0:
            # the same for a projected factorization: its own system, by one back-substitution
            du = precondition(b)
            du[D] = 0.0
        elif ok and self._shift and not np.any(jump) and float(R @ du) >= 0.0:
            # the latest tangent was indefinite and this Newton increment does not lower the energy: solve the
            # shifted system the factorization belongs to instead (a descent direction)
            data[self.op.diag_pos[~isD]] *= 1.0 + self._shift
            du, its, ok = gmres(self._symmetric_operator(data), b, precondition, atol, self.settings.max_krylov)
            self._n_krylov += its
        self._clock["krylov"] += time.perf_counter() - t
        if not ok:
            return None
        self._n_solves += 1
        du[D] = jump
        return du

    def _evaluate(self, u: np.ndarray, tangent: bool = True) -> Evaluation:
        """The phantom's operator at displacement ``u`` (shape ``(N, 3)``, mm), timed as assembly."""
        t = time.perf_counter()
        ev = self._op.evaluate(u, residual=True, tangent=tangent)
        self._clock["assembly"] += time.perf_counter() - t
        return ev

    def _line_search(self, u: np.ndarray, du: np.ndarray, ev: Evaluation, has_jump: bool, isD: np.ndarray):
        """Backtrack until no tet inverts and (without a prescribed jump) energy or residual decreases."""
        slope = float(ev.residual_N @ du)
        r_old = float(np.linalg.norm(ev.residual_N[~isD]))
        alpha, min_J = 1.0, np.inf
        for k in range(12):
            trial_u = u + alpha * du.reshape(u.shape)
            trial = self._evaluate(trial_u, tangent=k == 0)
            min_J = min(min_J, trial.min_J)
            if not trial.inverted:
                if has_jump:
                    ok = True
                else:
                    armijo = trial.energy_Nmm <= ev.energy_Nmm + 1e-4 * alpha * min(slope, 0.0)
                    ok = armijo or float(np.linalg.norm(trial.residual_N[~isD])) < r_old
                if ok:
                    if trial.data is None:
                        trial = self._evaluate(trial_u, tangent=True)
                    return trial, trial_u
            alpha *= 0.5
        raise _StepFailed("line search found no admissible step" + (" (elements invert)" if min_J <= 0 else ""),
                          r_old, min_J)

    @property
    def linear_counts(self) -> dict:
        """Factorizations and GMRES iterations of this solver since its last press began (they go on counting
        through the adjoint solves that follow the press)."""
        return {"factorizations": self._n_factor, "krylov_iterations": self._n_krylov}

    def adjoint_solve(self, result, rhs: np.ndarray, values: np.ndarray | None = None, rtol: float = 1e-10
                      ) -> np.ndarray:
        """Solve the converged tangent of ``result``: ``K_ff x_f = rhs_f`` with ``x_D = values`` (default 0).

        The adjoint of a function of the converged displacement (``rhs`` its gradient) or, with ``values`` on the
        constrained DOFs, the response of the free DOFs to a change of the prescribed ones. GMRES on the exact
        converged tangent, preconditioned by its own factorization (made at the first adjoint solve of the press
        and kept for the next ones; a new press drops it); stops at ``|residual| <= rtol |rhs|``.

        Parameters
        ----------
        result : IndentationResult
            A press solved by this solver (its :attr:`~IndentationResult.state`).
        rhs : ndarray, shape (3N,)
            Right-hand side (its constrained entries are ignored), interleaved x, y, z per node.
        values : ndarray, shape (len(result.state.dofs),), optional
            Prescribed values of the constrained DOFs.

        Returns
        -------
        ndarray, shape (3N,)
        """
        st = result.state
        D, ev = st.dofs, st.evaluation
        isD = np.zeros(self.op.n_dofs, dtype=bool)
        isD[D] = True
        jump = np.zeros(len(D)) if values is None else np.asarray(values, dtype=float)
        b = self._free_rhs(ev, D, jump, -np.asarray(rhs, dtype=float))
        b[D] = 0.0
        matvec = self._symmetric_operator(self._constrained(ev.data, isD))
        atol = rtol * max(float(np.linalg.norm(b)), 1e-300)
        t = time.perf_counter()
        if self._adjoint_factor is not st:
            # one factorization of the converged tangent for all of this press's adjoints: GMRES then needs 1-3
            # back-substitutions each, against about 20 through the last Newton factorization (a back-substitution
            # costs a tenth of a factorization here: benchmarks/bench_gradient.py)
            self._factorize(ev.data, isD)
            self._factor_isD, self._adjoint_factor = isD, st
        x, its, ok = gmres(matvec, b, lambda r: self.linear.solve(r).ravel(), atol, 40)
        self._n_krylov += its
        if not ok:
            raise ConvergenceError(f"adjoint solve: GMRES on the converged tangent reached no relative residual "
                                   f"{rtol:g} in 40 iterations")
        self._clock["adjoint"] = self._clock.get("adjoint", 0.0) + time.perf_counter() - t
        x[D] = jump
        return x
