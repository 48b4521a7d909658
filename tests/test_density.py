"""Density layouts: adjoint gradients of V_rel, force and stretch against central finite differences, the split
of the V_rel gradient into its electrics and mechanics parts, the sharp (0/1) limit against a conforming mesh of
the same layout, warm starts, and the density file's checks."""

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.coupled import PhysicsSettings, relative_change
from latticeopt.density import DensityModel, density_of_design, load_density, save_density
from latticeopt.density.mesh import density_mesh
from latticeopt.electrics.forward import ForwardModel
from latticeopt.electrics.sensitivity import weighted_sensitivities
from latticeopt.errors import ParameterError
from latticeopt.mechanics import IndentationSolver
from latticeopt.mesh.grid import tensor_mesh
from latticeopt.touches import Touch

N = 8
PRESS = [[Touch(40.0, 55.0, 12.0, 2.5)]]
H = 1e-4  # central-difference step in density units (truncation error ~1e-8 relative here)


@pytest.fixture(scope="module")
def model():
    # tight Newton tolerance: the adjoint is exact only at the exact equilibrium
    return DensityModel(LatticeDesign(thickness_mm=3.0), N, MeshSettings(size_mm=6.0),
                        PhysicsSettings(mechanics_rtol=1e-10))


@pytest.fixture(scope="module")
def base(model):
    rng = np.random.default_rng(1)
    d = 0.3 + 0.4 * rng.random((N, N))
    return d, model.evaluate(d, PRESS)


def smooth_direction(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:N, 0:N] / N
    a, b, c = rng.normal(size=3)
    return a * np.sin(2 * np.pi * x + c) * np.cos(np.pi * y) + b * x * y


@pytest.mark.parametrize("name, grad", [("v_rel", "dv_rel_ddensity"), ("force_N", "dforce_ddensity"),
                                        ("stretch", "dstretch_ddensity")])
def test_gradient_matches_central_differences(model, base, name, grad):
    d, ev = base
    direction = smooth_direction(7)
    plus = model.evaluate(d + H * direction, PRESS, gradient=False)
    minus = model.evaluate(d - H * direction, PRESS, gradient=False)
    fd = (getattr(plus, name) - getattr(minus, name)) / (2 * H)
    ad = float(np.sum(getattr(ev, grad) * direction))
    assert abs(ad - fd) <= 1e-4 * abs(fd)


def test_gradient_per_cell(model, base):
    d, ev = base
    for i, j in [(3, 2), (0, 5)]:  # a cell under the press and one at an electrode
        e = np.zeros((N, N))
        e[i, j] = 1.0
        fd = (model.evaluate(d + H * e, PRESS, gradient=False).v_rel
              - model.evaluate(d - H * e, PRESS, gradient=False).v_rel) / (2 * H)
        assert abs(ev.dv_rel_ddensity[i, j] - fd) <= 1e-4 * abs(fd) + 1e-9 * np.abs(ev.dv_rel_ddensity).max()


def _vrel_split(model, d, u, d_mech):
    """V_rel with the electrics' conductivities from ``d`` on the displacement of ``d_mech`` (``u`` if None)."""
    _, (mu, kappa, sigma), _ = model.materials(d)
    ref = model.electrics.with_conductivity(sigma)
    if d_mech is not None:
        _, (mu, kappa, _), _ = model.materials(d_mech)
        ind = model.mechanics.with_moduli(mu, kappa).solve(PRESS[0])
        u = ind.deformed_mesh.nodes_mm
    return relative_change(ref.with_nodes(u).voltages, ref.voltages)


def test_electrics_and_mechanics_parts_each_match_differences(model, base):
    d, ev = base
    press = ev.presses[0]
    direction = smooth_direction(3)
    nodes = model.mesh.nodes_mm + press.displacement_mm  # no punch rim moves a layer node
    # electrics: the displacement held, the conductivities moved
    fd_e = (_vrel_split(model, d + H * direction, nodes, None)
            - _vrel_split(model, d - H * direction, nodes, None)) / (2 * H)
    assert abs(np.sum(press.dv_rel_electrics * direction) - fd_e) <= 1e-4 * abs(fd_e)
    # mechanics: the conductivities held, the moduli moved
    fd_m = (_vrel_split(model, d, None, d + H * direction) - _vrel_split(model, d, None, d - H * direction)) / (2 * H)
    assert abs(np.sum(press.dv_rel_mechanics * direction) - fd_m) <= 1e-4 * abs(fd_m)
    assert abs(fd_e) > 1e-6 and abs(fd_m) > 1e-6  # both parts matter, so both checks can fail


