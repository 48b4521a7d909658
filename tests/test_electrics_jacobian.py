"""Adjoint Jacobian against finite differences; pixel projection against exact pixel volumes."""

import numpy as np
import pytest

from latticeopt.design import LatticeDesign
from latticeopt.electrics import ForwardModel
from latticeopt.electrics.pixels import pixel_matrix
from latticeopt.mesh import MeshSettings, mesh_design


@pytest.fixture(scope="module")
def model():
    mesh = mesh_design(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=5), cache_dir=False)
    base = ForwardModel(mesh)
    rng = np.random.default_rng(3)
    return base.with_conductivity(rng.uniform(0.5, 2.0, base.mesh.n_tets))


def _fd_column(model, k, h=1e-3):
    step = h * model.sigma[k]
    up, down = model.sigma.copy(), model.sigma.copy()
    up[k] += step
    down[k] -= step
    return (model.with_conductivity(up).voltages - model.with_conductivity(down).voltages) / (2 * step)


def test_adjoint_matches_finite_differences(model):
    J = model.jacobian()
    assert J.shape == (208, model.mesh.n_tets)
    rng = np.random.default_rng(4)
    norms = np.linalg.norm(J, axis=0)
    sample = np.r_[np.argsort(norms)[-3:], rng.choice(model.mesh.n_tets, 5, replace=False)]
    worst = 0.0
    for k in sample:
        fd = _fd_column(model, k)
        worst = max(worst, np.linalg.norm(fd - J[:, k]) / np.linalg.norm(J[:, k]))
    print(f"finite-difference vs adjoint Jacobian: worst relative column error {worst:.1e}")
    assert worst < 1e-4


def test_point_mode_euler_identity(model):
    """Without contact impedance V is homogeneous of degree -1 in sigma, so J sigma = -V exactly."""
    point = ForwardModel(model.mesh, model.sigma, electrode_mode="point")
    np.testing.assert_allclose(point.jacobian() @ point.sigma, -point.voltages, rtol=1e-9,
                               atol=1e-12 * np.abs(point.voltages).max())


def test_pixel_jacobian_is_the_chain_rule(model):
    n = 12
    F = model.pixel_matrix(n)
    J = model.jacobian()
    Jp = model.pixel_jacobian(n)
    np.testing.assert_allclose(Jp.sum(axis=1), J.sum(axis=1), rtol=1e-12)
    # A conductivity change of the hydrogel under pixel p (each element by its overlap) moves the voltages by
    # the pixel column.
    # pixels at the rim next to a corner and at the centre, each over a channel (the corner pixels themselves lie
    # on silicone without a rim channel)
    for p in (1, 5 * n + 6, n * n - 2):
        delta = 1e-3 * model.sigma.mean()
        w = np.asarray(F[:, p].todense()).ravel()
        assert w.sum() > 0
        dv = (model.with_conductivity(model.sigma + delta * w).voltages
              - model.with_conductivity(model.sigma - delta * w).voltages) / (2 * delta)
        assert np.linalg.norm(dv - Jp[:, p]) / np.linalg.norm(Jp[:, p]) < 1e-4
        # ... and that column sums the columns of the elements beneath the pixel, weighted by overlap.
        cover = np.nonzero(w)[0]
        np.testing.assert_allclose(Jp[:, p], J[:, cover] @ w[cover], rtol=1e-12)


def _exact_gel_area(design: LatticeDesign, n: int) -> np.ndarray:
    h = design.size_mm / n
    edges = np.linspace(0, design.size_mm, n + 1)
    if not design.has_lattice:
        return np.full((n, n), h * h)
    iv = design.channel_intervals_mm()
    cover = np.array([sum(max(0.0, min(b, hi) - max(a, lo)) for lo, hi in iv) for a, b in zip(edges, edges[1:])])
    return h * h - np.outer(h - cover, h - cover)  # [iy, ix]: pixel minus the silicone island part


@pytest.mark.parametrize("width, jitter", [(0.0, False), (0.0, True), (4.0, False)])
def test_pixel_volumes_are_exact(width, jitter):
    """Hydrogel volume above every pixel equals the analytic channel area times t, on straight and jittered tets."""
    design = LatticeDesign(width_mm=width, thickness_mm=3)
    mesh, _ = mesh_design(design, MeshSettings(size_mm=5), cache_dir=False).restrict(("hydrogel",))
    nodes = mesh.nodes_mm.copy()
    if jitter:
        # Move interior nodes sideways (z kept): the slab and its columns are unchanged, the tets are not
        # axis-aligned any more.
        rng = np.random.default_rng(5)
        inner = np.all((nodes[:, :2] > 1e-9) & (nodes[:, :2] < design.size_mm - 1e-9), axis=1)
        nodes[inner, :2] += rng.uniform(-0.8, 0.8, (inner.sum(), 2))
    n = 48
    F = pixel_matrix(nodes, mesh.tets, n, (0, design.size_mm, 0, design.size_mm))
    np.testing.assert_allclose(np.asarray(F.sum(axis=1)).ravel(), 1.0, rtol=1e-12)
    vol = np.abs(np.linalg.det(nodes[mesh.tets[:, 1:]] - nodes[mesh.tets[:, :1]])) / 6
    expected = (_exact_gel_area(design, n) * design.thickness_mm).ravel()
    np.testing.assert_allclose(F.T @ vol, expected, rtol=1e-10, atol=1e-10 * expected.max())
