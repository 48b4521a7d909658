"""Sparse direct solves: PARDISO (double and single precision) against SuperLU and against the matrix itself."""

import numpy as np
import pytest
import scipy.sparse as sp

from latticeopt.linalg import SymmetricSolver, pardiso_available

pardiso = pytest.mark.skipif(not pardiso_available(), reason="pypardiso not installed")


def _laplacian_3d(n: int, shift: float = 0.1) -> sp.csr_matrix:
    """SPD 7-point Laplacian on an n^3 grid plus a diagonal shift (independent of the solver)."""
    T = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    eye = sp.identity(n)
    A = sp.kron(sp.kron(T, eye), eye) + sp.kron(sp.kron(eye, T), eye) + sp.kron(sp.kron(eye, eye), T)
    return sp.csr_matrix(A + shift * sp.identity(n ** 3))


@pytest.fixture(scope="module")
def system():
    A = _laplacian_3d(12)
    b = np.random.default_rng(0).standard_normal((A.shape[0], 2))
    return A, b


def test_scipy_backend_solves_to_round_off(system):
    A, b = system
    x = SymmetricSolver(A, backend="scipy").solve(b)
    assert np.linalg.norm(A @ x - b) <= 1e-12 * np.linalg.norm(b)


@pardiso
@pytest.mark.parametrize("positive_definite", [True, False])
def test_pardiso_double_matches_superlu(system, positive_definite):
    A, b = system
    x = SymmetricSolver(A, positive_definite=positive_definite, backend="pardiso").solve(b)
    y = SymmetricSolver(A, backend="scipy").solve(b)
    assert np.abs(x - y).max() <= 1e-12 * np.abs(y).max()


@pardiso
def test_pardiso_single_precision_is_accurate_to_float32(system):
    A, b = system
    s = SymmetricSolver(A, backend="pardiso", precision="single")
    x = s.solve(b[:, 0])
    assert x.dtype == np.float64 and s.precision == "single"
    rel = np.linalg.norm(A @ x - b[:, 0]) / np.linalg.norm(b[:, 0])
    assert 1e-10 < rel < 1e-4  # float32 round-off: clearly not double, clearly a solve


@pardiso
def test_refactor_with_new_values_on_the_analysed_upper_pattern(system):
    """The mechanics passes the upper triangle in the analysed pattern; new values must be used."""
    A, b = system
    s = SymmetricSolver(A, backend="pardiso", factorize=False)
    A2 = A + sp.diags(np.linspace(1.0, 2.0, A.shape[0]))
    upper = sp.csr_matrix(sp.triu(A2))
    s.refactor(upper)
    x = s.solve(b[:, 1])
    assert np.linalg.norm(A2 @ x - b[:, 1]) <= 1e-12 * np.linalg.norm(b[:, 1])


def test_bad_arguments_are_named(system):
    A, _ = system
    with pytest.raises(ValueError, match="precision"):
        SymmetricSolver(A, precision="half")
    with pytest.raises(ValueError, match="backend"):
        SymmetricSolver(A, backend="mumps")
