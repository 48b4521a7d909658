"""Sparse direct solves: MKL PARDISO through pypardiso when it is installed, SuperLU otherwise.

PARDISO measured 10-50x faster than SuperLU on this project's 3D systems (mechanics and electrics meshes). The
symbolic analysis (ordering, elimination tree) depends only on the sparsity pattern, so
:meth:`SymmetricSolver.refactor` re-uses it when only the values change (Newton steps, new conductivities).
The fallback is explicit: ``backend="scipy"`` or no pypardiso installed; :attr:`SymmetricSolver.backend`
says which one ran.

PARDISO's parameters are set explicitly (``iparm[0] = 1``): with ``iparm[0] = 0`` MKL fills in its defaults,
which include two steps of iterative refinement per solve (2.5-3x the cost of a back-substitution here).
``precision="single"`` factorizes in float32 (``iparm[27] = 1``): half the factorization time and a quarter
of the solve time on the mechanics tangent, with relative residuals near 1e-6 -- for Newton and quasi-Newton
iterations, whose convergence is judged on the double-precision residual anyway.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import logging
import os
import sys

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

BACKENDS = ("auto", "pardiso", "scipy")
PRECISIONS = ("double", "single")
_OPENBLAS = None  # threadpoolctl's handle on the loaded OpenBLAS libraries, made at first use


@contextlib.contextmanager
def single_threaded_blas():
    """OpenBLAS on one thread inside the block (its count is restored after); MKL, and so PARDISO, keeps its own.

    Used as a context manager or a decorator around in-process presses and solves. OpenBLAS threads that finish a
    call go on spinning for a while, and a press interleaves small BLAS calls (numpy, scipy) with PARDISO
    factorizations: on 2 cores the spinning threads took the cores PARDISO's threads needed. With OpenBLAS on one
    thread presses ran 1.3-1.5x faster on the paper map's 2 mm mesh, 1.3x on 1.4 mm and 2.3x on 4 mm
    (``benchmarks/mkl_threads.py``, docs/performance.md); OpenBLAS's own threads bought nothing on these presses.
    Worker processes start with one thread for every library, so there it changes nothing.
    """
    global _OPENBLAS
    if _OPENBLAS is None:
        import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS, beside numpy's, before the handle lists them)
        from threadpoolctl import ThreadpoolController

        _OPENBLAS = ThreadpoolController().select(internal_api="openblas")
    with _OPENBLAS.limit(limits=1):
        yield


def _pardiso_parameters(mtype: int, single: bool) -> dict[int, int]:
    """PARDISO ``iparm`` (1-based, as MKL documents them) for a symmetric matrix, set explicitly."""
    return {1: 1,  # use the values below, not MKL's defaults
            2: 2,  # nested-dissection ordering (METIS)
            8: 0,  # no iterative refinement: direct solves are accurate to ~1e-14 on these systems
            10: 8,  # pivot perturbation 1e-8 (symmetric default)
            11: 0, 13: 0,  # no scaling or weighted matching (symmetric matrices)
            21: 1 if mtype == -2 else 0,  # Bunch-Kaufman pivoting for symmetric indefinite
            28: 1 if single else 0}


def pardiso_available() -> bool:
    try:
        import pypardiso  # noqa: F401
    except (ImportError, OSError):
        return False
    return True


class SymmetricSolver:
    """Factorization of a symmetric sparse matrix, for many right-hand sides and value-only updates.

    Parameters
    ----------
    A : sparse matrix, shape (n, n)
        Symmetric; only its upper triangle is read (by both backends).
    positive_definite
        True for SPD systems (Cholesky-type, PARDISO ``mtype=2``); False for symmetric indefinite ones
        (``mtype=-2``, Bunch-Kaufman ``LDL^T``; saddle points such as mixed u-p mechanics); ``"auto"``:
        Cholesky, and ``LDL^T`` for a factorization that meets a non-positive pivot (Newton tangents, SPD
        near stable equilibria; Cholesky measured 8 % faster to factorize and 25 % faster to solve here).
        SuperLU ignores it.
    backend
        ``"auto"`` (PARDISO if available), ``"pardiso"`` or ``"scipy"``.
    factorize
        False: only analyse the pattern of ``A`` now (PARDISO); call :meth:`refactor` with the first real
        values before :meth:`solve` (saves a numeric factorization when ``A`` is only a pattern template).
    precision
        ``"double"`` (default) or ``"single"``: PARDISO factorizes and solves in float32 (results returned as
        float64, relative residual about 1e-6; for use inside nonlinear iterations). SuperLU ignores it.
    """

    def __init__(self, A, positive_definite: bool = True, backend: str = "auto", factorize: bool = True,
                 precision: str = "double"):
        if backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
        if precision not in PRECISIONS:
            raise ValueError(f"precision: expected one of {PRECISIONS}, got {precision!r}")
        if backend == "pardiso" and not pardiso_available():
            raise ImportError("backend='pardiso' needs pypardiso (pip install pypardiso)")
        self.backend = "pardiso" if backend in ("auto", "pardiso") and pardiso_available() else "scipy"
        self.positive_definite = positive_definite
        self.precision = precision if self.backend == "pardiso" else "double"
        self._dtype = np.float32 if self.precision == "single" else np.float64
        self.n = A.shape[0]
        self.n_factorizations = 0
        self._pattern = None
        if positive_definite not in (True, False, "auto"):
            raise ValueError(f"positive_definite: expected True, False or 'auto', got {positive_definite!r}")
        self._solvers: dict[int, object] = {}
        self.n_indefinite = 0  # "auto": factorizations that fell back to LDL^T
        if self.backend == "pardiso":
            # pypardiso searches the whole environment for mkl_rt on every construction (0.3 s here)
            # unless this variable names it: look in the usual place first, then remember what it found.
            if "PYPARDISO_MKL_RT" not in os.environ:
                found = sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmkl_rt.so*")))
                if found:
                    os.environ["PYPARDISO_MKL_RT"] = found[0]
            upper = self._upper(A)
            self._set_pattern(upper)
            self._ps = self._analysed(-2 if positive_definite is False else 2, upper)
        if factorize or self.backend == "scipy":
            self.refactor(A)

    def _analysed(self, mtype: int, upper: sp.csr_matrix):
        """The PARDISO handle for ``mtype`` with the symbolic analysis of ``upper``'s pattern (made once)."""
        ps = self._solvers.get(mtype)
        if ps is None:
            import pypardiso

            ps = self._solvers[mtype] = pypardiso.PyPardisoSolver(mtype=mtype)
            os.environ.setdefault("PYPARDISO_MKL_RT", ps.libmkl._name)
            for i, value in _pardiso_parameters(mtype, self.precision == "single").items():
                ps.set_iparm(i, value)
            if upper.dtype == np.float64:  # pypardiso's checks only accept float64 (its own casts are skipped)
                ps._check_A(upper)
            self._call(ps, 11, self._cast(upper).data, np.zeros((self.n, 1), dtype=self._dtype))
        return ps

    def _set_pattern(self, upper: sp.csr_matrix) -> None:
        self._pattern = (upper.indptr.copy(), upper.indices.copy())
        # PARDISO's 1-based int32 index arrays, made once per pattern: pypardiso's own call rebuilds them (a cast
        # and a shift of the whole CSR pattern) on every phase, back-substitutions included (2 ms of a 26 ms solve)
        self._ia = np.ascontiguousarray(upper.indptr + 1, dtype=np.int32)
        self._ja = np.ascontiguousarray(upper.indices + 1, dtype=np.int32)

    def _call(self, ps, phase: int, values: np.ndarray, B: np.ndarray) -> np.ndarray:
        """One PARDISO phase on the stored pattern with ``values`` (the upper triangle's CSR data, in the
        factorization's precision) and right-hand sides ``B`` (Fortran order, same precision)."""
        X = np.zeros_like(B)
        error = ctypes.c_int32(0)
        i32 = ctypes.POINTER(ctypes.c_int32)
        ps._mkl_pardiso(ps.pt.ctypes.data_as(ctypes.POINTER(ps._pt_type[0])), ctypes.byref(ctypes.c_int32(1)),
                        ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(ps.mtype)),
                        ctypes.byref(ctypes.c_int32(phase)), ctypes.byref(ctypes.c_int32(self.n)),
                        values.ctypes.data_as(ctypes.c_void_p), self._ia.ctypes.data_as(i32),
                        self._ja.ctypes.data_as(i32), ps.perm.ctypes.data_as(i32),
                        ctypes.byref(ctypes.c_int32(1 if B.ndim == 1 else B.shape[1])), ps.iparm.ctypes.data_as(i32),
                        ctypes.byref(ctypes.c_int32(0)), B.ctypes.data_as(ctypes.c_void_p),
                        X.ctypes.data_as(ctypes.c_void_p), ctypes.byref(error))
        if error.value != 0:
            from pypardiso.pardiso_wrapper import PyPardisoError

            raise PyPardisoError(error.value)
        return X

    def _cast(self, upper: sp.csr_matrix) -> sp.csr_matrix:
        """``upper`` with values in the factorization's precision (PARDISO reads raw float32 or float64)."""
        if upper.dtype == self._dtype:
            return upper
        return sp.csr_matrix((upper.data.astype(self._dtype), upper.indices, upper.indptr), shape=upper.shape)

    @staticmethod
    def _upper(A) -> sp.csr_matrix:
        # PARDISO's symmetric storage needs every diagonal entry stored, even a zero (saddle-point blocks).
        S = sp.triu(sp.coo_matrix(A), k=1)
        n = A.shape[0]
        diag = np.arange(n)
        U = sp.csr_matrix((np.r_[S.data, A.diagonal()], (np.r_[S.row, diag], np.r_[S.col, diag])), shape=(n, n))
        U.sort_indices()
        return U

    def _is_stored_pattern(self, A) -> bool:
        return (self._pattern is not None and sp.isspmatrix_csr(A) and A.dtype == np.float64
                and np.array_equal(A.indptr, self._pattern[0]) and np.array_equal(A.indices, self._pattern[1]))

    def refactor(self, A) -> None:
        """Numeric factorization of new values; the symbolic analysis is reused when the pattern is unchanged."""
        if A.shape != (self.n, self.n):
            raise ValueError(f"A: expected shape {(self.n, self.n)}, got {A.shape}")
        self.n_factorizations += 1
        if self.backend == "scipy":
            from scipy.sparse.linalg import splu

            # only the upper triangle is read, as by PARDISO (the mechanics passes nothing else)
            upper = sp.triu(A, format="csc")
            full = (upper + sp.triu(upper, k=1).T).tocsc()
            self._lu = splu(full, permc_spec="MMD_AT_PLUS_A")
            return
        if self._is_stored_pattern(A):  # already the analysed upper triangle (mechanics): skip the rebuild
            upper, same = A, True
        else:
            upper = self._upper(A)
            same = self._is_stored_pattern(upper)
            self._ps._check_A(upper)
        if not same:  # new pattern: redo the analyses
            self._set_pattern(upper)
            self._free_solvers()
        self._upper_A = upper = self._cast(upper)
        from pypardiso.pardiso_wrapper import PyPardisoError

        try:
            self._factorize(-2 if self.positive_definite is False else 2, upper)
        except PyPardisoError:  # a non-positive pivot (error -4) under Cholesky: this matrix needs LDL^T
            if self.positive_definite != "auto":
                raise
            self.n_indefinite += 1
            self._factorize(-2, upper)

    def _factorize(self, mtype: int, upper: sp.csr_matrix) -> None:
        self._ps = self._analysed(mtype, upper)
        self._call(self._ps, 22, upper.data, np.zeros((self.n, 1), dtype=self._dtype))

    def solve(self, B: np.ndarray) -> np.ndarray:
        """Solve ``A X = B`` for one (shape ``(n,)``) or many (shape ``(n, k)``) right-hand sides."""
        B = np.asarray(B, dtype=np.float64)
        if B.shape[0] != self.n:
            raise ValueError(f"B: expected {self.n} rows, got shape {B.shape}")
        if self.backend == "scipy":
            return self._lu.solve(B)
        X = self._call(self._ps, 33, self._upper_A.data, np.asfortranarray(B, dtype=self._dtype))
        return X.astype(np.float64, copy=False)

    def _free_solvers(self) -> None:
        """Release every PARDISO handle's MKL memory (a new pattern, or the solver going away)."""
        for ps in getattr(self, "_solvers", {}).values():
            try:
                ps.free_memory(everything=True)
            except Exception:  # noqa: BLE001 - interpreter shutdown; nothing to report to
                pass
        self._solvers = {}

    def __del__(self):
        self._free_solvers()


