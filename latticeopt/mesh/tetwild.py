"""Unstructured tet mesher: fTetWild (via pytetwild) on the manifold3d region solids.

fTetWild's CSG mode meshes all region surfaces together and gives every tet the index of the input solid it
lies in (its winding-number "marker"); that is the region label. Plain ``tetrahedralize`` on the merged
surfaces does not work for a layered stack: its winding-number filter drops most of the conductive layer
(the interfaces flip the winding number), which is fTetWild issue #69.

The envelope. fTetWild keeps every output surface within ``epsilon = epsilon_rel * diagonal`` of its input
(0.14 mm for the default sensor at ``epsilon_rel = 1e-3``), not on it: outer faces bulge out to ~0.06 mm,
interfaces wander, and where a layer interface meets the outer wall fTetWild only stays near the *wall*,
so the interface line zigzags up to ~0.4 mm. Raw, the hydrogel volume comes out ~0.1 % low and electrode
areas up to ~2.4 % off (mean -0.6 %). So, after meshing, surface nodes are *snapped* onto their exact
planes (:func:`snap_to_planes`): nodes of outer faces and channel walls lying within the envelope, and
nodes of the layer interfaces within three envelopes (those planes are known from the region labels). A
move that would flatten or invert a tet, or drop its quality below 0.2, is shortened (halved until
harmless, at worst dropped), nodes pulled *into* the layer yielding first. Measured for ``w = 4, t = 3`` on 6
meshes at 2-3 mm (and benchmarks/bench_mesh.py): hydrogel volume error <= 0.0001 %, electrode areas within
0.015 %, min quality >= 0.2. Where an electrode edge is a box edge (a layer without substrate or sealing)
fTetWild's chamfer along it cannot always be sharpened by moving nodes (that would need edge collapses):
there single electrodes stay up to ~1 % off. Facet sets are then found with
:func:`~latticeopt.mesh.facets.tag_facets` at the envelope tolerance (never equality), and electrode patches
carry exact fractional coverage because triangles do not follow electrode outlines.

fTetWild runs in a child process (see :func:`_child_main`): it prints to C++ stdout, drops debug files
into the working directory and can abort. It is not deterministic (thread scheduling), which is why meshes
are cached by content hash.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..design import REGION_IDS, LatticeDesign
from ..errors import MeshError
from ..geometry import build_solids
from .facets import face_keys, tag_facets
from .tetmesh import TET_FACES, TetMesh, mean_ratio_quality, tet_volumes

log = logging.getLogger(__name__)

#: Worst tet quality (mean ratio) a snap may leave behind, or the mesh's own minimum if that is lower.
#: 0.3 left a 0.9 % electrode-area outlier on one of 6 meshes that 0.2 removes; 0.1 gained nothing more.
SNAP_MIN_QUALITY = 0.2
#: Layer interfaces are told apart by their region labels, not by position, so their nodes may move further
#: (this many envelope tolerances): where an interface meets the outer wall fTetWild only keeps nodes
#: within the envelope of the *wall*, and measured interface nodes there sat up to 0.38 mm off their plane.
INTERFACE_TOL_FACTOR = 3.0


def _write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    with open(path, "w") as fh:
        np.savetxt(fh, vertices, fmt="v %.17g %.17g %.17g")
        np.savetxt(fh, faces + 1, fmt="f %d %d %d")


def _union_tree(leaves: list[str]):
    """Balanced CSG union tree over the files ``leaves`` (fTetWild numbers markers by leaf order, from 1)."""
    if len(leaves) == 1:
        return leaves[0]
    mid = len(leaves) // 2
    return {"operation": "union", "left": _union_tree(leaves[:mid]), "right": _union_tree(leaves[mid:])}


def _tail(path: Path, n: int = 5) -> str:
    try:
        return " | ".join(path.read_text(errors="replace").strip().splitlines()[-n:])
    except OSError:
        return ""


def _child_main(folder: str) -> None:
    """Body of the child process of :func:`run_ftetwild`: mesh the job in ``folder`` and write ``result.npz`` there.

    fTetWild runs in its own process (``python -m latticeopt.mesh.tetwild FOLDER``) because it prints to C++
    stdout through buffers Python cannot flush (that text would land in the CLI's ``--json`` output), writes
    debug files into the working directory, and may abort or crash the interpreter on bad input.
    """
    import pytetwild

    folder = Path(folder)
    job = json.loads((folder / "job.json").read_text())
    if len(job["files"]) == 1:
        with np.load(folder / "solid.npz") as z:
            # The binding wants writeable C-contiguous float64 vertices and uint32 faces.
            v = np.array(z["vertices"], dtype=np.float64, order="C")
            f = np.array(z["faces"], dtype=np.uint32, order="C")
        pts, tets = pytetwild.tetrahedralize(v, f, edge_length_abs=job["size_mm"], epsilon=job["epsilon_rel"],
                                             num_threads=job["num_threads"], quiet=True, loglevel=6)
        marker = np.ones(len(tets), dtype=np.int64)
    else:
        (folder / "csg.json").write_text(json.dumps(_union_tree(job["files"])))
        grid = pytetwild.tetrahedralize_csg(str(folder / "csg.json"), epsilon=job["epsilon_rel"],
                                            edge_length_r=job["edge_length_r"], coarsen=False,
                                            num_threads=job["num_threads"], loglevel=6)
        pts, tets, marker = grid.points, grid.cells_dict[10], grid["marker"]
    np.savez(folder / "result.npz", nodes=np.asarray(pts, dtype=np.float64), tets=np.asarray(tets, dtype=np.int64),
             marker=np.asarray(marker, dtype=np.int64))


def run_ftetwild(design: LatticeDesign, size_mm: float, epsilon_rel: float,
                  num_threads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run fTetWild on the region solids in a child process.

    Returns
    -------
    nodes_mm : ndarray, shape (N, 3)
    tets : ndarray, shape (M, 4), as fTetWild orders them (not necessarily positive)
    region : ndarray, shape (M,), int8 region ids from fTetWild's CSG markers
    """
    solids = build_solids(design)
    names = list(solids.names)
    L, H = design.size_mm, design.total_thickness_mm
    diag = float(np.sqrt(2 * L * L + H * H))
    with tempfile.TemporaryDirectory(prefix="latticeopt-tetwild-") as tmp:
        tmp = Path(tmp)
        files = []
        for name in names:
            files.append(str(tmp / f"{name}.obj"))
            _write_obj(Path(files[-1]), solids.vertices_mm[name], solids.faces[name])
        if len(names) == 1:
            np.savez(tmp / "solid.npz", vertices=solids.vertices_mm[names[0]], faces=solids.faces[names[0]])
        job = {"files": files, "size_mm": size_mm, "edge_length_r": size_mm / diag, "epsilon_rel": epsilon_rel,
               "num_threads": num_threads}
        (tmp / "job.json").write_text(json.dumps(job))
        logfile = tmp / "ftetwild.log"
        with open(logfile, "wb") as fh:
            proc = subprocess.run([sys.executable, "-m", __name__, str(tmp)], cwd=tmp, stdout=fh,
                                  stderr=subprocess.STDOUT, check=False)
        if proc.returncode != 0 or not (tmp / "result.npz").exists():
            raise MeshError(f"fTetWild failed (exit status {proc.returncode}); its last output: {_tail(logfile)}")
        log.debug("fTetWild output: %s", _tail(logfile, 20))
        with np.load(tmp / "result.npz") as z:
            nodes, tets, marker = z["nodes"], z["tets"], z["marker"]
    lut = np.full(len(names) + 1, -1, dtype=np.int64)
    lut[1:] = [REGION_IDS[n] for n in names]
    if len(marker) == 0 or marker.min() < 1 or marker.max() > len(names):
        raise MeshError(f"fTetWild markers outside 1..{len(names)}: {np.unique(marker).tolist()}")
    return np.ascontiguousarray(nodes), np.ascontiguousarray(tets), lut[marker].astype(np.int8)


def _check_labels(nodes: np.ndarray, tets: np.ndarray, region: np.ndarray, design: LatticeDesign) -> float:
    """Fraction of tets whose marker label equals the analytic label of their centroid.

    Guards the marker -> region mapping: fTetWild's marker numbering is undocumented, so a mismatch means
    the mapping broke, not a few envelope tets.
    """
    agree = float(np.mean(design.region_at(nodes[tets].mean(axis=1)) == region))
    if agree < 0.98:
        raise MeshError(f"fTetWild region markers agree with the geometry on only {agree:.1%} of tets")
    return agree


def _plane_targets(nodes: np.ndarray, faces: np.ndarray, axis: int, planes: np.ndarray,
                   tol_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(node, coordinate) pairs for nodes of faces lying within ``tol_mm`` of one of ``planes`` (on ``axis``)."""
    if len(faces) == 0 or len(planes) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    c = nodes[faces][:, :, axis]  # (K, 3)
    nearest = planes[np.argmin(np.abs(c.mean(axis=1)[:, None] - planes[None, :]), axis=1)]
    on = np.abs(c - nearest[:, None]).max(axis=1) <= tol_mm
    return faces[on].ravel(), np.repeat(nearest[on], 3)


def snap_to_planes(nodes: np.ndarray, tets: np.ndarray, region: np.ndarray, design: LatticeDesign,
                   tol_mm: float) -> tuple[np.ndarray, dict]:
    """Move surface nodes lying within ``tol_mm`` of their exact plane onto it.

    Surfaces considered: the outer box faces (``x, y = 0, L``; ``z = 0, H``), the layer interfaces
    (``z = z0`` between substrate and layer, ``z = z1`` between layer and sealing) and the channel walls
    between hydrogel and islands (``x`` or ``y`` = a channel edge). A triangle of such a surface snaps when
    all three nodes are within ``tol_mm`` of the same plane (``INTERFACE_TOL_FACTOR * tol_mm`` for the layer
    interfaces, whose plane the region labels identify); a node claimed by two different planes of one axis
    stays put, and nodes of tets that the move would invert or flatten (quality below
    :data:`SNAP_MIN_QUALITY`, or the mesh's own minimum if lower) move only part of the way.

    Returns
    -------
    nodes_mm : ndarray, shape (N, 3)
    stats : dict
        ``moved`` (number of nodes moved), ``max_move_mm``, ``partial`` (nodes moved only part of the way)
        and ``kept`` (nodes that could not move at all).
    """
    L, H = design.size_mm, design.total_thickness_mm
    z0, z1 = design.layer_z_mm
    n = len(nodes)
    faces = tets[:, TET_FACES].reshape(-1, 3)
    owner = np.repeat(region, 4)
    _, inv, cnt = np.unique(face_keys(faces, n), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    outer = faces[cnt[inv] == 1]
    order = np.argsort(inv, kind="stable")  # the two copies of an interior face end up side by side
    pair = inv[order][1:] == inv[order][:-1]
    a, b = order[:-1][pair], order[1:][pair]
    lo, hi = np.minimum(owner[a], owner[b]), np.maximum(owner[a], owner[b])
    sub, gel, isl, seal = (REGION_IDS[k] for k in ("substrate", "hydrogel", "islands", "sealing"))
    layer = (gel, isl)
    lower_if = faces[a[(lo == sub) & np.isin(hi, layer)]]
    upper_if = faces[a[np.isin(lo, layer) & (hi == seal)]]
    walls = faces[a[(lo == gel) & (hi == isl)]]
    edges = np.unique(design.channel_intervals_mm().ravel())
    targets = {0: [], 1: [], 2: []}
    for axis, surf, planes in (
            (0, outer, np.array([0.0, L])), (1, outer, np.array([0.0, L])), (2, outer, np.array([0.0, H])),
            (2, lower_if, np.array([z0])), (2, upper_if, np.array([z1])),
            (0, walls, edges), (1, walls, edges)):
        tol = tol_mm * (INTERFACE_TOL_FACTOR if surf is lower_if or surf is upper_if else 1.0)
        targets[axis].append(_plane_targets(nodes, surf, axis, planes, tol))
    new = nodes.copy()
    for axis, parts in targets.items():
        idx = np.concatenate([p[0] for p in parts])
        val = np.concatenate([p[1] for p in parts])
        if len(idx) == 0:
            continue
        uniq, inv = np.unique(idx, return_inverse=True)
        vmin = np.full(len(uniq), np.inf)
        vmax = np.full(len(uniq), -np.inf)
        np.minimum.at(vmin, inv, val)
        np.maximum.at(vmax, inv, val)
        ok = vmin == vmax  # one plane per axis, else ambiguous
        new[uniq[ok], axis] = vmin[ok]
    # A node whose full move would flatten or invert a tet (typically a sliver where an interface meets
    # the outer wall) goes half as far, then a quarter, ..., and finally stays put. Within such a tet, nodes
    # that a layer interface pulls *into* the layer give way first: the others restore the layer's full
    # height, which is what the electrode patches (clipped to [z0, z1]) need.
    q_floor = min(SNAP_MIN_QUALITY, float(mean_ratio_quality(nodes, tets).min()))
    target, step = new, np.ones(n)
    wanted = np.any(target != nodes, axis=1)
    dz = target[:, 2] - nodes[:, 2]
    widening = ((target[:, 2] == z1) & (dz > 0)) | ((target[:, 2] == z0) & (dz < 0))
    # Terminates: every pass lowers some node's step (1, 1/2, ..., 1/16, 0), and tets whose nodes all
    # stay put are fTetWild's own, whose quality is at least q_floor.
    while True:
        new = nodes + step[:, None] * (target - nodes)
        bad = (tet_volumes(new, tets) <= 0) | (mean_ratio_quality(new, tets) < q_floor)
        if not bad.any():
            break
        t_bad = tets[bad]
        moving = wanted[t_bad] & (step[t_bad] > 0)
        yielding = moving & ~widening[t_bad]
        chosen = np.where(yielding.any(axis=1, keepdims=True), yielding, moving)
        back = np.unique(t_bad[chosen])
        if len(back) == 0:
            break
        step[back] = np.where(step[back] > 1 / 16, step[back] / 2, 0.0)
    move = np.linalg.norm(new - nodes, axis=1)
    return new, {"moved": int(np.count_nonzero(move)), "max_move_mm": float(move.max(initial=0.0)),
                 "partial": int(np.count_nonzero(wanted & (step > 0) & (step < 1))),
                 "kept": int(np.count_nonzero(wanted & (step == 0)))}


def tetwild_mesh(design: LatticeDesign, size_mm: float = 3.0, epsilon_rel: float = 1e-3, *,
                 snap: bool = True, num_threads: int = 0) -> TetMesh:
    """Unstructured labelled tet mesh of ``design`` with fTetWild.

    Parameters
    ----------
    design
        The sensor design (any pattern that :func:`~latticeopt.geometry.build_solids` builds).
    size_mm
        Target (ideal) edge length (mm).
    epsilon_rel
        Envelope relative to the bounding-box diagonal: output surfaces lie within
        ``epsilon_rel * diagonal`` mm of the input.
    snap
        Snap surface nodes within the envelope onto their exact planes (see the module docstring).
    num_threads
        fTetWild threads; 0 uses all cores.

    Returns
    -------
    TetMesh
        Positively oriented tets labelled by fTetWild's CSG markers, facet sets found at the envelope
        tolerance. ``info`` records the envelope, label agreement with the analytic geometry and the snap.

    Raises
    ------
    MeshError
        fTetWild failed, lost tets (total volume off by more than 1 %), produced a flat tet, left out a
        region or an electrode patch, or its labels disagree with the geometry.
    """
    nodes, tets, region = run_ftetwild(design, size_mm, epsilon_rel, num_threads)
    return tetmesh_from_ftetwild(design, nodes, tets, region, epsilon_rel, snap=snap)


def tetmesh_from_ftetwild(design: LatticeDesign, nodes: np.ndarray, tets: np.ndarray, region: np.ndarray,
                          epsilon_rel: float, *, snap: bool = True) -> TetMesh:
    """Check, orient, snap and tag fTetWild's raw output (the second half of :func:`tetwild_mesh`).

    Separate so that one (slow, nondeterministic) fTetWild run can be finished with and without snapping,
    as benchmarks/bench_mesh.py does.
    """
    tets = np.array(tets, dtype=np.int64)
    vol = tet_volumes(nodes, tets)
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    vol = np.abs(vol)
    if vol.min() <= 1e-12 * vol.mean():
        raise MeshError(f"fTetWild produced a flat tet (volume {vol.min():.3g} mm^3)")
    L, H = design.size_mm, design.total_thickness_mm
    box = L * L * H
    if abs(vol.sum() - box) > 0.01 * box:
        raise MeshError(f"fTetWild mesh volume {vol.sum():.1f} mm^3 differs from the sensor's {box:.1f} mm^3 "
                        "by more than 1 % (tets lost)")
    agree = _check_labels(nodes, tets, region, design)
    tol_mm = epsilon_rel * float(np.sqrt(2 * L * L + H * H))
    stats = {"moved": 0, "max_move_mm": 0.0, "partial": 0, "kept": 0}
    if snap:
        nodes, stats = snap_to_planes(nodes, tets, region, design, 1.5 * tol_mm)
        log.info("tetwild snap: %d nodes moved (max %.3f mm), %d part of the way, %d kept", stats["moved"],
                 stats["max_move_mm"], stats["partial"], stats["kept"])
    expected = [name for name, v in design.region_volumes_mm3().items() if v > 0]
    missing = [name for name in expected if not np.any(region == REGION_IDS[name])]
    if missing:
        raise MeshError(f"fTetWild mesh has no tets in region(s) {missing}")
    facets, weights = tag_facets(nodes, tets, region, design, tol_mm=1.5 * tol_mm)
    empty = [name for name, tri in facets.items() if len(tri) == 0]
    if empty:
        raise MeshError(f"fTetWild mesh has empty facet set(s) {empty}")
    info = {"mesher": "tetwild", "envelope_mm": tol_mm, "label_agreement": agree, "snap": stats}
    return TetMesh(nodes, tets, region, facets, weights, info)


if __name__ == "__main__":  # the child process of run_ftetwild
    _child_main(sys.argv[1])
