"""The neo-Hookean operator against finite differences, the patch structure, materials and Hayes' kappa."""

import numpy as np
import pytest
import scipy.sparse as sp

from latticeopt import LatticeDesign, MeshSettings, mesh_design
from latticeopt.errors import ParameterError
from latticeopt.mechanics import Materials, NeoHookean
from latticeopt.mechanics.assembly import NeoHookeanOperator, dilatation_patches
from latticeopt.mechanics.verification import block_mesh, hayes_kappa


@pytest.fixture(scope="module")
def small_block():
    return block_mesh(np.linspace(0, 3, 4), np.linspace(0, 2, 3), np.array([0.0, 0.7, 2.0]))


@pytest.mark.parametrize("volumetric", ["patch", "element"])
def test_residual_and_tangent_match_finite_differences(small_block, volumetric):
    mat = Materials(silicone=NeoHookean(23.0, 0.49), hydrogel=NeoHookean(5.0, 0.45))
    op = NeoHookeanOperator(small_block, mat, volumetric)
    rng = np.random.default_rng(1)
    u = 0.12 * rng.standard_normal((small_block.n_nodes, 3))  # large, non-symmetric strains
    ev = op.evaluate(u)
    assert not ev.inverted
    du = 1e-6 * rng.standard_normal(u.shape)
    e_plus = op.evaluate(u + du, residual=False).energy_Nmm
    e_minus = op.evaluate(u - du, residual=False).energy_Nmm
    assert (e_plus - e_minus) / 2 == pytest.approx(ev.residual_N @ du.ravel(), rel=1e-6)
    U = sp.csr_matrix((ev.data, op.indices, op.indptr), shape=(op.n_dofs,) * 2)
    K = (U + U.T - sp.diags(U.diagonal())).toarray()
    fd = (op.evaluate(u + du).residual_N - op.evaluate(u - du).residual_N) / 2
    assert np.abs(K @ du.ravel() - fd).max() <= 1e-6 * np.abs(fd).max()


def test_reference_state_is_stress_free_and_inversion_is_reported(small_block):
    op = NeoHookeanOperator(small_block, Materials())
    ev = op.evaluate(np.zeros((small_block.n_nodes, 3)))
    assert ev.energy_Nmm == pytest.approx(0.0, abs=1e-14)
    assert np.abs(ev.residual_N).max() < 1e-14
    u = np.zeros((small_block.n_nodes, 3))
    u[:, 2] = -1.2 * small_block.nodes_mm[:, 2]  # squash through the bottom: every tet inverts
    bad = op.evaluate(u)
    assert bad.inverted and bad.energy_Nmm == np.inf and bad.residual_N is None


def test_rigid_motion_costs_nothing(small_block):
    op = NeoHookeanOperator(small_block, Materials())
    X = small_block.nodes_mm
    c, s = np.cos(0.7), np.sin(0.7)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    u = X @ Rz.T - X + np.array([1.0, -2.0, 0.5])
    ev = op.evaluate(u)
    assert abs(ev.energy_Nmm) < 1e-12 and np.abs(ev.residual_N).max() < 1e-12


