"""Sparse direct solves: MKL PARDISO through pypardiso when it is installed, SuperLU otherwise.

PARDISO measured 10-50x faster than SuperLU on this project's 3D systems (``../shared/NOTES.md``). The
symbolic analysis (ordering, elimination tree) depends only on the sparsity pattern, so
:meth:`SymmetricSolver.refactor` re-uses it when only the values change (Newton steps, new conductivities).
The fallback is explicit: ``backend="scipy"`` or no pypardiso installed; :attr:`SymmetricSolver.backend`
says which one ran.
"""

from __future__ import annotations

import glob
import logging
import os
import sys

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

BACKENDS = ("auto", "pardiso", "scipy")


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
        Symmetric; only its upper triangle is read by PARDISO.
    positive_definite
        True for SPD systems (Cholesky-type, PARDISO ``mtype=2``); False for symmetric indefinite ones
        (``mtype=-2``; saddle points such as mixed u-p mechanics).
    backend
        ``"auto"`` (PARDISO if available), ``"pardiso"`` or ``"scipy"``.
    factorize
        False: only analyse the pattern of ``A`` now (PARDISO); call :meth:`refactor` with the first real
        values before :meth:`solve` (saves a numeric factorization when ``A`` is only a pattern template).
    """

    def __init__(self, A, positive_definite: bool = True, backend: str = "auto", factorize: bool = True):
        if backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
        if backend == "pardiso" and not pardiso_available():
            raise ImportError("backend='pardiso' needs pypardiso (pip install pypardiso)")
        self.backend = "pardiso" if backend in ("auto", "pardiso") and pardiso_available() else "scipy"
        self.positive_definite = positive_definite
        self.n = A.shape[0]
        self.n_factorizations = 0
        self._pattern = None
        if self.backend == "pardiso":
            import pypardiso

            # pypardiso searches the whole environment for mkl_rt on every construction (0.3 s here)
            # unless this variable names it: look in the usual place first, then remember what it found.
            if "PYPARDISO_MKL_RT" not in os.environ:
                found = sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmkl_rt.so*")))
                if found:
                    os.environ["PYPARDISO_MKL_RT"] = found[0]
            self._ps = pypardiso.PyPardisoSolver(mtype=2 if positive_definite else -2)
            os.environ.setdefault("PYPARDISO_MKL_RT", self._ps.libmkl._name)
            if positive_definite:
                # Cholesky of an SPD matrix needs no iterative refinement (results equal to 1e-13 without it);
                # skipping PARDISO's default two steps made dataset generation 1.8x faster here.
                self._ps.set_iparm(8, 0)
            upper = self._upper(A)
            self._pattern = (upper.indptr.copy(), upper.indices.copy())
            self._ps._check_A(upper)
            self._ps.set_phase(11)
            self._ps._call_pardiso(upper, np.zeros((self.n, 1)))
        if factorize or self.backend == "scipy":
            self.refactor(A)

    @staticmethod
    def _upper(A) -> sp.csr_matrix:
        # PARDISO's symmetric storage needs every diagonal entry stored, even a zero (saddle-point blocks).
        S = sp.triu(sp.coo_matrix(A), k=1)
        n = A.shape[0]
        diag = np.arange(n)
        U = sp.csr_matrix((np.r_[S.data, A.diagonal()], (np.r_[S.row, diag], np.r_[S.col, diag])), shape=(n, n))
        U.sort_indices()
        return U

    def refactor(self, A) -> None:
        """Numeric factorization of new values; the symbolic analysis is reused when the pattern is unchanged."""
        if A.shape != (self.n, self.n):
            raise ValueError(f"A: expected shape {(self.n, self.n)}, got {A.shape}")
        self.n_factorizations += 1
        if self.backend == "scipy":
            from scipy.sparse.linalg import splu

            self._lu = splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A")
            return
        upper = self._upper(A)
        same = (self._pattern is not None and np.array_equal(upper.indptr, self._pattern[0])
                and np.array_equal(upper.indices, self._pattern[1]))
        self._ps._check_A(upper)
        if not same:  # new pattern: redo the analysis
            self._pattern = (upper.indptr.copy(), upper.indices.copy())
            self._ps.set_phase(11)
            self._ps._call_pardiso(upper, np.zeros((self.n, 1)))
        self._upper_A = upper
        self._ps.set_phase(22)
        self._ps._call_pardiso(upper, np.zeros((self.n, 1)))

    def solve(self, B: np.ndarray) -> np.ndarray:
        """Solve ``A X = B`` for one (shape ``(n,)``) or many (shape ``(n, k)``) right-hand sides."""
        B = np.asarray(B, dtype=np.float64)
        if B.shape[0] != self.n:
            raise ValueError(f"B: expected {self.n} rows, got shape {B.shape}")
        if self.backend == "scipy":
            return self._lu.solve(B)
        self._ps.set_phase(33)
        X = self._ps._call_pardiso(self._upper_A, np.asfortranarray(B))
        return X

    def __del__(self):
        ps = getattr(self, "_ps", None)
        if ps is not None:
            try:
                ps.free_memory(everything=True)
            except Exception:  # noqa: BLE001 - interpreter shutdown; nothing to report to
                pass
