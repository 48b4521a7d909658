"""Forward model against physics it does not encode: bar resistance, independent assembly, energy, symmetry."""

import numpy as np
import pytest
from skfem import Basis, BilinearForm, ElementTetP1, MeshTet
from skfem.helpers import dot, grad

from latticeopt.design import REGION_IDS, LatticeDesign
from latticeopt.electrics import ForwardModel, Protocol
from latticeopt.errors import MeshError, ParameterError
from latticeopt.mesh import MeshSettings, TetMesh, mesh_design
from latticeopt.mesh.facets import boundary_faces
from latticeopt.mesh.tetmesh import tet_volumes


def box_mesh(size_mm=(20.0, 4.0, 3.0), cells=(10, 3, 2), weight=None) -> TetMesh:
    """Hydrogel bar meshed with Kuhn tets; electrode_1 covers x = 0 and electrode_2 covers x = Lx."""
    axes = [np.linspace(0, s, c + 1) for s, c in zip(size_mm, cells)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    nodes = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    nx, ny, nz = (c + 1 for c in cells)
    idx = np.arange(nodes.shape[0]).reshape(nx, ny, nz)
    base = idx[:-1, :-1, :-1].ravel()
    step = (ny * nz, nz, 1)
    tets = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        v1 = base + step[perm[0]]
        v2 = v1 + step[perm[1]]
        tets.append(np.column_stack([base, v1, v2, v2 + step[perm[2]]]))
    tets = np.concatenate(tets)
    neg = tet_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    faces = boundary_faces(tets)
    x = nodes[faces][:, :, 0]
    facets = {"electrode_1": faces[np.all(x < 1e-9, axis=1)],
              "electrode_2": faces[np.all(x > size_mm[0] - 1e-9, axis=1)]}
    weights = {} if weight is None else {k: np.full(len(f), weight) for k, f in facets.items()}
    return TetMesh(nodes, tets, np.full(len(tets), REGION_IDS["hydrogel"]), facets, weights)


TWO = Protocol.from_matrices([[1.0, -1.0]], [[1.0, -1.0]], [0])


@pytest.mark.parametrize("weight", [None, 0.5])
def test_bar_resistance(weight):
    L, W, H = 20.0, 4.0, 3.0
    sigma, zc, current = 2.0, 1e-3, 1e-3
    model = ForwardModel(box_mesh((L, W, H), weight=weight), sigma, zc, TWO, current)
    A = W * H * 1e-6
    # Coverage w spreads the contact over the whole face with conductance w / z_c per area.
    z_eff = zc / (1.0 if weight is None else weight)
    R = L * 1e-3 / (sigma * A) + 2 * z_eff / A
    rel = abs(model.voltages[0] / current - R) / R
    print(f"bar resistance: model {model.voltages[0] / current:.6f} ohm, analytic {R:.6f} ohm, rel {rel:.1e}")
    assert rel < 5e-3
    assert model.pair_resistances == pytest.approx([model.voltages[0] / current], rel=1e-12)
    # Without a design the electrode width is the square root of the (covered) patch area.
    covered = W * H * (1.0 if weight is None else weight)
    assert model.contact_number == pytest.approx(zc * sigma / (np.sqrt(covered) * 1e-3))


@pytest.fixture(scope="module")
def lattice_mesh():
    return mesh_design(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=5), cache_dir=False)


@pytest.fixture(scope="module")
def perturbed_model(lattice_mesh):
    """Random conductivity and moved nodes, so no symmetry helps."""
    rng = np.random.default_rng(1)
    model = ForwardModel(lattice_mesh)
    nodes = model.mesh.nodes_mm + rng.uniform(-0.2, 0.2, model.mesh.nodes_mm.shape)
    sigma = rng.uniform(0.5, 2.0, model.mesh.n_tets)
    return model.with_nodes(nodes, sigma)


def test_reciprocity(perturbed_model):
    p = perturbed_model.protocol
    assert np.sum(p.reciprocal >= 0) == 208
    err = perturbed_model.reciprocity_error()
    print(f"reciprocity error {err:.2e}")
    assert err < 1e-8


def _skfem_stiffness(model):
    m = MeshTet(model.mesh.nodes_mm.T * 1e-3, model.mesh.tets.T)
    basis = Basis(m, ElementTetP1())

    @BilinearForm
    def conduction(u, v, w):
        return w.sigma * dot(grad(u), grad(v))

    sigma = np.repeat(model.sigma[:, None], basis.X.shape[1], axis=1)
    return conduction.assemble(basis, sigma=sigma)


