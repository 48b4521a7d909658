"""Sparse direct solves: PARDISO (double and single precision) against SuperLU and against the matrix itself."""

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (loads scipy's OpenBLAS beside numpy's, so the thread tests set both)
import scipy.sparse as sp

from latticeopt.linalg import SymmetricSolver, gmres, pardiso_available

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


@pardiso
def test_auto_definiteness_falls_back_to_ldlt_only_when_needed(system):
    """``positive_definite="auto"``: Cholesky for the SPD Laplacian, LDL^T once it is shifted indefinite
    (eigenvalues of the 12^3 Laplacian lie in (0.1, 12.1), so a shift of -3 makes it indefinite)."""
    A, b = system
    solver = SymmetricSolver(A, positive_definite="auto", backend="pardiso")
    assert solver.n_indefinite == 0
    indefinite = sp.csr_matrix(A - 3.0 * sp.identity(A.shape[0]))
    for M, n_indefinite in ((indefinite, 1), (A, 1), (indefinite, 2)):
        solver.refactor(M)
        x = solver.solve(b)
        assert solver.n_indefinite == n_indefinite
        assert np.linalg.norm(M @ x - b) <= 1e-10 * np.linalg.norm(b)


@pytest.mark.parametrize("shift", [0.1, -3.0])
def test_gmres_with_a_nearby_factorization_reaches_the_tolerance(system, shift):
    """GMRES on A preconditioned by the factorization of a perturbed A (SPD and indefinite): the true
    residual meets atol, and the solution matches a direct solve."""
    A, b = system
    A = sp.csr_matrix(A + (shift - 0.1) * sp.identity(A.shape[0]))
    rng = np.random.default_rng(1)
    near = sp.csr_matrix(A + sp.diags(1e-3 * rng.random(A.shape[0])))
    M = SymmetricSolver(near, positive_definite=False, backend="scipy")
    rhs = b[:, 0]
    atol = 1e-8 * np.linalg.norm(rhs)
    x, its, ok = gmres(lambda v: A @ v, rhs, lambda r: M.solve(r), atol, 30)
    assert ok and its < 30
    assert np.linalg.norm(A @ x - rhs) <= 1.01 * atol
    assert np.abs(x - SymmetricSolver(A, positive_definite=False, backend="scipy").solve(rhs)).max() \
        <= 1e-6 * np.abs(x).max()


def test_gmres_gives_up_early_when_the_rate_cannot_reach_the_tolerance(system):
    """Unpreconditioned GMRES on the ill-conditioned Laplacian: after a few iterations the geometric rate
    cannot reach 1e-12 within the budget, so it stops before maxiter and says it did not converge."""
    A, b = system
    x, its, ok = gmres(lambda v: A @ v, b[:, 0], lambda r: r, 1e-12 * np.linalg.norm(b[:, 0]), 50)
    assert not ok and 3 <= its < 50
    assert np.linalg.norm(A @ x - b[:, 0]) < np.linalg.norm(b[:, 0])  # the best iterate still helps


@pytest.mark.parametrize("backend", ["scipy", pytest.param("pardiso", marks=pardiso)])
def test_only_the_upper_triangle_is_read(system, backend):
    """Given just the upper triangle (as the mechanics passes it), every backend solves the symmetric system."""
    A, b = system
    x = SymmetricSolver(sp.triu(A, format="csr"), backend=backend).solve(b)
    assert np.linalg.norm(A @ x - b) <= 1e-10 * np.linalg.norm(b)


def _openblas_threads() -> set[int]:
    from threadpoolctl import threadpool_info

    return {lib["num_threads"] for lib in threadpool_info() if lib["internal_api"] == "openblas"}


@pytest.fixture
def openblas_on_two_threads():
    """OpenBLAS set to 2 threads for the test (the suite's processes start on one), restored after."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=2, user_api="blas"):
        if _openblas_threads() != {2}:
            pytest.skip(f"no OpenBLAS that runs 2 threads here: {_openblas_threads()}")
        yield


def test_single_threaded_blas_holds_openblas_at_one_thread_and_restores_it(openblas_on_two_threads):
    from latticeopt.linalg import single_threaded_blas

    with single_threaded_blas():
        assert _openblas_threads() == {1}
    assert _openblas_threads() == {2}


def test_a_press_runs_on_one_openblas_thread(stack_solver, openblas_on_two_threads):
    seen = []
    stack_solver.solve([(25, 25, 7.5, 1.0)], progress=lambda d, final: seen.append(_openblas_threads()))
    assert seen and all(s == {1} for s in seen), seen
    assert _openblas_threads() == {2}
