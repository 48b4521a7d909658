"""EIDORS and pyEIT exports: every field read back, the EIDORS file solved by a complete-electrode solver that
sees only the file's fields (and by EIDORS itself where Octave and EIDORS are installed), the pyEIT export
solved by pyEIT."""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.io import loadmat

from latticeopt.cli import main
from latticeopt.design import LatticeDesign
from latticeopt.electrics import ForwardModel
from latticeopt.errors import ParameterError
from latticeopt.interop import eidors_model, to_pyeit, write_eidors_mat, write_pyeit_npz
from latticeopt.mesh import MeshSettings
from latticeopt.mesh.tetmesh import electrode_name
from latticeopt.sensor_model import build_sensor_model, save_sensor_model


@pytest.fixture(scope="module")
def model():
    return build_sensor_model(LatticeDesign(width_mm=4.0, thickness_mm=3.0), MeshSettings(size_mm=5.0),
                              n_pixels=8, cache_dir=False)


@pytest.fixture(scope="module")
def mat(model, tmp_path_factory):
    path = write_eidors_mat(model, tmp_path_factory.mktemp("eidors") / "sensor.mat")
    return path, loadmat(path, squeeze_me=False, struct_as_record=True)


def _field(struct, name):
    return struct[name][0, 0]


def _cem_voltages_from_file(f) -> np.ndarray:
    """The complete electrode model assembled from the .mat fields alone (P1 tets, electrodes as the boundary
    triangles whose nodes are all electrode nodes, as EIDORS finds them), one solve per stimulation."""
    fm = f["fwd_model"]
    nodes, elems = _field(fm, "nodes"), _field(fm, "elems").astype(int) - 1
    sigma = f["sigma_S_per_m"].ravel()
    n = len(nodes)
    d = nodes[elems[:, 1:]] - nodes[elems[:, :1]]  # (E, 3, 3) edge vectors
    vol = np.abs(np.linalg.det(d)) / 6
    g = np.linalg.inv(d)  # gradients of barycentric coordinates 1..3 are the columns
    grads = np.concatenate([-g.sum(axis=2, keepdims=True), g], axis=2).transpose(0, 2, 1)  # (E, 4, 3)
    ke = sigma[:, None, None] * vol[:, None, None] * grads @ grads.transpose(0, 2, 1)
    rows = np.repeat(elems, 4, axis=1).ravel()
    K = sp.coo_matrix((ke.ravel(), (rows, np.tile(elems, 4).ravel())), shape=(n, n)).tolil()
    bnd = _field(fm, "boundary").astype(int) - 1
    electrodes = _field(fm, "electrode")[0]
    n_e = len(electrodes)
    A = sp.lil_matrix((n + n_e, n + n_e))
    A[:n, :n] = K
    for k, el in enumerate(electrodes):
        enodes = el["nodes"].ravel().astype(int) - 1
        zc = float(el["z_contact"].ravel()[0])
        tris = bnd[np.all(np.isin(bnd, enodes), axis=1)]
        p = nodes[tris]
        area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1) / 2
        for t, a in zip(tris, area, strict=True):
            m = a / 12 * (np.ones((3, 3)) + np.eye(3)) / zc  # P1 boundary mass / z_c
            for i in range(3):
                A[t[i], n + k] -= a / 3 / zc
                A[n + k, t[i]] -= a / 3 / zc
                for j in range(3):
                    A[t[i], t[j]] += m[i, j]
        A[n + k, n + k] += area.sum() / zc
    gnd = int(_field(fm, "gnd_node").ravel()[0]) - 1
    keep = np.setdiff1d(np.arange(n + n_e), [gnd])
    lu = spla.splu(A.tocsc()[keep][:, keep])
    out = []
    for st in _field(fm, "stimulation")[0]:
        rhs = np.zeros(n + n_e)
        rhs[n:] = st["stim_pattern"].ravel()
        u = np.zeros(n + n_e)
        u[keep] = lu.solve(rhs[keep])
        out.append(sp.csr_matrix(st["meas_pattern"]) @ u[n:])
    return np.concatenate(out)


