"""Sensor models for the reconstruction codes people already use: EIDORS (MATLAB/Octave) and pyEIT.

:func:`eidors_model` turns a :class:`~latticeopt.sensor_model.SensorModel` into the variables of an EIDORS
``.mat`` file (:func:`write_eidors_mat` writes it): a ``fwd_model`` struct that ``fwd_solve`` takes as it is,
with the complete electrode model, plus the reference voltages, the conductivity and the pixel Jacobian.
:func:`pyeit_fields` gives the arrays pyEIT's ``PyEITMesh`` and ``PyEITProtocol`` take (:func:`write_pyeit_npz`
writes them, :func:`to_pyeit` builds the pyEIT objects). Both are in SI units (metres, S/m, ohm m^2, A, V),
whatever the sensor model's own millimetres.

What each code can represent
----------------------------
EIDORS solves the same complete electrode model on the same 3D hydrogel mesh: an electrode is the set of
boundary triangles whose three nodes are all electrode nodes, which is the exported electrode exactly when
every electrode triangle is fully covered (meshes with electrode-edge lines, the default); a mesh whose
electrode edges cut triangles is refused. pyEIT 1.2.4 knows only point electrodes (one node per electrode,
no contact impedance), so its export carries the point-electrode voltages of the same mesh beside the
complete-electrode ones; the 3D channels themselves are kept (pyEIT's tetrahedral solver takes them).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ._npzfile import write_atomic, write_npz_atomic
from .errors import ParameterError
from .mesh.facets import boundary_faces
from .mesh.tetmesh import electrode_name
from .sensor_model import SensorModel, save_sensor_model

MM = 1e-3  # m per mm
#: pyEIT's tetrahedral stiffness wants the opposite vertex order to ours for a positive volume.
PYEIT_TET_ORDER = [0, 2, 1, 3]


def _off_electrode_node(mesh) -> int:
    """The first node on no electrode (EIDORS' ``gnd_node``, pyEIT's ``ref_node``)."""
    on = np.unique(np.concatenate([mesh.facets[electrode_name(k + 1)] for k in range(mesh.n_electrodes)]))
    return int(np.setdiff1d(np.arange(mesh.n_nodes), on)[0])


def _check_exact_electrodes(model: SensorModel) -> None:
    for k in range(model.mesh.n_electrodes):
        w = model.mesh.weights(electrode_name(k + 1))
        if not np.allclose(w, 1.0, rtol=0, atol=1e-12):
            raise ParameterError("electrode_edges", "a mesh with electrode-edge lines (every electrode triangle "
                                 "fully covered) for an exact EIDORS electrode",
                                 f"electrode {k + 1} with partly covered triangles")


def _protocol_blocks(model: SensorModel) -> list[np.ndarray]:
    """Row indices of each drive, in row order; the rows must come drive by drive."""
    rd = model.protocol.row_drive
    if np.any(np.diff(rd) < 0):
        raise ParameterError("protocol", "rows grouped drive by drive (EIDORS concatenates the measurements of "
                             "each stimulation)", "rows that return to an earlier drive")
    return [np.flatnonzero(rd == d) for d in range(len(model.protocol.drive_currents))]


def eidors_model(model: SensorModel) -> dict:
    """The variables of an EIDORS ``.mat`` file for ``model``.

    Returns
    -------
    dict
        ``fwd_model``: struct with ``type``, ``name``, ``nodes`` (N, 3) m, ``elems`` (E, 4) 1-based,
        ``boundary`` (B, 3) 1-based, ``gnd_node``, ``electrode`` (1 x n_e struct array of ``nodes`` 1-based and
        ``z_contact`` ohm m^2), ``stimulation`` (1 x n_drives struct array: ``stimulation = 'Amp'``,
        ``stim_pattern`` (n_e, 1) A, ``meas_pattern`` (n_meas, n_e) sparse), ``normalize_measurements = 0`` and
        EIDORS' default solver names. ``fwd_solve`` returns the rows in the sensor model's order
        (``v_ref``). Extra variables: ``v_ref`` (n_rows, 1) V, ``sigma_S_per_m`` (E, 1) (the image's
        ``elem_data``), ``jacobian`` (n_rows, n_pixels^2) V per S/m over pixels ``iy * n + ix`` of
        ``pixel_extent_m`` (x0, x1, y0, y1), ``n_pixels``, ``units`` and ``latticeopt`` (version, fingerprint,
        design as JSON).
    """
    if model.electrode_mode != "cem":
        raise ParameterError("electrode_mode", "'cem' (EIDORS' complete electrode model)", model.electrode_mode)
    _check_exact_electrodes(model)
    mesh = model.mesh
    n_e = mesh.n_electrodes
    blocks = _protocol_blocks(model)
    electrode = np.empty((1, n_e), dtype=[("nodes", object), ("z_contact", object)])
    for k in range(n_e):
        electrode[0, k] = (np.unique(mesh.facets[electrode_name(k + 1)]).astype(float)[None, :] + 1,
                           float(model.contact_impedance_ohm_m2[k]))
    stim = np.empty((1, len(blocks)), dtype=[("stimulation", object), ("stim_pattern", object),
                                             ("meas_pattern", object)])
    for d, rows in enumerate(blocks):
        stim[0, d] = ("Amp", (model.protocol.drive_currents[d] * model.current_A)[:, None],
                      sp.csc_matrix(model.protocol.measure[rows]))
    from . import __version__

    fwd_model = {"type": "fwd_model", "name": f"latticeopt {model.design.describe()}",
                 "nodes": mesh.nodes_mm * MM, "elems": mesh.tets.astype(float) + 1,
                 "boundary": boundary_faces(mesh.tets).astype(float) + 1,
                 "gnd_node": float(_off_electrode_node(mesh) + 1),
                 "electrode": electrode, "stimulation": stim, "normalize_measurements": 0.0,
                 "solve": "eidors_default", "system_mat": "eidors_default", "jacobian": "eidors_default"}
    x0, x1, y0, y1 = model.extent_mm
    return {"fwd_model": fwd_model, "v_ref": model.v_ref[:, None], "sigma_S_per_m": model.sigma_S_per_m[:, None],
            "jacobian": model.jacobian, "pixel_extent_m": np.array([[x0, x1, y0, y1]]) * MM,
            "n_pixels": float(model.n_pixels),
            "units": {"lengths": "m", "voltages": "V", "conductivity": "S/m", "jacobian": "V per (S/m)",
                      "contact_impedance": "ohm m^2", "current": "A"},
            "latticeopt": {"version": __version__, "fingerprint": model.fingerprint,
                           "design": json.dumps(model.design.as_dict(), sort_keys=True)}}


def write_eidors_mat(model: SensorModel, path: str | Path) -> Path:
    """Write :func:`eidors_model` as a MATLAB v5 ``.mat`` file (``load`` in MATLAB or Octave); returns the path."""
    from scipy.io import savemat

    variables = eidors_model(model)  # before the file is opened: a refused model leaves no file behind
    return write_atomic(path, lambda fh: savemat(fh, variables, do_compression=True, oned_as="column"))


def pyeit_fields(model: SensorModel) -> dict:
    """Arrays for pyEIT 1.2.4 (``PyEITMesh`` and ``PyEITProtocol``) on the sensor model's hydrogel mesh.

    Returns
    -------
    dict
        ``node`` (N, 3) m, ``element`` (E, 4) 0-based in pyEIT's vertex order, ``perm`` (E,) S/m, ``el_pos``
        (n_e,) the point-electrode node of each electrode (nearest the patch centroid), ``ref_node`` (a node on no
        electrode), ``ex_mat`` (n_drives, 2), ``meas_mat`` (n_drives, n_meas, 2) ``[N, M]`` pairs (value
        ``U[N] - U[M]``), ``keep_ba`` (n_drives * n_e,) bool, ``v_point`` (n_rows,) the point-electrode voltages
        per ampere (pyEIT's ``solve_eit`` scale) and ``v_cem`` (n_rows,) the complete-electrode ones, also per
        ampere.
    """
    from .electrics import ForwardModel

    blocks = _protocol_blocks(model)
    pairs, mpairs = model.protocol.drive_pairs, model.protocol.meas_pairs
    if np.any(pairs < 0) or np.any(mpairs < 0) or len({len(b) for b in blocks}) != 1:
        raise ParameterError("protocol", "pairwise drives and measurements with the same count per drive "
                             "(pyEIT's ex_mat and meas_mat)", model.protocol.name)
    point = ForwardModel(model.mesh, sigma_S_per_m=model.sigma_S_per_m, electrode_mode="point", current_A=1.0,
                         protocol=model.protocol)
    n_e = model.mesh.n_electrodes
    keep = np.zeros((len(blocks), n_e), dtype=bool)
    for d, rows in enumerate(blocks):
        keep[d, mpairs[rows, 1]] = True  # pyEIT indexes keep_ba by M of [N, M]
    return {"node": model.mesh.nodes_mm * MM, "element": model.mesh.tets[:, PYEIT_TET_ORDER],
            "perm": np.array(model.sigma_S_per_m), "el_pos": point.point_nodes,
            "ref_node": _off_electrode_node(model.mesh), "ex_mat": pairs,
            "meas_mat": np.stack([mpairs[rows] for rows in blocks]), "keep_ba": keep.ravel(),
            "v_point": point.voltages, "v_cem": model.v_ref / model.current_A}


def write_pyeit_npz(model: SensorModel, path: str | Path) -> Path:
    """Write :func:`pyeit_fields` as an ``.npz`` (numpy alone reads it); returns the path."""
    return write_npz_atomic(path, pyeit_fields(model))


def to_pyeit(model: SensorModel | str | Path):
    """pyEIT objects for a sensor model (or a sensor-model file): ``(PyEITMesh, PyEITProtocol)``.

    Needs pyEIT (``pip install pyeit==1.2.4``). ``pyeit.eit.fem.EITForward(mesh, protocol).solve_eit()``
    then gives the point-electrode voltages per ampere, ``pyeit_fields(model)["v_point"]``.
    """
    try:
        from pyeit.eit.protocol import PyEITProtocol
        from pyeit.mesh import PyEITMesh
    except ImportError as exc:
        raise ImportError("to_pyeit needs pyEIT: pip install pyeit==1.2.4") from exc
    if not isinstance(model, SensorModel):
        from .sensor_model import load_sensor_model

        model = load_sensor_model(model)
    f = pyeit_fields(model)
    mesh = PyEITMesh(node=f["node"], element=f["element"], perm=f["perm"], el_pos=f["el_pos"],
                     ref_node=f["ref_node"])
    return mesh, PyEITProtocol(f["ex_mat"], f["meas_mat"], f["keep_ba"])


@dataclass(frozen=True)
class ExportFormat:
    """One file format a sensor model is written in: its name, file suffix, writer and a description."""

    name: str
    suffix: str
    writer: Callable[[SensorModel, str | Path], Path]
    description: str


#: The export formats, by name (``latticeopt export --format``): the one table of writer and suffix.
FORMATS: dict[str, ExportFormat] = {f.name: f for f in (
    ExportFormat("npz", ".npz", save_sensor_model, "latticeopt's sensor model"),
    ExportFormat("eidors", ".mat", write_eidors_mat, "MATLAB .mat fwd_model for EIDORS"),
    ExportFormat("pyeit", ".npz", write_pyeit_npz, ".npz of PyEITMesh and PyEITProtocol fields"),
)}