def test_current_conservation_with_independent_stiffness(perturbed_model):
    """K u from scikit-fem's assembly: zero at insulated nodes, the drive current through each electrode."""
    model = perturbed_model
    K = _skfem_stiffness(model)
    patches = [np.unique(t) for t in model.mesh.electrode_facets()]
    on_patch = np.zeros(model.mesh.n_nodes, bool)
    on_patch[np.concatenate(patches)] = True
    for d in (0, 5):
        r = K @ model.node_potentials[d]  # current leaving each node into the gel (A)
        I = model.current_A * model.protocol.drive_currents[d]
        assert np.max(np.abs(r[~on_patch])) < 1e-9 * model.current_A
        through = np.array([r[p].sum() for p in patches])
        np.testing.assert_allclose(through, I, atol=1e-9 * model.current_A)
        assert abs(through.sum()) < 1e-12


def test_pair_resistances_are_direct_two_terminal_solves(perturbed_model):
    """R_ij from the transfer matrix equals the voltage of a solve injecting +1 A at i and -1 A at j, for
    neighbours and across the sensor, and the adjacent pairs' equal the drive voltages per ampere."""
    model = perturbed_model
    R = model.pair_resistances
    n_e = model.n_electrodes
    i, j = np.triu_indices(n_e, 1)
    assert R.shape == (n_e * (n_e - 1) // 2,) and np.all(R > 0)
    dofs = model._topology.electrode_dofs
    for a, b in ((0, 1), (0, 8), (3, 12), (14, 15)):
        rhs = np.zeros(model.n_dof)
        rhs[dofs[a]], rhs[dofs[b]] = 1.0, -1.0
        phi = model.solve(rhs)
        assert R[np.flatnonzero((i == a) & (j == b))[0]] == pytest.approx(phi[dofs[a]] - phi[dofs[b]], rel=1e-9)
    for d, (src, snk) in enumerate(model.protocol.drive_pairs):
        U = model.electrode_potentials[d] / model.current_A
        k = np.flatnonzero((i == min(src, snk)) & (j == max(src, snk)))[0]
        assert R[k] == pytest.approx(abs(U[src] - U[snk]), rel=1e-9)


def test_transfer_sensitivities_of_a_pair_resistance_match_differences(perturbed_model):
    from latticeopt.electrics.sensitivity import transfer_sensitivities

    model = perturbed_model
    W = np.zeros((model.n_electrodes, model.n_electrodes))
    W[0, 0] = W[8, 8] = 1.0
    W[0, 8] = W[8, 0] = -1.0  # (e_1 - e_9)(e_1 - e_9)^T: the resistance between electrodes 1 and 9
    k = 7  # electrodes 1 and 9 are pair 7 in triu order
    d_sigma, _ = transfer_sensitivities(model, W)
    direction = np.random.default_rng(3).normal(size=model.mesh.n_tets)
    # h = 1e-6 sits at the round-off floor of a 3.7 kOhm resistance (the difference moved by 2.5e-6 of itself
    # when the tet gradients changed in their last bits); at 1e-4 the O(h^2) error is below 1e-9
    h = 1e-4
    plus, minus = (model.with_conductivity(model.sigma * (1 + s * h * direction)).pair_resistances[k] for s in (1, -1))
    assert np.sum(d_sigma * model.sigma * direction) == pytest.approx((plus - minus) / (2 * h), rel=1e-6)
    assert np.all(d_sigma <= 0)  # more conductivity anywhere never raises a two-terminal resistance


def test_drive_voltage_sign_and_energy(perturbed_model):
    """I (U_src - U_snk) equals the power dissipated in the gel plus in the contacts (Tellegen)."""
    model = perturbed_model
    K = _skfem_stiffness(model)
    nodes_m = model.mesh.nodes_mm * 1e-3
    for d in (0, 7):
        src, snk = model.protocol.drive_pairs[d]
        u, U = model.node_potentials[d], model.electrode_potentials[d]
        bulk = u @ K @ u
        contact = 0.0
        for e, tri in enumerate(model.mesh.electrode_facets()):
            p = nodes_m[tri]
            area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
            # (U - u)^2 is quadratic on a triangle: the edge-midpoint rule integrates it exactly.
            mids = [(u[tri[:, i]] + u[tri[:, j]]) / 2 for i, j in ((0, 1), (1, 2), (2, 0))]
            contact += sum(area / 3 * (U[e] - mu) ** 2 for mu in mids).sum() / model.contact_impedance_ohm_m2[e]
        power = model.current_A * (U[src] - U[snk])
        assert U[src] > U[snk]
        assert power == pytest.approx(bulk + contact, rel=1e-9)


def test_uniform_square_measurements_positive():
    """Std order reads U[m+1] - U[m]: along the rim from the sink to the source the potential rises."""
    mesh = mesh_design(LatticeDesign(width_mm=0, thickness_mm=3), MeshSettings(size_mm=5), cache_dir=False)
    V = ForwardModel(mesh).voltages
    assert np.all(V > 0)


def test_mirror_symmetry(lattice_mesh):
    """The grid mesh is symmetric under x <-> y, which maps electrode e to 15 - e."""
    model = ForwardModel(lattice_mesh)
    index, sign = model.protocol.row_map(15 - np.arange(16))
    V = model.voltages
    np.testing.assert_allclose(sign * V[index], V, rtol=1e-10, atol=1e-12 * np.abs(V).max())


def test_ground_and_rescaling(lattice_mesh):
    model = ForwardModel(lattice_mesh)
    np.testing.assert_allclose(model.electrode_potentials.sum(axis=1), 0, atol=1e-12)
    # Lengths x s and z_c x s keep z_c sigma / w: every voltage scales by exactly 1 / s.
    s = 1.7
    scaled = ForwardModel(lattice_mesh.with_nodes(lattice_mesh.nodes_mm * s),
                          contact_impedance_ohm_m2=model.contact_impedance_ohm_m2 * s)
    np.testing.assert_allclose(scaled.voltages * s, model.voltages, rtol=1e-9)


def test_reuse_equals_fresh(lattice_mesh):
    rng = np.random.default_rng(2)
    base = ForwardModel(lattice_mesh)
    sigma = rng.uniform(0.5, 2.0, base.mesh.n_tets)
    fresh = ForwardModel(lattice_mesh, sigma)
    reused = base.with_conductivity(sigma)
    assert reused._shared is base._shared  # one factorization object, symbolic analysis reused
    np.testing.assert_allclose(reused.voltages, fresh.voltages, rtol=1e-10)
    nodes = lattice_mesh.nodes_mm.copy()
    nodes[:, 2] *= 1.05
    moved = base.with_nodes(nodes)  # full-mesh node array
    np.testing.assert_allclose(moved.voltages, ForwardModel(lattice_mesh.with_nodes(nodes)).voltages, rtol=1e-10)
    # The original model's results survive its siblings' refactorizations; solve() refactors as needed.
    np.testing.assert_allclose(base.voltages, ForwardModel(lattice_mesh).voltages, rtol=1e-10)
    rhs = np.zeros(base.n_dof)
    rhs[base._topology.electrode_dofs[:2]] = [1.0, -1.0]
    x = base.solve(rhs)
    current = np.zeros(16)
    current[:2] = [1.0, -1.0]
    np.testing.assert_allclose(x[base._topology.electrode_dofs], base.transfer_matrix @ current, rtol=1e-8)


def test_bad_input(lattice_mesh):
    with pytest.raises(ParameterError, match="sigma_S_per_m"):
        ForwardModel(lattice_mesh, sigma_S_per_m=np.ones(3))
    with pytest.raises(ParameterError, match="contact_impedance_ohm_m2"):
        ForwardModel(lattice_mesh, contact_impedance_ohm_m2=0.0)
    with pytest.raises(ParameterError, match="electrode_mode"):
        ForwardModel(lattice_mesh, electrode_mode="shunt")
    with pytest.raises(ParameterError, match="protocol"):
        ForwardModel(lattice_mesh, protocol=Protocol.adjacent(8))
    model = ForwardModel(lattice_mesh)
    nodes = model.mesh.nodes_mm.copy()
    nodes[:, 2] *= -1  # mirror: every tet inverted
    with pytest.raises(MeshError, match="inverted"):
        model.with_nodes(nodes)


def test_floating_piece_is_an_error():
    bar = box_mesh()
    far = bar.nodes_mm + [100.0, 0, 0]  # a second bar with no electrodes
    nodes = np.vstack([bar.nodes_mm, far])
    tets = np.vstack([bar.tets, bar.tets + bar.n_nodes])
    mesh = TetMesh(nodes, tets, np.full(len(tets), REGION_IDS["hydrogel"]), bar.facets)
    with pytest.raises(MeshError, match="touch no electrode"):
        ForwardModel(mesh, protocol=TWO)


def test_rotated_phantom_matches_row_map(lattice_mesh):
    """Rotating a conductive blob by 90 degrees CCW (electrode e -> e + 4) permutes the rows as row_map says.

    The grid mesh is only approximately rotation-symmetric (its Kuhn split is not), so agreement is to the
    discretization level; the inverse permutation is off by O(1).
    """
    model = ForwardModel(lattice_mesh)
    c = model.mesh.nodes_mm[model.mesh.tets].mean(axis=1)

    def blob(x, y):
        return np.where(np.hypot(c[:, 0] - x, c[:, 1] - y) < 15, 3.0, 1.0)

    V = model.with_conductivity(blob(30, 20)).voltages
    Vt = model.with_conductivity(blob(100 - 20, 30)).voltages  # (x, y) -> (L - y, x)
    scale = np.abs(Vt).max()
    index, sign = model.protocol.row_map((np.arange(16) + 4) % 16)
    assert np.abs(Vt - sign * V[index]).max() < 0.01 * scale
    index, sign = model.protocol.row_map((np.arange(16) - 4) % 16)
    assert np.abs(Vt - sign * V[index]).max() > 0.1 * scale