def test_eidors_fields_read_back(model, mat):
    _, f = mat
    fm = f["fwd_model"]
    mesh = model.mesh
    assert str(_field(fm, "type")[0]) == "fwd_model"
    np.testing.assert_array_equal(_field(fm, "nodes"), mesh.nodes_mm * 1e-3)
    np.testing.assert_array_equal(_field(fm, "elems"), mesh.tets + 1)
    # the boundary is every face of exactly one tet, once
    bnd = np.sort(_field(fm, "boundary").astype(int) - 1, axis=1)
    faces = np.sort(mesh.tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    np.testing.assert_array_equal(np.unique(bnd, axis=0), uniq[count == 1])
    assert len(np.unique(bnd, axis=0)) == len(bnd)
    electrodes = _field(fm, "electrode")[0]
    assert len(electrodes) == mesh.n_electrodes == 16
    for k, el in enumerate(electrodes):
        facets = np.sort(mesh.facets[electrode_name(k + 1)], axis=1)
        enodes = el["nodes"].ravel().astype(int) - 1
        np.testing.assert_array_equal(np.sort(enodes), np.unique(facets))
        # EIDORS' rule (boundary triangles with every node on the electrode) finds exactly our electrode
        found = bnd[np.all(np.isin(bnd, enodes), axis=1)]
        np.testing.assert_array_equal(np.unique(found, axis=0), np.unique(facets, axis=0))
        assert float(el["z_contact"].ravel()[0]) == pytest.approx(model.contact_impedance_ohm_m2[k], rel=1e-15)
    stims = _field(fm, "stimulation")[0]
    assert len(stims) == 16
    meas = np.vstack([sp.csr_matrix(s["meas_pattern"]).toarray() for s in stims])
    np.testing.assert_array_equal(meas, model.protocol.measure)
    for d, s in enumerate(stims):
        assert str(s["stimulation"][0]) == "Amp"
        np.testing.assert_allclose(s["stim_pattern"].ravel(), model.protocol.drive_currents[d] * model.current_A)
    gnd = int(_field(fm, "gnd_node").ravel()[0]) - 1
    assert not any(gnd in mesh.facets[electrode_name(k + 1)] for k in range(16))
    np.testing.assert_array_equal(f["v_ref"].ravel(), model.v_ref)
    np.testing.assert_array_equal(f["sigma_S_per_m"].ravel(), model.sigma_S_per_m)
    np.testing.assert_array_equal(f["jacobian"], model.jacobian)
    np.testing.assert_allclose(f["pixel_extent_m"].ravel(), np.array(model.extent_mm) * 1e-3)
    assert str(_field(f["units"], "lengths")[0]) == "m"


def test_eidors_file_alone_reproduces_the_voltages(model, mat):
    _, f = mat
    v = _cem_voltages_from_file(f)
    rel = np.max(np.abs(v - model.v_ref)) / np.max(np.abs(model.v_ref))
    print(f"independent CEM solve of the .mat vs latticeopt: {rel:.1e}")
    assert rel < 1e-9


def test_partly_covered_electrodes_are_refused():
    m = build_sensor_model(LatticeDesign(width_mm=9.0, thickness_mm=3.0),
                           MeshSettings(size_mm=5.0, electrode_edges=False), n_pixels=4, cache_dir=False)
    with pytest.raises(ParameterError, match="electrode_edges"):
        eidors_model(m)


@pytest.mark.skipif(not (os.environ.get("LATTICEOPT_EIDORS") and shutil.which("octave-cli")),
                    reason="needs octave-cli and LATTICEOPT_EIDORS (the EIDORS folder holding startup.m)")
def test_eidors_fwd_solve_reproduces_the_voltages(model, mat, tmp_path):
    path, _ = mat
    startup = os.path.join(os.environ["LATTICEOPT_EIDORS"], "startup.m")
    out = tmp_path / "v.txt"
    script = (f"run('{startup}'); load('{path}'); d = fwd_solve(mk_image(fwd_model, sigma_S_per_m)); "
              f"v = d.meas; save('-ascii', '-double', '{out}', 'v');")
    subprocess.run(["octave-cli", "--no-gui", "-q", "--eval", script], check=True, capture_output=True,
                   timeout=600)
    v = np.loadtxt(out)
    rel = np.max(np.abs(v - model.v_ref)) / np.max(np.abs(model.v_ref))
    print(f"EIDORS fwd_solve vs latticeopt: {rel:.1e}")
    assert rel < 1e-9


def test_pyeit_forward_on_the_export_equals_point_electrodes(model, tmp_path):
    from pyeit.eit import protocol as pyeit_protocol
    from pyeit.eit.fem import EITForward

    mesh, protocol = to_pyeit(model)
    ref = pyeit_protocol.create(16, 1, 1, "std")  # pyEIT's own adjacent protocol: the same rows
    np.testing.assert_array_equal(protocol.ex_mat, ref.ex_mat)
    np.testing.assert_array_equal(protocol.meas_mat, ref.meas_mat)
    np.testing.assert_array_equal(protocol.keep_ba, ref.keep_ba)
    v = EITForward(mesh, protocol).solve_eit(perm=mesh.perm)
    ours = ForwardModel(model.mesh, sigma_S_per_m=model.sigma_S_per_m, electrode_mode="point", current_A=1.0)
    rel = np.max(np.abs(ours.voltages - v)) / np.max(np.abs(v))
    print(f"pyEIT on the export vs point electrodes: {rel:.1e}")
    assert rel < 1e-6
    fields = np.load(write_pyeit_npz(model, tmp_path / "p.npz"))
    np.testing.assert_array_equal(fields["v_point"], ours.voltages)
    np.testing.assert_allclose(fields["v_cem"], model.v_ref / model.current_A, rtol=1e-15)
    np.testing.assert_array_equal(fields["el_pos"], ours.point_nodes)
    # a saved sensor-model file gives the same objects
    path = save_sensor_model(model, tmp_path / "s.npz")
    mesh2, _ = to_pyeit(path)
    np.testing.assert_array_equal(mesh2.node, mesh.node)


def test_export_cli_formats(tmp_path, capsys):
    argv = ["export", "--size", "6", "--pixels", "4", "--no-cache"]
    assert main([*argv, "--format", "eidors", "-o", str(tmp_path / "s.mat"), "--json"]) == 0
    assert "fwd_model" in loadmat(tmp_path / "s.mat")
    assert main([*argv, "--format", "pyeit", "-o", str(tmp_path / "p.npz")]) == 0
    assert set(np.load(tmp_path / "p.npz").files) == {"node", "element", "perm", "el_pos", "ref_node", "ex_mat",
                                                      "meas_mat", "keep_ba", "v_point", "v_cem"}
    capsys.readouterr()
    assert main([*argv, "--format", "vtk", "-o", str(tmp_path / "x.npz")]) == 2
    assert "--format" in capsys.readouterr().err
    assert main([*argv, "--format", "eidors", "-o", str(tmp_path / "x.npz")]) == 2



@pytest.mark.parametrize("name", ["npz", "eidors", "pyeit"])
def test_export_cli_takes_each_format_suffix_from_the_table(name, tmp_path, capsys):
    from latticeopt.interop import FORMATS

    suffix = FORMATS[name].suffix
    other = ".mat" if suffix != ".mat" else ".npz"
    assert main(["export", "--format", name, "-o", str(tmp_path / f"x{other}")]) == 2  # before any meshing
    assert f"ending in {suffix}" in capsys.readouterr().err
    assert not (tmp_path / f"x{other}").exists()


def test_export_cli_npz_writes_the_sensor_model(tmp_path):
    from latticeopt.sensor_model import load_sensor_model

    out = tmp_path / "s.npz"
    assert main(["export", "--size", "6", "--pixels", "4", "--no-cache", "--format", "npz", "-o", str(out)]) == 0
    assert load_sensor_model(out).n_pixels == 4
