"""Classical reconstruction: algebra against dense normal equations, GCV against its definition, and a centred
touch found where it is by every prior, one-step and iterative."""

import numpy as np
import pytest

from latticeopt.design import LatticeDesign
from latticeopt.mesh import MeshSettings
from latticeopt.recon.classical import PRIORS, GaussNewton, LinearReconstructor, laplacian_2d
from latticeopt.recon.dataset import add_noise, relative_change, render_touches
from latticeopt.sensor_model import SensorSimulator, build_sensor_model

TOUCH = np.array([[50.0, 50.0, 20.0, 0.2]])  # centred, 20 mm across, conductivity down to 0.2 sigma0


@pytest.fixture(scope="module")
def sim():
    return SensorSimulator(build_sensor_model(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=5),
                                              cache_dir=False))


@pytest.fixture(scope="module")
def frame(sim):
    m = sim.model
    img = render_touches(TOUCH, m.sigma0_S_per_m)
    V = add_noise(sim.voltages(img), 50.0, np.random.default_rng(0))
    return relative_change(V, m.v_ref)[0]


def _peak_distance(model, image) -> float:
    xy = model.pixel_centres_mm()[np.argmax(np.abs(image.ravel()))]
    return float(np.linalg.norm(xy - TOUCH[0, :2]))


@pytest.mark.parametrize("prior", PRIORS)
def test_one_step_finds_the_centred_touch(sim, frame, prior):
    lin = LinearReconstructor(sim.model, prior)
    x, lam = lin.solve(frame[None])
    d = _peak_distance(sim.model, x[0])
    print(f"{prior}: lambda / g_max {lam[0] / lin.eigenvalues.max():.1e}, peak {d:.1f} mm from the centre")
    assert d <= TOUCH[0, 2] / 2
    assert x[0].ravel()[np.argmax(np.abs(x[0]))] < 0  # the touch lowers the conductivity


@pytest.mark.parametrize("prior", PRIORS)
def test_gauss_newton_finds_the_centred_touch_and_lowers_the_objective(sim, frame, prior):
    res = GaussNewton(sim, prior, max_iter=4).reconstruct(frame[None])
    phi = np.array(res.objective[0])
    assert res.iterations[0] >= 2 and np.all(np.diff(phi) < 0)
    d = _peak_distance(sim.model, res.images[0])
    print(f"GN {prior}: {res.iterations[0]} iterations, objective {phi[0]:.3g} -> {phi[-1]:.3g}, peak {d:.1f} mm")
    assert d <= TOUCH[0, 2] / 2
    assert res.images[0].min() > -1  # log parametrization: conductivity stays positive


@pytest.mark.parametrize("prior", PRIORS)
def test_data_space_solution_equals_normal_equations(sim, frame, prior):
    lin = LinearReconstructor(sim.model, prior)
    lam = 1e-3 * lin.eigenvalues.max()
    x, _ = lin.solve(frame[None], lam)
    A, b = lin.A, lin.w * frame
    P = lin.prior.matrix.toarray()
    direct = np.linalg.solve(A.T @ A + lam * P, A.T @ b)
    np.testing.assert_allclose(x[0], direct, rtol=1e-6, atol=1e-8 * np.abs(direct).max())


def test_gcv_matches_its_definition(sim, frame):
    lin = LinearReconstructor(sim.model, "identity")
    grid = np.logspace(-7, -1, 7)
    lam, curve = lin.gcv(frame[None], grid)
    A, b = lin.A, lin.w * frame
    G = A @ A.T
    m = len(b)
    for j, rel in enumerate(grid):
        H = G @ np.linalg.inv(G + rel * lin.eigenvalues.max() * np.eye(m))
        gcv = np.sum(((np.eye(m) - H) @ b) ** 2) / np.trace(np.eye(m) - H) ** 2
        assert curve[0, j] == pytest.approx(gcv, rel=1e-6)
    assert lam[0] == pytest.approx(grid[np.argmin(curve[0])] * lin.eigenvalues.max())


def test_gcv_regularizes_more_for_more_noise(sim):
    m = sim.model
    V = sim.voltages(render_touches(TOUCH, m.sigma0_S_per_m))
    lin = LinearReconstructor(m, "laplacian")
    rng = np.random.default_rng(3)
    lam = [np.median(lin.gcv(relative_change(add_noise(np.repeat(V, 5, 0), snr, rng), m.v_ref))[0])
           for snr in (65, 45, 30)]
    assert lam[0] < lam[1] < lam[2]


def test_laplacian_is_symmetric_with_constants_in_its_null_space():
    L = laplacian_2d(7)
    assert abs(L - L.T).max() == 0
    np.testing.assert_allclose(L @ np.ones(49), 0)
    assert L[0, 0] == 2 and L[8, 8] == 4  # corner and interior pixel