def gmres(matvec, b: np.ndarray, precondition, atol: float, maxiter: int) -> tuple[np.ndarray, int, bool]:
    """Right-preconditioned GMRES (no restart) for ``A x = b``: minimises the true residual ``|b - A x|``.

    For Newton tangents that may be indefinite, with a factorization of a nearby tangent as ``M``. Gives up
    early when the residual's geometric rate so far cannot reach ``atol`` within ``maxiter`` iterations (the
    preconditioner is too stale: a new factorization is cheaper than more iterations).

    Parameters
    ----------
    matvec, precondition
        ``x -> A x`` and ``r -> M^-1 r`` for vectors of shape ``(n,)``.
    b
        Right-hand side, shape ``(n,)``.
    atol
        Stop when ``|b - A x| <= atol``.
    maxiter
        Iterations (preconditioner applications) before giving up.

    Returns
    -------
    x, iterations, converged
        ``x`` is the best iterate found (zeros if none), with shape ``(n,)``.
    """
    beta = float(np.linalg.norm(b))
    if beta <= atol:
        return np.zeros_like(b), 0, True
    V = [b / beta]
    Z = []
    H = np.zeros((maxiter + 1, maxiter))
    e1 = np.zeros(maxiter + 1)
    e1[0] = beta
    for k in range(maxiter):
        Z.append(precondition(V[k]))
        w = matvec(Z[k])
        for j in range(k + 1):  # modified Gram-Schmidt
            H[j, k] = float(w @ V[j])
            w -= H[j, k] * V[j]
        H[k + 1, k] = float(np.linalg.norm(w))
        y = np.linalg.lstsq(H[: k + 2, : k + 1], e1[: k + 2], rcond=None)[0]
        res = float(np.linalg.norm(H[: k + 2, : k + 1] @ y - e1[: k + 2]))
        rate = (res / beta) ** (1.0 / (k + 1))
        done = res <= atol or H[k + 1, k] <= 1e-14 * beta
        if done or k + 1 == maxiter or (k >= 2 and res * rate ** (maxiter - k - 1) > atol):
            x = np.asarray(Z[: k + 1]).T @ y
            return x, k + 1, bool(res <= atol)
        V.append(w / H[k + 1, k])
    raise AssertionError("unreachable")  # pragma: no cover
