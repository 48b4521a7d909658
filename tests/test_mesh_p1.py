"""P1 gradients and volumes (latticeopt.mesh.p1) against the hat functions' defining property and the einsum
volume formula of latticeopt.mesh.tetmesh."""

import numpy as np

from latticeopt.mesh.p1 import hat_gradients
from latticeopt.mesh.tetmesh import tet_volumes


def _random_tets(m: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    nodes = rng.uniform(-5.0, 5.0, (4 * m, 3))
    tets = np.arange(4 * m).reshape(m, 4)
    return nodes, tets


def test_gradients_reproduce_nodal_values_of_the_hat_functions():
    # N_a is linear with N_a(x_b) = delta_ab, so grad N_a . (x_b - x_c) = delta_ab - delta_ac for every pair
    nodes, tets = _random_tets(200)
    grad, _ = hat_gradients(nodes, tets)
    x = nodes[tets]  # (M, 4, 3)
    values = np.einsum("mak,mbk->mab", grad, x - x[:, :1])  # grad N_a . (x_b - x_0)
    expected = np.eye(4)[None] - np.eye(4)[:, :1][None]
    assert np.allclose(values, expected, atol=1e-11)
    assert np.allclose(grad.sum(axis=1), 0.0, atol=1e-12)  # the hat functions sum to one


def test_volumes_are_signed_like_the_einsum_formula():
    nodes, tets = _random_tets(200, seed=1)
    _, vol = hat_gradients(nodes, tets)
    assert np.any(vol < 0) and np.any(vol > 0)  # both orientations drawn
    assert np.allclose(vol, tet_volumes(nodes, tets), rtol=1e-12, atol=1e-12)


def test_a_flat_tet_gives_non_finite_gradients_not_an_error():
    nodes = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    grad, vol = hat_gradients(nodes, np.array([[0, 1, 2, 3]]))
    assert vol[0] == 0.0 and not np.all(np.isfinite(grad))
