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


@pytest.mark.parametrize("prior", ["identity", "laplacian"])
def test_lcurve_norms_match_direct_solves(sim, frame, prior):
    """The L-curve's residual and prior norms from the eigenvalues equal those of explicit solves, and the corner
    is where the curvature of that curve (by finite differences here) is largest."""
    lin = LinearReconstructor(sim.model, prior)
    grid = np.logspace(-8, 0, 33)
    lam, kappa = lin.lcurve(frame[None], grid)
    A, b = lin.A, lin.w * frame
    P = lin.prior.matrix.toarray()
    X, Y = [], []
    for rel in grid:
        x, _ = lin.solve(frame[None], rel * lin.eigenvalues.max())
        X.append(0.5 * np.log(np.sum((A @ x[0] - b) ** 2)))
        Y.append(0.5 * np.log(x[0] @ P @ x[0]))
    t = np.log(grid * lin.eigenvalues.max())
    dX, dY = np.gradient(X, t), np.gradient(Y, t)
    brute = (dX * np.gradient(dY, t) - np.gradient(dX, t) * dY) / (dX ** 2 + dY ** 2) ** 1.5
    np.testing.assert_allclose(kappa[0], brute, rtol=1e-5, atol=1e-8 * np.abs(brute).max())
    assert lam[0] == pytest.approx(grid[np.argmax(brute)] * lin.eigenvalues.max())


def test_noise_free_frame_lcurve_stays_inside_its_grid_and_gcv_warns(sim, caplog):
    m = sim.model
    img = render_touches(np.array([[30.0, 30.0, 15.0, 0.3], [70.0, 60.0, 12.0, 0.3]]), m.sigma0_S_per_m)
    y = relative_change(sim.voltages(img), m.v_ref)
    lin = LinearReconstructor(m, "laplacian")
    g_max = lin.eigenvalues.max()
    with caplog.at_level("WARNING"):
        lam_l = lin.lambdas(y, "lcurve")[0] / g_max
    assert 1e-9 < lam_l < 10 and not caplog.records
    with caplog.at_level("WARNING"):
        lam_g = lin.lambdas(y, "gcv")[0] / g_max
    assert lam_g == pytest.approx(1e-9) and "end of its range" in caplog.text


def test_gauss_newton_warns_when_pixels_sit_on_the_bounds(sim, frame, caplog):
    with caplog.at_level("WARNING"):
        res = GaussNewton(sim, "identity", max_iter=3).reconstruct(frame[None] * 50, lam=1e-12)
    held = np.isclose(np.log1p(res.images[0]), np.log(1e-2)) | np.isclose(np.log1p(res.images[0]), np.log(1e2))
    assert held.any() == ("conductivity bounds" in caplog.text)
    assert held.any()