def test_grid_patches_are_the_hexahedral_cells_and_never_mix_regions():
    mesh = mesh_design(LatticeDesign(size_mm=50.0), MeshSettings(size_mm=5.0), cache_dir=False)
    patch = dilatation_patches(mesh)
    counts = np.bincount(patch)
    assert np.all(counts == 6)  # six Kuhn tets per cell
    for p in np.unique(patch)[:: max(1, len(counts) // 200)]:
        assert len(np.unique(mesh.tets[patch == p])) == 8
    per_patch_regions = {int(p): set(mesh.region[patch == p].tolist()) for p in range(len(counts))}
    assert all(len(r) == 1 for r in per_patch_regions.values())
    assert np.array_equal(dilatation_patches(mesh, "element"), np.arange(mesh.n_tets))


def test_materials_validate_and_convert():
    m = NeoHookean(20.0, 0.25)
    assert m.mu_MPa == pytest.approx(0.02)
    assert m.kappa_MPa == pytest.approx(0.02 * 2 * 1.25 / (3 * 0.5))
    assert m.youngs_modulus_kPa == pytest.approx(50.0)
    for bad in ({"shear_modulus_kPa": 0, "poisson_ratio": 0.3}, {"shear_modulus_kPa": 5, "poisson_ratio": 0.5},
                {"shear_modulus_kPa": float("nan"), "poisson_ratio": 0.3}):
        with pytest.raises(ParameterError):
            NeoHookean(**bad)
    mats = Materials()
    mu, kappa = mats.moduli_MPa(np.array([0, 1, 2, 3], dtype=np.int8))
    assert mu[1] == mats.hydrogel.mu_MPa and mu[0] == mu[2] == mu[3] == mats.silicone.mu_MPa
    with pytest.raises(ParameterError, match="silicone"):
        Materials(silicone=3.0)


def test_hayes_kappa_limits_and_trends():
    # half-space limit: kappa -> 1, with a first-order correction linear in a/h
    k1, k2 = hayes_kappa(0.002, 0.3), hayes_kappa(0.004, 0.3)
    assert k1 == pytest.approx(1.0, abs=3e-3)
    assert (k2 - 1) / (k1 - 1) == pytest.approx(2.0, rel=0.02)
    # thinner layers and less compressible layers are stiffer
    ks = [hayes_kappa(r, 0.45) for r in (0.25, 0.5, 1.0, 2.0)]
    assert np.all(np.diff(ks) > 0)
    assert hayes_kappa(1.0, 0.3) < hayes_kappa(1.0, 0.45) < hayes_kappa(1.0, 0.5)
    # converged in the quadrature
    assert hayes_kappa(1.0, 0.49, 32) == pytest.approx(hayes_kappa(1.0, 0.49, 96), rel=1e-8)


def test_element_kernel_equals_scikit_fem_forms(small_block):
    """The same decoupled neo-Hookean energy written as scikit-fem forms (helpers, 4-point quadrature)."""
    from skfem import Basis, BilinearForm, ElementTetP0, ElementTetP1, ElementVector, LinearForm, asm
    from skfem.helpers import ddot, det, eye, grad, inv, mul, transpose

    def parts(w):
        G = grad(w["disp"])
        F = G + eye(np.ones_like(G[0, 0]), 3)
        return F, det(F), transpose(inv(F))

    @LinearForm
    def residual(v, w):
        F, J, FiT = parts(w)
        P = w.mu * J ** (-2 / 3) * (F - ddot(F, F) / 3 * FiT) + 0.5 * w.kap * (J * J - 1) * FiT
        return ddot(P, grad(v))

    @BilinearForm
    def tangent(u, v, w):
        F, J, FiT = parts(w)
        C, I1, dF = J ** (-2 / 3), ddot(F, F), grad(u)
        dJ = J * ddot(FiT, dF)
        dFiT = -transpose(mul(mul(inv(F), dF), inv(F)))
        dP = (w.mu * (-2 / 3 * C / J * dJ * (F - I1 / 3 * FiT) + C * (dF - 2 * ddot(F, dF) / 3 * FiT - I1 / 3 * dFiT))
              + w.kap * J * dJ * FiT + 0.5 * w.kap * (J * J - 1) * dFiT)
        return ddot(dP, grad(v))

    mats = Materials(silicone=NeoHookean(23.0, 0.49), hydrogel=NeoHookean(5.0, 0.45))
    basis = Basis(small_block.to_skfem(), ElementVector(ElementTetP1()), intorder=2)
    pb = basis.with_element(ElementTetP0())
    mu, kap = (pb.interpolate(a) for a in mats.moduli_MPa(small_block.region))
    u = 0.1 * np.random.default_rng(3).standard_normal(basis.N)
    w = basis.interpolate(u)
    R = asm(residual, basis, disp=w, mu=mu, kap=kap)
    K = asm(tangent, basis, disp=w, mu=mu, kap=kap)
    op = NeoHookeanOperator(small_block, mats, "element")
    ev = op.evaluate(u.reshape(-1, 3))  # scikit-fem's vector P1 DOFs are interleaved per node, like ours
    U = sp.csr_matrix((ev.data, op.indices, op.indptr), shape=(op.n_dofs,) * 2)
    assert np.abs(R - ev.residual_N).max() <= 1e-12 * np.abs(R).max()
    assert abs(K - (U + U.T - sp.diags(U.diagonal()))).max() <= 1e-12 * abs(K).max()


def _full(op, data):
    U = sp.csr_matrix((data, op.indices, op.indptr), shape=(op.n_dofs,) * 2)
    return (U + U.T - sp.diags(U.diagonal())).toarray()


def test_projected_tangent_is_the_tangent_without_its_negative_parts(small_block):
    """A projected tangent (each patch block's negative eigenvalues set to 0) is positive semidefinite and differs
    from the tangent by a positive semidefinite part, on a squashed state whose tangent is indefinite; where every
    block is positive semidefinite (the undeformed stack) it is the tangent itself."""
    op = NeoHookeanOperator(small_block, Materials(silicone=NeoHookean(23.0, 0.49), hydrogel=NeoHookean(5.0, 0.45)))
    u0 = np.zeros((small_block.n_nodes, 3))
    K0, P0 = (_full(op, op.evaluate(u0, project=p).data) for p in (False, True))
    assert np.abs(P0 - K0).max() <= 1e-12 * np.abs(K0).max()
    rng = np.random.default_rng(4)
    u = 0.05 * rng.standard_normal(u0.shape)
    u[:, 2] -= 0.6 * small_block.nodes_mm[:, 2]  # squashed to 40 % of its height: compressive pressure
    ev = op.evaluate(u)
    assert not ev.inverted
    K, P = _full(op, ev.data), _full(op, op.evaluate(u, project=True).data)
    scale = np.abs(K).max()
    assert np.linalg.eigvalsh(K)[0] < -1e-6 * scale  # the case a projection is for
    assert np.linalg.eigvalsh(P)[0] >= -1e-12 * scale
    assert np.linalg.eigvalsh(P - K)[0] >= -1e-12 * scale
