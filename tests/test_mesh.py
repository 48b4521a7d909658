"""Structured grid mesher, facet sets, TetMesh operations, the on-disk cache and VTU output."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from latticeopt.design import REGION_IDS, LatticeDesign
from latticeopt.errors import ParameterError
from latticeopt.layout import electrode_contact_mm
from latticeopt.mesh import MeshSettings, TetMesh, electrode_name, mesh_design, mesh_key
from latticeopt.mesh import grid as grid_module
from latticeopt.mesh.facets import boundary_faces, tag_facets
from latticeopt.mesh.grid import grid_coordinates, grid_mesh
from latticeopt.mesh.tetmesh import TET_FACES, face_keys, triangle_areas

DESIGNS = [
    LatticeDesign(),
    LatticeDesign(width_mm=0.0, thickness_mm=3.0),
    LatticeDesign(width_mm=2.0, thickness_mm=1.0, pitch_mm=10.0),
    LatticeDesign(width_mm=6.0, thickness_mm=7.0),  # no substrate
    LatticeDesign(width_mm=5.0, thickness_mm=2.5, pitch_mm=30.0, electrode_width_mm=6.0),
]


def _contact_mm(d: LatticeDesign) -> np.ndarray:
    """Length of each electrode's side-wall segment that lies on hydrogel (mm), shape ``(16,)``: with
    ``rim = "none"`` a channel narrower than an electrode covers only part of it."""
    return electrode_contact_mm(d.footprint(), d.electrodes())


def _ids(d: LatticeDesign) -> str:
    return f"w{d.width_mm:g}-t{d.thickness_mm:g}-p{d.pitch_mm:g}"


@pytest.fixture(scope="module", params=DESIGNS, ids=_ids)
def design_mesh(request):
    return request.param, grid_mesh(request.param, size_mm=4.0)


def _normals(nodes, tri):
    a, b, c = (nodes[tri[:, i]] for i in range(3))
    n = np.cross(b - a, c - a)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _closed_and_oriented(tri: np.ndarray) -> bool:
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    _, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    return bool(np.all(counts == 2) and len(np.unique(directed, axis=0)) == len(directed))


def _enclosed_volume(nodes, tri) -> float:
    a, b, c = (nodes[tri[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


# -- the grid mesher -------------------------------------------------------------------------------------------

def test_region_volumes_are_exact(design_mesh):
    d, mesh = design_mesh
    vols = mesh.region_volumes_mm3()
    for name, expected in d.region_volumes_mm3().items():
        assert vols[name] == pytest.approx(expected, rel=1e-12, abs=1e-9), name
    assert sum(vols.values()) == pytest.approx(100 * 100 * 9, rel=1e-12)


def test_tets_positive_and_labels_match_centroids(design_mesh):
    d, mesh = design_mesh
    assert mesh.tet_volumes_mm3().min() > 0
    assert mesh.quality().min() > 0.05  # graded cells are stretched (4 mm x 0.5 mm at thin layers)
    assert np.array_equal(mesh.region, d.region_at(mesh.nodes_mm[mesh.tets].mean(axis=1)))


def test_electrode_areas_are_contact_length_times_thickness(design_mesh):
    d, mesh = design_mesh
    assert mesh.n_electrodes == d.n_electrodes
    assert mesh.electrode_areas_mm2() == pytest.approx(_contact_mm(d) * d.thickness_mm, rel=1e-12)
    assert not mesh.facet_weights  # conforming mesh: every electrode triangle fully covered


def test_top_and_bottom_facets(design_mesh):
    d, mesh = design_mesh
    for name, z, nz in (("top", d.total_thickness_mm, 1.0), ("bottom", 0.0, -1.0)):
        tri = mesh.facets[name]
        assert mesh.facet_area_mm2(name) == pytest.approx(100 * 100, rel=1e-12)
        assert np.allclose(mesh.nodes_mm[tri][:, :, 2], z)
        assert np.allclose(_normals(mesh.nodes_mm, tri)[:, 2], nz)  # oriented outward


def test_electrode_patches_sit_on_their_wall_in_numbering_order(design_mesh):
    d, mesh = design_mesh
    z0, z1 = d.layer_z_mm
    gel_nodes = np.unique(mesh.tets[mesh.region == REGION_IDS["hydrogel"]])
    for k, (cx, cy, _cz, nx, ny, axis, width, _h) in enumerate(d.electrodes()):
        tri = mesh.facets[electrode_name(k + 1)]
        p = mesh.nodes_mm[tri]
        normal_axis = 0 if nx else 1
        assert np.allclose(p[:, :, normal_axis], cx if nx else cy)  # on the wall
        assert np.allclose(_normals(mesh.nodes_mm, tri)[:, :2], [nx, ny])  # facing out
        t = p[:, :, int(axis)]
        assert t.min() >= (cx if axis == 0 else cy) - width / 2 - 1e-9
        assert t.max() <= (cx if axis == 0 else cy) + width / 2 + 1e-9
        assert p[:, :, 2].min() == pytest.approx(z0) and p[:, :, 2].max() == pytest.approx(z1)
        assert np.all(np.isin(tri, gel_nodes))  # on the hydrogel
    # Patch centroids (area-weighted) are the electrode centres (where the gel covers the whole electrode,
    # else the contact's centre), counter-clockwise from y = 0, smallest x.
    cent = np.array([triangle_areas(mesh.nodes_mm, tri) @ mesh.nodes_mm[tri].mean(axis=1)
                     / triangle_areas(mesh.nodes_mm, tri).sum() for tri in mesh.electrode_facets()])
    full = np.isclose(_contact_mm(d), d.electrode_width_mm)
    assert cent[full] == pytest.approx(d.electrodes()[full, :3])
    angle = np.unwrap(np.arctan2(cent[:, 1] - 50, cent[:, 0] - 50))
    assert np.all(np.diff(angle) > 0) and angle[-1] - angle[0] < 2 * np.pi


def test_hydrogel_boundary_is_closed_and_encloses_the_hydrogel(design_mesh):
    d, mesh = design_mesh
    tri = mesh.facets["hydrogel_boundary"]
    assert _closed_and_oriented(tri)
    assert _enclosed_volume(mesh.nodes_mm, tri) == pytest.approx(d.region_volumes_mm3()["hydrogel"], rel=1e-12)


def test_grid_lines_hit_every_feature_and_respect_the_size():
    d = LatticeDesign()
    x, y, z = grid_coordinates(d, 3.0, channel_cells=2, layer_cells=3)
    features = np.r_[d.channel_intervals_mm().ravel(), d.electrodes()[:4, 0] - 2, d.electrodes()[:4, 0] + 2]
    assert np.all(np.min(np.abs(x[:, None] - features[None, :]), axis=0) < 1e-9)
    assert np.array_equal(x, y)
    assert np.all(np.diff(x) <= 3.0 + 1e-9) and np.all(np.diff(z) <= 3.0 + 1e-9)
    for a, b in d.channel_intervals_mm():  # at least two cells across every channel
        assert np.count_nonzero((x > a + 1e-9) & (x < b - 1e-9)) >= 1
    assert np.count_nonzero((z > 4 - 1e-9) & (z < 7 + 1e-9)) >= 4  # >= 3 cells through the layer
    assert {0.0, 4.0, 7.0, 9.0} <= set(np.round(z, 9))


@pytest.mark.parametrize("width_mm", [2.0, 3.0, 4.0, 5.0, 6.0])
def test_grid_channels_get_channel_cells_as_a_whole_not_per_piece(width_mm):
    # electrode edges cut channels wider than an electrode into pieces; splitting every piece into
    # channel_cells made 0.25 mm slivers at w = 5 whose grid lines crossed the whole sensor
    d = LatticeDesign(width_mm=width_mm)
    size, cells, centre = 2.0, 2, d.size_mm / 2
    x, _, _ = grid_coordinates(d, size, channel_cells=cells, layer_cells=2)
    edges = np.r_[d.electrodes()[:4, 0] - d.electrode_width_mm / 2, d.electrodes()[:4, 0] + d.electrode_width_mm / 2]
    for a0, b0 in d.channel_intervals_mm():
        for a, b in ((a0, min(b0, centre)), (max(a0, centre), b0)):  # each side of the centre line
            if b <= a:
                continue
            inside = x[(x > a - 1e-9) & (x < b + 1e-9)]
            assert len(inside) - 1 >= cells
            ends = np.r_[a, np.sort(edges[(edges > a + 1e-9) & (edges < b - 1e-9)]), b]
            for p, q in zip(ends[:-1], ends[1:]):  # a piece below both the size and its share is one cell
                if q - p < min(size, (b - a) / cells) - 1e-9:
                    assert np.count_nonzero((x > p + 1e-9) & (x < q - 1e-9)) == 0, (p, q, inside)


def test_grid_mesh_is_deterministic():
    d = LatticeDesign(width_mm=3.0)
    a, b = grid_mesh(d, 4.0), grid_mesh(d, 4.0)
    assert np.array_equal(a.nodes_mm, b.nodes_mm) and np.array_equal(a.tets, b.tets)
    assert np.array_equal(a.region, b.region)
    assert all(np.array_equal(a.facets[k], b.facets[k]) for k in a.facets)


def test_refinement_increases_resolution_but_not_the_volumes():
    d = LatticeDesign()
    coarse, fine = grid_mesh(d, 4.0), grid_mesh(d, 2.0, channel_cells=3)
    assert fine.n_tets > coarse.n_tets
    assert fine.region_volumes_mm3()["hydrogel"] == pytest.approx(coarse.region_volumes_mm3()["hydrogel"])


# -- facets with tolerance and fractional coverage -------------------------------------------------------------

def test_boundary_faces_of_one_tet_point_outward():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    faces = boundary_faces(np.array([[0, 1, 2, 3]]))
    assert len(faces) == 4
    out = nodes[faces].mean(axis=1) - nodes.mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", _normals(nodes, faces), out) > 0)


def test_face_keys_are_orientation_free_and_the_wide_fallback_agrees():
    f = np.array([[3, 1, 2], [2, 3, 1], [1, 2, 4]])
    k = face_keys(f, 10)
    assert k[0] == k[1] != k[2]
    wide = face_keys(f, 2 ** 22)
    assert wide.shape == (3, 3) and np.array_equal(wide[0], wide[1]) and not np.array_equal(wide[0], wide[2])


def test_facets_found_with_tolerance_on_a_perturbed_mesh():
    """Surfaces off their plane by less than ``tol_mm`` (as tetwild's) are still found, with the same areas."""
    d = LatticeDesign()
    mesh = grid_mesh(d, 4.0)
    rng = np.random.default_rng(0)
    shaken = mesh.nodes_mm + rng.uniform(-0.01, 0.01, mesh.nodes_mm.shape)
    facets, weights = tag_facets(shaken, mesh.tets, mesh.region, d, tol_mm=0.05)
    for name in ("top", "bottom", "hydrogel_boundary"):
        assert np.array_equal(facets[name], mesh.facets[name]), name
    shaken_mesh = TetMesh(shaken, mesh.tets, mesh.region, facets, weights)
    for k in range(16):
        name = electrode_name(k + 1)
        # Neighbours now poke into the rectangle by up to 0.01 mm and join with tiny weights.
        main = facets[name][shaken_mesh.weights(name) > 0.5]
        assert np.array_equal(np.sort(face_keys(main, mesh.n_nodes)),
                              np.sort(face_keys(mesh.facets[name], mesh.n_nodes)))
    # The shaken gel wall really is off by up to 0.01 mm at z0 and z1: 2 x 0.01 / 3 = 0.7 % at most.
    assert shaken_mesh.electrode_areas_mm2() == pytest.approx(np.full(16, 12.0), rel=7e-3)
    with_eq, _ = tag_facets(shaken, mesh.tets, mesh.region, d, tol_mm=1e-9)
    assert len(with_eq["top"]) < len(mesh.facets["top"])  # equality would lose them


@pytest.mark.parametrize("width", [3.3, 2.0, 5.7])
def test_fractional_coverage_gives_exact_areas_on_non_conforming_triangles(width):
    """A mesh whose triangles do not follow the electrode outline still reports width x t exactly."""
    d = LatticeDesign(rim="channel")  # the rim channel covers every electrode, whatever its width
    mesh = grid_mesh(d, 4.0)  # grid lines at the 4 mm electrode edges, not at the new ones
    other = d.replace(electrode_width_mm=width)
    facets, weights = tag_facets(mesh.nodes_mm, mesh.tets, mesh.region, other, tol_mm=1e-6)
    assert weights  # some triangles are cut by the electrode edges
    test_mesh = TetMesh(mesh.nodes_mm, mesh.tets, mesh.region, facets, weights)
    assert test_mesh.electrode_areas_mm2() == pytest.approx(np.full(16, width * 3.0), rel=1e-12)
    for name, w in weights.items():
        assert np.all((w > 0) & (w <= 1)), name


# -- TetMesh operations ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def mesh4():
    # rim channel: gel volume t L^2 (1 - (1 - w/p)^2) = 16128 mm^3, every electrode wholly on gel
    return grid_mesh(LatticeDesign(rim="channel"), 4.0)


def test_arrays_are_read_only(mesh4):
    with pytest.raises(ValueError):
        mesh4.nodes_mm[0, 0] = 1.0
    with pytest.raises(ValueError):
        mesh4.facets["top"][0, 0] = 1


def test_restrict_to_hydrogel(mesh4):
    sub, node_ids = mesh4.restrict(("hydrogel",))
    assert np.all(sub.region == REGION_IDS["hydrogel"])
    assert sub.n_tets == np.count_nonzero(mesh4.region == REGION_IDS["hydrogel"])
    assert np.array_equal(sub.nodes_mm, mesh4.nodes_mm[node_ids])
    assert sub.region_volumes_mm3()["hydrogel"] == pytest.approx(16128.0, rel=1e-12)
    assert sub.electrode_areas_mm2() == pytest.approx(np.full(16, 12.0))
    # The electrode triangles are the same triangles, renumbered.
    for k in range(16):
        name = electrode_name(k + 1)
        assert np.array_equal(node_ids[sub.facets[name]], mesh4.facets[name])
    # The hydrogel boundary is the boundary of the sub-mesh; top and bottom are not on the hydrogel.
    assert np.array_equal(np.sort(face_keys(sub.facets["hydrogel_boundary"], sub.n_nodes)),
                          np.sort(face_keys(boundary_faces(sub.tets), sub.n_nodes)))
    assert len(sub.facets["top"]) == 0 and len(sub.facets["bottom"]) == 0
    with pytest.raises(ValueError, match="regions"):
        mesh4.restrict(("gel",))


def test_restrict_keeps_only_faces_of_kept_tets():
    # Without a sealing layer the top is half hydrogel, half islands; an island's corner triangles have
    # all three nodes on hydrogel, but they are not faces of the hydrogel sub-mesh.
    d = LatticeDesign(sealing_mm=0.0)
    sub, _ = grid_mesh(d, 4.0).restrict(("hydrogel",))
    assert sub.facet_area_mm2("top") == pytest.approx(d.hydrogel_area_fraction() * 100 * 100, rel=1e-12)
    kept = face_keys(sub.tets[:, TET_FACES].reshape(-1, 3), sub.n_nodes)
    for name, tri in sub.facets.items():
        assert np.all(np.isin(face_keys(tri, sub.n_nodes), kept)), name


def test_restrict_to_several_regions(mesh4):
    sub, _ = mesh4.restrict(("hydrogel", "islands"))
    assert sub.region_volumes_mm3()["islands"] == pytest.approx(13872.0)
    assert sub.region_volumes_mm3()["substrate"] == 0.0


def test_with_nodes_moves_nodes_and_keeps_labels(mesh4):
    moved = mesh4.nodes_mm * np.array([2.0, 1.0, 1.0])
    m2 = mesh4.with_nodes(moved)
    assert np.array_equal(m2.nodes_mm, moved) and m2.tets is mesh4.tets and m2.region is mesh4.region
    assert m2.region_volumes_mm3()["hydrogel"] == pytest.approx(2 * 16128.0)
    assert m2.electrode_areas_mm2()[:4] == pytest.approx(np.full(4, 24.0))  # y = 0 side stretched along x
    assert m2.electrode_areas_mm2()[4:8] == pytest.approx(np.full(4, 12.0))
    assert mesh4.region_volumes_mm3()["hydrogel"] == pytest.approx(16128.0)  # original untouched
    with pytest.raises(ValueError, match="shape"):
        mesh4.with_nodes(moved[:-1])


def test_to_skfem_keeps_nodes_and_subdomains(mesh4):
    m = mesh4.to_skfem()
    assert m.p.shape == (3, mesh4.n_nodes) and m.t.shape == (4, mesh4.n_tets)
    assert np.array_equal(m.subdomains["hydrogel"], np.nonzero(mesh4.region == 1)[0])


def test_save_load_round_trip(mesh4, tmp_path):
    path = tmp_path / "m.npz"
    mesh4.save(path)
    back = TetMesh.load(path)
    assert np.array_equal(back.nodes_mm, mesh4.nodes_mm) and np.array_equal(back.tets, mesh4.tets)
    assert back.facets.keys() == mesh4.facets.keys()
    assert not list(tmp_path.glob("*.part"))


def test_vtu_round_trip_keeps_regions_and_electrodes(mesh4, tmp_path):
    import meshio

    path = tmp_path / "sensor.vtu"
    mesh4.to_vtu(path, cell_data={"q": mesh4.quality()})
    m = meshio.read(path)
    blocks = {c.type: i for i, c in enumerate(m.cells)}
    tet_block, tri_block = blocks["tetra"], blocks["triangle"]
    assert np.allclose(m.points, mesh4.nodes_mm)
    assert np.array_equal(m.cells[tet_block].data, mesh4.tets)
    assert np.array_equal(m.cell_data["region"][tet_block], mesh4.region)
    elec = m.cell_data["electrode"][tri_block]
    tris = m.cells[tri_block].data
    for k in range(16):
        assert np.array_equal(np.sort(face_keys(tris[elec == k + 1], mesh4.n_nodes)),
                              np.sort(face_keys(mesh4.facets[electrode_name(k + 1)], mesh4.n_nodes)))
    surface = m.cell_data["surface"][tri_block]
    assert triangle_areas(m.points, tris[surface == 1]).sum() == pytest.approx(100 * 100)
    assert np.allclose(m.cell_data["q"][tet_block], mesh4.quality())


# -- settings and cache ----------------------------------------------------------------------------------------

def test_mesh_settings_validation():
    with pytest.raises(ParameterError,
                       match=r"mesher: expected one of 'auto', 'grid', 'extruded', 'tetwild', got 'gmsh'"):
        MeshSettings(mesher="gmsh")
    with pytest.raises(ParameterError, match="size_mm"):
        MeshSettings(size_mm=0.0)
    with pytest.raises(ParameterError, match="channel_cells"):
        MeshSettings(channel_cells=0)
    with pytest.raises(ParameterError, match="epsilon_rel"):
        MeshSettings(epsilon_rel=float("nan"))


def test_cache_key_follows_what_determines_the_mesh():
    d, s = LatticeDesign(), MeshSettings(size_mm=4.0)
    key = mesh_key(d, s)
    assert mesh_key(LatticeDesign(), MeshSettings(size_mm=4)) == key
    assert mesh_key(d.replace(width_mm=5.0), s) != key
    assert mesh_key(d.replace(electrode_width_mm=3.0), s) != key
    assert mesh_key(d, dataclasses.replace(s, size_mm=3.0)) != key
    assert mesh_key(d, dataclasses.replace(s, channel_cells=3)) != key
    assert mesh_key(d, dataclasses.replace(s, mesher="tetwild")) != key
    assert mesh_key(d, dataclasses.replace(s, mesher="extruded")) != key
    # Every field of the resolved settings counts, even one this mesher ignores (a changed default is then
    # never silently reused); "auto" keys as the mesher it picks.
    assert mesh_key(d, dataclasses.replace(s, epsilon_rel=1e-4)) != key
    assert mesh_key(d, dataclasses.replace(s, mesher="grid")) == key
    hexa = LatticeDesign(pattern="hexagonal", width_mm=3.0)
    assert mesh_key(hexa, s) == mesh_key(hexa, dataclasses.replace(s, mesher="extruded"))
    # the footprint itself: the same fields drawn differently (here: leads added by the layout code) rebuild
    import shapely

    real = LatticeDesign.footprint
    try:
        LatticeDesign.footprint = lambda self: shapely.box(0, 0, 1, 1).union(real(self))
        assert mesh_key(LatticeDesign(), s) != key
    finally:
        LatticeDesign.footprint = real
    # the package version: a new release rebuilds its meshes
    import latticeopt

    old = latticeopt.__version__
    try:
        latticeopt.__version__ = old + ".post1"
        assert mesh_key(d, s) != key
    finally:
        latticeopt.__version__ = old


def test_second_request_is_a_file_read(tmp_path, monkeypatch):
    d, s = LatticeDesign(width_mm=3.0), MeshSettings(size_mm=4.0)
    first = mesh_design(d, s, cache_dir=tmp_path)
    assert first.info["cached"] is False and first.info["key"] == mesh_key(d, s)
    files = list(tmp_path.glob("grid-*.npz"))
    assert len(files) == 1

    def no_rebuild(*args, **kwargs):
        raise AssertionError("the mesher ran although the mesh is cached")

    monkeypatch.setattr(grid_module, "grid_mesh", no_rebuild)
    second = mesh_design(d, s, cache_dir=tmp_path)
    assert second.info["cached"] is True
    for name in ("nodes_mm", "tets", "region"):
        assert np.array_equal(getattr(second, name), getattr(first, name)), name
    assert all(np.array_equal(second.facets[k], first.facets[k]) for k in first.facets)
    assert second.info["build_seconds"] == first.info["build_seconds"]
    # A different design is not served from that entry.
    with pytest.raises(AssertionError, match="cached"):
        mesh_design(d.replace(width_mm=2.0), s, cache_dir=tmp_path)


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty"])
def test_corrupt_cache_entry_is_rebuilt(tmp_path, damage):
    d, s = LatticeDesign(), MeshSettings(size_mm=4.0)
    good = mesh_design(d, s, cache_dir=tmp_path)
    path = next(tmp_path.glob("grid-*.npz"))
    data = path.read_bytes()
    path.write_bytes({"garbage": b"not a mesh", "truncated": data[: len(data) // 2], "empty": b""}[damage])
    again = mesh_design(d, s, cache_dir=tmp_path)
    assert again.info["cached"] is False
    assert np.array_equal(again.nodes_mm, good.nodes_mm) and np.array_equal(again.tets, good.tets)
    assert mesh_design(d, s, cache_dir=tmp_path).info["cached"] is True  # the entry was rewritten


def test_cache_location_and_disabling(tmp_path, monkeypatch):
    monkeypatch.setenv("LATTICEOPT_MESH_CACHE", str(tmp_path / "env-cache"))
    monkeypatch.chdir(tmp_path)
    d, s = LatticeDesign(), MeshSettings(size_mm=5.0)
    mesh_design(d, s)
    assert len(list((tmp_path / "env-cache").glob("*.npz"))) == 1
    m = mesh_design(d, s, cache_dir=False)
    assert m.info["cached"] is False
    assert len(list((tmp_path / "env-cache").glob("*.npz"))) == 1
    assert not (tmp_path / "meshes").exists()


def test_default_cache_folder_is_the_user_cache(monkeypatch):
    import platformdirs

    from latticeopt.mesh import default_cache_dir

    monkeypatch.delenv("LATTICEOPT_MESH_CACHE", raising=False)
    assert default_cache_dir() == Path(platformdirs.user_cache_dir("latticeopt")) / "meshes"
    monkeypatch.setenv("LATTICEOPT_MESH_CACHE", "/some/where")
    assert default_cache_dir() == Path("/some/where")


def test_concurrent_builders_of_one_mesh_do_not_collide(tmp_path):
    """Two processes meshing the same uncached design at once (sweep chunks) both succeed."""
    import subprocess
    import sys

    code = ("from latticeopt import LatticeDesign, MeshSettings, mesh_design;"
            f"mesh_design(LatticeDesign(), MeshSettings(size_mm=5.0), cache_dir={str(tmp_path)!r})")
    procs = [subprocess.Popen([sys.executable, "-c", code], stderr=subprocess.PIPE) for _ in range(3)]
    errors = [p.communicate()[1].decode() for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0], errors
    assert len(list(tmp_path.glob("*.npz"))) == 1 and not list(tmp_path.glob("*.part"))


# -- the grid without electrode-edge lines ----------------------------------------------------------------
@pytest.mark.parametrize("width_mm", [0.0, 2.0, 3.0, 4.0, 5.0, 6.0])
def test_grid_without_electrode_edges_keeps_every_material_interface(width_mm):
    d = LatticeDesign(width_mm=width_mm, thickness_mm=1.0)
    full = grid_coordinates(d, 2.0, 2, 2)
    part = grid_coordinates(d, 2.0, 2, 2, electrode_edges=False)
    features = np.r_[0.0, d.size_mm / 2, d.size_mm, d.channel_intervals_mm().ravel()]
    assert np.all(np.min(np.abs(part[0][:, None] - features[None, :]), axis=0) < 1e-9)
    assert np.array_equal(part[2], full[2]) and np.array_equal(part[0], part[1])
    assert len(part[0]) <= len(full[0]) and np.all(np.diff(part[0]) <= 2.0 + 1e-9)
    edges = np.r_[d.electrodes()[:4, 0] - d.electrode_width_mm / 2, d.electrodes()[:4, 0] + d.electrode_width_mm / 2]
    edges = edges[np.min(np.abs(edges[:, None] - features[None, :]), axis=1) > 1e-9]
    # electrode edges that are no material interface are no grid lines (electrode triangles get weights)
    assert width_mm == 4.0 or len(edges) == 8
    assert not np.any(np.min(np.abs(part[0][:, None] - edges[None, :]), axis=0) < 1e-9)


def test_electrode_edges_setting_is_validated_and_keyed():
    assert "electrode_edges" not in MeshSettings().as_dict()
    assert MeshSettings(electrode_edges=False).as_dict()["electrode_edges"] is False
    with pytest.raises(ParameterError, match="electrode_edges"):
        MeshSettings(cell_counts="fixed", electrode_edges=False)
    d = LatticeDesign()
    assert mesh_key(d, MeshSettings()) != mesh_key(d, MeshSettings(electrode_edges=False))


@pytest.mark.parametrize("width_mm", [0.0, 3.0, 6.0])
def test_grid_without_electrode_edges_weights_give_the_exact_electrode_areas(width_mm):
    d = LatticeDesign(width_mm=width_mm, thickness_mm=2.0)
    mesh = grid_mesh(d, 2.0, 2, 2, electrode_edges=False)
    areas = []
    for k in range(16):
        name = electrode_name(k + 1)
        tri = mesh.facets[name]
        areas.append(float(np.sum(triangle_areas(mesh.nodes_mm, tri) * mesh.weights(name))))
    # t high, as wide as the electrode's contact with the gel, whichever grid lines its edges fall between
    np.testing.assert_allclose(areas, d.thickness_mm * _contact_mm(d), rtol=1e-9)


def test_an_element_coarser_than_the_narrowest_feature_is_warned_once(caplog, monkeypatch):
    import latticeopt.mesh as mesh_module

    monkeypatch.setattr(mesh_module, "_WARNED_COARSE", set())
    design = LatticeDesign(width_mm=4, thickness_mm=3)
    with caplog.at_level("WARNING", logger="latticeopt.mesh"):
        mesh_design(design, MeshSettings(size_mm=2), cache_dir=False)
        assert not caplog.records  # 2 mm resolves a 4 mm channel
        mesh_design(design, MeshSettings(size_mm=40), cache_dir=False)
        mesh_design(design, MeshSettings(size_mm=40), cache_dir=False)  # a sweep's next phantom: said once
    record, = caplog.records
    assert "size_mm = 40 mm" in record.message and "channel width w = 4 mm" in record.message
    caplog.clear()
    with caplog.at_level("WARNING", logger="latticeopt.mesh"):  # the uniform layer: the electrodes are narrowest
        mesh_design(LatticeDesign(width_mm=0, electrode_width_mm=3), MeshSettings(size_mm=3.5), cache_dir=False)
    record, = caplog.records
    assert "electrode width = 3 mm" in record.message


def test_narrowest_feature_is_the_channel_or_the_electrode():
    from latticeopt.mesh import narrowest_feature_mm

    assert narrowest_feature_mm(LatticeDesign(width_mm=2)) == ("channel width w", 2.0)
    assert narrowest_feature_mm(LatticeDesign(width_mm=4)) == ("channel width w", 4.0)
    assert narrowest_feature_mm(LatticeDesign(width_mm=6)) == ("electrode width", 4.0)
    assert narrowest_feature_mm(LatticeDesign(width_mm=0)) == ("electrode width", 4.0)
    # the rim channel is half a channel wide (the footprint tests measure it), so it is the narrowest feature
    assert narrowest_feature_mm(LatticeDesign(width_mm=3, rim="channel")) == ("rim channel 0.5 w", 1.5)
    assert narrowest_feature_mm(LatticeDesign(width_mm=10, rim="channel")) == ("electrode width", 4.0)