def test_electrics_sensitivity_against_the_jacobian_and_node_differences():
    mesh = density_mesh(LatticeDesign(thickness_mm=2.0), 4, MeshSettings(size_mm=8.0))
    rng = np.random.default_rng(0)
    fm = ForwardModel(mesh, sigma_S_per_m=1.0 + rng.random(np.count_nonzero(mesh.region == 1)))
    a = rng.normal(size=len(fm.voltages))
    d_sigma, d_nodes = weighted_sensitivities(fm, a)
    np.testing.assert_allclose(d_sigma, a @ fm.jacobian(), rtol=1e-9, atol=1e-12 * np.abs(d_sigma).max())
    move = rng.normal(size=fm.mesh.nodes_mm.shape)  # every gel node, electrode patches included
    h = 1e-5
    fd = (a @ fm.with_nodes(fm.mesh.nodes_mm + h * move).voltages
          - a @ fm.with_nodes(fm.mesh.nodes_mm - h * move).voltages) / (2 * h)
    assert abs(np.sum(d_nodes * move) - fd) <= 1e-6 * abs(fd)


def test_sharp_density_reproduces_the_conforming_mesh():
    """A 0/1 density whose edges lie on the density mesh's lines gives the V_rel of the same mesh with the
    layout's regions (the conforming model: electrics on the gel alone), up to the insulating floor."""
    design = LatticeDesign(width_mm=12.5, pitch_mm=25.0, thickness_mm=3.0)
    n, settings = 16, MeshSettings(size_mm=6.25)
    d = density_of_design(design, n)
    assert set(np.unique(d)) == {0.0, 1.0}
    model = DensityModel(design, n, settings, PhysicsSettings(mechanics_rtol=1e-8))
    v_density = model.evaluate(d, PRESS, gradient=False).v_rel
    m = model.mesh
    x, y, z = (np.unique(m.nodes_mm[:, i]) for i in range(3))
    conforming = tensor_mesh(design, x, y, z)
    gel = np.zeros(m.n_tets, dtype=bool)
    gel[model.layer_tets] = model.cells @ d.ravel() > 0.5
    assert np.array_equal(conforming.region == 1, gel)  # the same mesh, the same layout
    ind = IndentationSolver(conforming, PhysicsSettings(mechanics_rtol=1e-8).indent_settings()).solve(PRESS[0])
    fm = ForwardModel(conforming)
    v_conf = relative_change(fm.with_nodes(ind.deformed_mesh.nodes_mm).voltages, fm.voltages)
    assert abs(v_density - v_conf) <= 1e-4 * v_conf


def test_warm_start_saves_newton_steps(model, base):
    d, ev = base
    nearby = np.clip(d + 0.02 * smooth_direction(5), 0, 1)
    cold = model.evaluate(nearby, PRESS, gradient=False).presses[0]
    warm = model.evaluate(nearby, PRESS, gradient=False, warm=[ev.presses[0].displacement_mm]).presses[0]
    assert warm.warm_start and not cold.warm_start
    assert warm.newton_steps < cold.newton_steps
    assert abs(warm.v_rel - cold.v_rel) <= 1e-7 * cold.v_rel


def test_worker_processes_give_the_serial_presses_in_order(model, base):
    """jobs > 1 presses each phantom in a worker process that builds its own copy of the model: the presses come
    back in the phantoms' order, warm starts included, and equal the serial ones (the same computation)."""
    d, ev = base
    phantoms = [PRESS[0], [Touch(70.0, 30.0, 10.0, 1.5)], [Touch(30.0, 30.0, 9.0, 3.0), Touch(70.0, 70.0, 9.0, 1.0)]]
    warm = [ev.presses[0].displacement_mm, None, None]
    serial = model.evaluate(d, phantoms, warm=warm)
    parallel = model.evaluate(d, phantoms, warm=warm, jobs=2)
    assert len({round(p.v_rel, 6) for p in serial.presses}) == 3  # distinct presses: an order swap would show
    for s, p in zip(serial.presses, parallel.presses):
        assert p.warm_start == s.warm_start and p.newton_steps == s.newton_steps
        assert p.v_rel == pytest.approx(s.v_rel, rel=1e-9)
        np.testing.assert_allclose(p.dv_rel, s.dv_rel, rtol=1e-7, atol=1e-12 * np.abs(s.dv_rel).max())
    np.testing.assert_allclose(parallel.reference_voltages, serial.reference_voltages, rtol=1e-12)
    assert parallel.v_rel == pytest.approx(serial.v_rel, rel=1e-9)
    with pytest.raises(ParameterError, match="warm"):
        model.evaluate(d, phantoms, warm=warm[:2])


@pytest.mark.parametrize("content, words", [
    ({"density": np.full((3, 3), 0.5)}, "4 <= n <= 400"),
    ({"density": np.full((6, 5), 0.5)}, "shape (6, 5)"),
    ({"density": np.full((6, 6), np.nan)}, "NaN"),
    ({"density": np.full((6, 6), 1.5)}, "values in [0, 1]"),
    ({"other": np.full((6, 6), 0.5)}, "members ['other']"),
    ({"density": np.array([{"a": 1}] * 36, dtype=object).reshape(6, 6)}, "pickle"),
])
def test_bad_density_files_name_the_problem(tmp_path, content, words):
    path = tmp_path / "d.npz"
    np.savez(path, **content)
    with pytest.raises(ParameterError) as exc:
        load_density(path)
    assert words.lower() in str(exc.value).lower() and "--density" in str(exc.value)


def test_density_files_round_trip_and_smooth_projection(tmp_path):
    design = LatticeDesign(width_mm=4.0, thickness_mm=3.0)
    sharp = density_of_design(design, 50)
    np.testing.assert_allclose(sharp.mean(), design.hydrogel_area_fraction(), rtol=1e-9)
    smooth = density_of_design(design, 50, smoothing_mm=1.0)
    assert 0 < smooth.min() and smooth.max() < 1 and abs(smooth.mean() - sharp.mean()) < 0.05
    save_density(tmp_path / "d.npz", sharp)
    np.testing.assert_array_equal(load_density(tmp_path / "d.npz"), sharp)


def test_chain_rule_to_the_channel_width(model):
    """The density gradient serves a parametric variable: dV_rel/dw through the smoothed projection against a
    central difference over w of the whole model (projection, mechanics and electrics)."""
    from latticeopt.density import parameter_gradient

    design, s = LatticeDesign(width_mm=6.0, thickness_mm=3.0), 4.0
    ev = model.evaluate(density_of_design(design, N, s), PRESS)
    chain = parameter_gradient(design, "width_mm", ev.dv_rel_ddensity, s)
    h = 1e-3
    fd = (model.evaluate(density_of_design(design.replace(width_mm=6.0 + h), N, s), PRESS, gradient=False).v_rel
          - model.evaluate(density_of_design(design.replace(width_mm=6.0 - h), N, s), PRESS, gradient=False).v_rel
          ) / (2 * h)
    assert abs(chain - fd) <= 1e-4 * abs(fd)


def test_sharp_jumps_become_grid_lines():
    """Cells finer than the mesh: without the density the elements straddle a sharp edge and are grey; with it
    (what simulate --density does) every element is 0 or 1, and a small change of the density keeps the mesh."""
    from latticeopt.density.mesh import cell_matrix

    d = np.zeros((32, 32))
    d[:, 5:7] = 1.0   # a channel between x = 15.625 and 21.875 mm: edges inside the 6.25 mm columns of the mesh
    d[20:23, :] = 1.0
    grey = []
    for sharp in (None, d):
        mesh = density_mesh(LatticeDesign(thickness_mm=3.0), 32, MeshSettings(size_mm=8.0), sharp)
        A, _ = cell_matrix(mesh, 32)
        rho = A @ d.ravel()
        grey.append(int(np.sum((rho > 1e-9) & (rho < 1 - 1e-9))))
    assert grey[0] > 0 and grey[1] == 0
    nudged = density_mesh(LatticeDesign(thickness_mm=3.0), 32, MeshSettings(size_mm=8.0), np.clip(d + 1e-3, 0, 1))
    assert nudged.n_nodes == density_mesh(LatticeDesign(thickness_mm=3.0), 32, MeshSettings(size_mm=8.0), d).n_nodes


def test_isolation_gradient_matches_differences(model):
    rng = np.random.default_rng(4)
    d = 0.2 + 0.6 * rng.random((N, N))
    value, g = model.isolation(d)
    h = 1e-5
    for direction in (smooth_direction(11), smooth_direction(12)):
        fd = (model.isolation(d + h * direction)[0] - model.isolation(d - h * direction)[0]) / (2 * h)
        assert abs(np.sum(g * direction) - fd) <= 1e-5 * abs(fd)
    e = np.zeros((N, N))
    e[0, 1] = 1.0  # a cell at electrode 1
    fd = (model.isolation(d + h * e)[0] - model.isolation(d - h * e)[0]) / (2 * h)
    assert g[0, 1] == pytest.approx(fd, rel=1e-5)
    assert model.isolation(np.ones((N, N)))[0] == pytest.approx(1.0, rel=1e-9)  # the uniform layer itself


@pytest.fixture(scope="module")
def model20():
    """5 mm cells: every electrode inside one column of cells, so pieces can be drawn per electrode."""
    return DensityModel(LatticeDesign(thickness_mm=3.0), 20, MeshSettings(size_mm=6.0))


def d4(quarter: np.ndarray) -> np.ndarray:
    q = quarter
    return np.maximum.reduce([q, q[::-1], q[:, ::-1], q[::-1, ::-1], q.T, q.T[::-1], q.T[:, ::-1], q.T[::-1, ::-1]])


def fe_pair_measure(model, density, p=8.0):
    """The same 8-norm with the pair resistances of the finite-element electrics."""
    _, (_, _, sigma), _ = model.materials(density)
    q = model.electrics.with_conductivity(sigma).pair_resistances / model.electrics.pair_resistances
    return float(np.mean(q ** p) ** (1.0 / p))


def row_measure(model, density, p=8.0):
    """The first bound: an 8-norm over the adjacent measurement rows of Vref / Vuniform."""
    _, (_, _, sigma), _ = model.materials(density)
    q = model.electrics.with_conductivity(sigma).voltages / model.electrics.voltages
    return float(np.mean(np.abs(q) ** p) ** (1.0 / p))


def test_isolation_sees_every_piece_of_gel(model20):
    n = 20
    net = np.zeros((n, n))
    net[:, [7, 12]] = net[[7, 12], :] = 1.0  # channels through the electrodes at 37.5 and 62.5 mm on every side
    spur = np.zeros((n, n))
    spur[0:8, 2] = spur[2, 0:8] = 1.0  # the electrodes at 12.5 mm (and by symmetry 87.5 mm) joined to the net
    joined = np.maximum(net, d4(spur))
    lattice = density_of_design(LatticeDesign(width_mm=4.0, thickness_mm=3.0), n)
    for connected in (joined, lattice):
        assert 1.0 < model20.isolation(connected)[0] < 10.0
    # four corner pieces each holding two neighbouring electrodes (1 and 16, ...), as the first bound let through
    corners = net.copy()
    corners[:4, :4] = corners[:4, -4:] = corners[-4:, :4] = corners[-4:, -4:] = 1.0
    assert model20.isolation(corners)[0] > 1e4
    # one electrode on a pad of its own: no adjacent measurement row reads across its gap, the pairs do
    alone = joined.copy()
    alone[1, 2] = 0.0
    assert model20.isolation(alone)[0] > 1e4
    assert row_measure(model20, alone) == pytest.approx(row_measure(model20, joined), rel=0.05)


def test_isolation_network_matches_the_electrics_but_not_across_corners(model20):
    """On layouts joined across cell sides the cells' network reads what the finite-element electrics read (20 %
    on this 6 mm mesh; 1-5 % on the default 2 mm mesh); a pad joined to the rest only at a cell corner conducts
    through the element mesh's shared edge but not in the network, nor in the cast outline."""
    n = 20
    net = np.zeros((n, n))
    net[:, [7, 12]] = net[[7, 12], :] = 1.0
    spur = np.zeros((n, n))
    spur[0:8, 2] = spur[2, 0:8] = 1.0
    joined = np.maximum(net, d4(spur))
    lattice = density_of_design(LatticeDesign(width_mm=4.0, thickness_mm=3.0), n)
    for d in (joined, lattice):
        assert model20.isolation(d)[0] == pytest.approx(fe_pair_measure(model20, d), rel=0.25)
    corner = joined.copy()
    corner[1, 2], corner[1, 1] = 0.0, 1.0  # electrode 1's pad (row 0, column 2) meets the spur at a corner only
    assert fe_pair_measure(model20, corner) < 10.0
    assert model20.isolation(corner)[0] > 1e4
