"""Sensor-model files: everything reconstruction and classification code needs from a design, in one file.

:func:`export_sensor_model` meshes a design, solves its rest state at the background conductivity and writes
a versioned ``.npz`` (no pickles; metadata as a JSON string) that :func:`load_sensor_model` reads back into a
frozen :class:`SensorModel`. :class:`~latticeopt.sensor_simulator.SensorSimulator` (importable from here too)
rebuilds the forward model from a loaded file and simulates voltage frames of pixel-conductivity images. The
format is documented in ``docs/sensor_model.md``.

Background conductivity and contact impedance
---------------------------------------------
The paper's image model uses ``sigma0 = 0.00312 S/m`` (§V); :data:`SIGMA0_S_PER_M` is the export default. The
electrics default is 1 S/m with ``z_c = 2e-3 ohm m^2``, i.e. ``z_c sigma = 2 mm`` (Cheng et al. 1989 fitted
``z_c sigma`` of 2.0-2.5 mm for metal electrodes on saline). Unless a contact impedance is given, the export
keeps that product: ``z_c = 2e-3 ohm m^2 * 1 S/m / sigma`` (0.641 ohm m^2 at sigma0), so the dimensionless
contact number ``z_c sigma / w`` stays 0.5 for 4 mm electrodes and every voltage is exactly the 1 S/m model's
voltage divided by ``sigma`` (the complete-electrode-model system scales as a whole). Voltages at sigma0 and
1 mA are therefore about 320 times those at 1 S/m.
"""

from __future__ import annotations

import hashlib
import json
import logging
import zipfile
import zlib
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from . import _validate as v
from ._npzfile import write_npz_atomic
from .design import REGION_IDS, LatticeDesign
from .electrics import DEFAULT_CONTACT_IMPEDANCE_OHM_M2, DEFAULT_CURRENT_A, DEFAULT_SIGMA_S_PER_M, ForwardModel
from .electrics.protocol import Protocol
from .errors import LatticeoptError, ParameterError
from .mesh import MeshSettings, mesh_design
from .mesh.tetmesh import TetMesh, electrode_name

log = logging.getLogger(__name__)

FORMAT = "latticeopt-sensor-model"
FORMAT_VERSION = 1
#: Background conductivity of the paper's image model (S/m).
SIGMA0_S_PER_M = 0.00312
#: ``z_c * sigma`` kept by the export when no contact impedance is given (m): the electrics defaults' product.
CONTACT_LENGTH_M = DEFAULT_CONTACT_IMPEDANCE_OHM_M2 * DEFAULT_SIGMA_S_PER_M

UNITS = {"lengths": "mm", "voltages": "V", "conductivity": "S/m", "jacobian": "V per (S/m)",
         "contact_impedance": "ohm m^2", "current": "A"}
_ARRAYS = ("electrodes", "drive_currents", "measure", "row_drive", "meas_pairs", "independent", "v_ref",
           "jacobian", "pixel_edges_x_mm", "pixel_edges_y_mm", "pixel_gel_fraction", "pixel_matrix_data",
           "pixel_matrix_indices", "pixel_matrix_indptr", "mesh_nodes_mm", "mesh_tets", "mesh_electrode_tris",
           "mesh_electrode_number", "mesh_electrode_weights", "sigma_S_per_m", "contact_impedance_ohm_m2")


class SensorModelError(LatticeoptError, ValueError):
    """A sensor-model file cannot be read: missing, truncated, corrupted, not ours, or from a newer version."""


@dataclass(frozen=True, eq=False)
class SensorModel:
    """The content of a sensor-model file (see ``docs/sensor_model.md``); arrays are read-only.

    Attributes
    ----------
    design : LatticeDesign
    mesh_settings : dict
        :class:`~latticeopt.mesh.MeshSettings` fields the hydrogel mesh was built with.
    electrodes : ndarray, shape (n_e, 8)
        :meth:`LatticeDesign.electrodes` rows (electrode ``k + 1`` in row ``k``, counter-clockwise from above).
    protocol : Protocol
        Drive/measurement patterns; rows in pyEIT ``"std"`` order for the adjacent protocol.
    v_ref : ndarray, shape (n_rows,)
        Voltages (V) of the untouched sensor at ``sigma0``.
    jacobian : ndarray, shape (n_rows, n_pixels ** 2)
        ``dV / d sigma_pixel`` (V per S/m) at the background, pixel ``iy * n + ix``.
    n_pixels : int
    extent_mm : tuple of 4 floats
        ``(x0, x1, y0, y1)`` of the pixel grid.
    pixel_gel_fraction : ndarray, shape (n_pixels ** 2,)
        Hydrogel volume under each pixel over ``pixel area * t`` (0 above a silicone island).
    pixel_matrix : scipy.sparse.csr_matrix, shape (n_tets, n_pixels ** 2)
        Volume fraction of each hydrogel tet above each pixel (rows sum to 1).
    mesh : TetMesh
        The hydrogel mesh with its electrode facet sets.
    sigma_S_per_m : ndarray, shape (n_tets,)
        Background conductivity per hydrogel tet.
    sigma0_S_per_m : float
        The background as one number (the pixel images' reference).
    contact_impedance_ohm_m2 : ndarray, shape (n_e,)
    current_A : float
    electrode_mode : str
    software_version : str
        latticeopt version that wrote the file.
    created_utc : str
    """

    design: LatticeDesign
    mesh_settings: dict
    electrodes: np.ndarray
    protocol: Protocol
    v_ref: np.ndarray
    jacobian: np.ndarray
    n_pixels: int
    extent_mm: tuple
    pixel_gel_fraction: np.ndarray
    pixel_matrix: sp.csr_matrix
    mesh: TetMesh
    sigma_S_per_m: np.ndarray
    sigma0_S_per_m: float
    contact_impedance_ohm_m2: np.ndarray
    current_A: float
    electrode_mode: str = "cem"
    software_version: str = ""
    created_utc: str = ""
    fingerprint: str = field(init=False)

    def __post_init__(self) -> None:
        for name in ("electrodes", "v_ref", "jacobian", "pixel_gel_fraction", "sigma_S_per_m",
                     "contact_impedance_ohm_m2"):
            a = np.ascontiguousarray(getattr(self, name))
            a.flags.writeable = False
            object.__setattr__(self, name, a)
        h = hashlib.sha256()
        for a in (self.v_ref, self.jacobian, self.sigma_S_per_m, self.contact_impedance_ohm_m2):
            h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
        h.update(json.dumps(self.design.as_dict(), sort_keys=True).encode())
        object.__setattr__(self, "fingerprint", h.hexdigest()[:16])

    @property
    def n_rows(self) -> int:
        return self.protocol.n_rows

    @property
    def independent(self) -> np.ndarray:
        """The reciprocity-independent rows (104 of 208 for the adjacent protocol)."""
        return self.protocol.independent

    def pixel_centres_mm(self) -> np.ndarray:
        """Centre ``(x, y)`` of every pixel in pixel order ``iy * n + ix``, shape ``(n * n, 2)``."""
        x0, x1, y0, y1 = self.extent_mm
        n = self.n_pixels
        xc = x0 + (np.arange(n) + 0.5) * (x1 - x0) / n
        yc = y0 + (np.arange(n) + 0.5) * (y1 - y0) / n
        X, Y = np.meshgrid(xc, yc)  # rows iy, columns ix
        return np.stack([X.ravel(), Y.ravel()], axis=1)

    def summary(self) -> dict:
        return {"design": self.design.as_dict(), "format_version": FORMAT_VERSION,
                "gel_nodes": self.mesh.n_nodes, "gel_tets": self.mesh.n_tets, "n_rows": self.n_rows,
                "n_pixels": self.n_pixels, "sigma0_S_per_m": self.sigma0_S_per_m,
                "contact_impedance_ohm_m2": float(np.mean(self.contact_impedance_ohm_m2)),
                "contact_number": float(np.mean(self.contact_impedance_ohm_m2) * self.sigma0_S_per_m
                                        / (self.design.electrode_width_mm * 1e-3)),
                "current_A": self.current_A, "v_ref_range_V": [float(np.abs(self.v_ref).min()),
                                                               float(np.abs(self.v_ref).max())],
                "fingerprint": self.fingerprint}


# -- building and writing --------------------------------------------------------------------------------

def build_sensor_model(design: LatticeDesign, mesh_settings: MeshSettings | None = None,
                       sigma_S_per_m: float = SIGMA0_S_PER_M, contact_impedance_ohm_m2: float | None = None,
                       n_pixels: int = 48, current_A: float = DEFAULT_CURRENT_A,
                       cache_dir=None) -> SensorModel:
    """Mesh ``design``, solve its rest state and compute the pixel Jacobian (see :func:`export_sensor_model`)."""
    if not isinstance(design, LatticeDesign):
        raise ParameterError("design", "a LatticeDesign", type(design).__name__)
    settings = mesh_settings or MeshSettings()
    sigma = v.real("sigma_S_per_m", sigma_S_per_m, lo=0, lo_open=True)
    zc = CONTACT_LENGTH_M / sigma if contact_impedance_ohm_m2 is None else v.real(
        "contact_impedance_ohm_m2", contact_impedance_ohm_m2, lo=0, lo_open=True)
    n = v.integer("n_pixels", n_pixels, lo=2, hi=512)
    mesh = mesh_design(design, settings, cache_dir=cache_dir)
    fwd = ForwardModel(mesh, sigma_S_per_m=sigma, contact_impedance_ohm_m2=zc, current_A=current_A)
    L = design.size_mm
    extent = (0.0, L, 0.0, L)
    F = fwd.pixel_matrix(n, extent).tocsr()
    F.sort_indices()
    J = np.asarray((F.T @ fwd.jacobian().T).T)
    vol = fwd.mesh.tet_volumes_mm3()
    gel_fraction = (F.T @ vol) / ((L / n) ** 2 * design.thickness_mm)
    gel = fwd.mesh
    info = {"design": design.as_dict(), "restricted_to": ["hydrogel"]}
    gel = TetMesh(gel.nodes_mm, gel.tets, gel.region,
                  {electrode_name(k + 1): gel.facets[electrode_name(k + 1)] for k in range(gel.n_electrodes)},
                  {electrode_name(k + 1): gel.weights(electrode_name(k + 1)) for k in range(gel.n_electrodes)},
                  info)
    return SensorModel(design=design, mesh_settings=settings.resolved(design).as_dict(), electrodes=design.electrodes(),
                       protocol=fwd.protocol, v_ref=fwd.voltages, jacobian=J, n_pixels=n, extent_mm=extent,
                       pixel_gel_fraction=gel_fraction, pixel_matrix=F, mesh=gel, sigma_S_per_m=fwd.sigma,
                       sigma0_S_per_m=sigma, contact_impedance_ohm_m2=fwd.contact_impedance_ohm_m2,
                       current_A=fwd.current_A, electrode_mode=fwd.electrode_mode,
                       software_version=_version(), created_utc=datetime.now(UTC).isoformat(timespec="seconds"))


def _version() -> str:
    from . import __version__

    return __version__


def save_sensor_model(model: SensorModel, path: str | Path) -> Path:
    """Write ``model`` to ``path`` (``.npz``, atomically: a temporary file renamed into place)."""
    path = Path(path)
    m, F, p = model.mesh, model.pixel_matrix, model.protocol
    n_e = m.n_electrodes
    tris = [m.facets[electrode_name(k + 1)] for k in range(n_e)]
    x0, x1, y0, y1 = model.extent_mm
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "software": "latticeopt",
            "software_version": model.software_version, "created_utc": model.created_utc,
            "design": model.design.as_dict(), "mesh_settings": model.mesh_settings, "units": UNITS,
            "n_pixels": model.n_pixels, "extent_mm": list(model.extent_mm), "pixel_order": "iy * n_pixels + ix",
            "sigma0_S_per_m": model.sigma0_S_per_m, "current_A": model.current_A,
            "electrode_mode": model.electrode_mode, "protocol": p.name, "n_rows": p.n_rows,
            "row_order": "pyEIT protocol.create(16, 1, 1, 'std'): drive d = 0..15 from electrode d to d + 1 "
                         "(0-based), rows U[m + 1] - U[m] for m ascending, pairs touching a drive skipped",
            "electrode_columns": ["x_mm", "y_mm", "z_mm", "normal_x", "normal_y", "tangent_axis", "width_mm",
                                  "height_mm"],
            "fingerprint": model.fingerprint}
    arrays = {
        "metadata": np.array(json.dumps(meta, sort_keys=True)),
        "format_version": np.array(FORMAT_VERSION),
        "electrodes": model.electrodes, "drive_currents": p.drive_currents, "measure": p.measure,
        "row_drive": p.row_drive, "meas_pairs": p.meas_pairs, "independent": p.independent,
        "v_ref": model.v_ref, "jacobian": model.jacobian,
        "pixel_edges_x_mm": np.linspace(x0, x1, model.n_pixels + 1),
        "pixel_edges_y_mm": np.linspace(y0, y1, model.n_pixels + 1),
        "pixel_gel_fraction": model.pixel_gel_fraction,
        "pixel_matrix_data": F.data, "pixel_matrix_indices": F.indices.astype(np.int64),
        "pixel_matrix_indptr": F.indptr.astype(np.int64),
        "mesh_nodes_mm": m.nodes_mm, "mesh_tets": m.tets, "mesh_electrode_tris": np.concatenate(tris),
        "mesh_electrode_number": np.concatenate([np.full(len(t), k + 1, np.int64) for k, t in enumerate(tris)]),
        "mesh_electrode_weights": np.concatenate([m.weights(electrode_name(k + 1)) for k in range(n_e)]),
        "sigma_S_per_m": model.sigma_S_per_m, "contact_impedance_ohm_m2": model.contact_impedance_ohm_m2,
    }
    return write_npz_atomic(path, arrays, compressed=True)


def export_sensor_model(design: LatticeDesign, path: str | Path, mesh_settings: MeshSettings | None = None,
                        sigma_S_per_m: float = SIGMA0_S_PER_M, contact_impedance_ohm_m2: float | None = None,
                        n_pixels: int = 48, cache_dir=None, current_A: float = DEFAULT_CURRENT_A) -> Path:
    """Export ``design`` as a sensor-model file.

    Parameters
    ----------
    design
        The sensor design.
    path
        Output ``.npz`` file.
    mesh_settings
        Mesh of the forward model (default :class:`MeshSettings()`, 2 mm grid).
    sigma_S_per_m
        Background hydrogel conductivity (default the paper's 0.00312 S/m).
    contact_impedance_ohm_m2
        Contact impedance; ``None`` keeps ``z_c sigma`` of the electrics defaults (module docstring).
    n_pixels
        Pixels per side of the image grid over the sensor (default 48).
    cache_dir
        Mesh cache folder (see :func:`latticeopt.mesh.mesh_design`).
    current_A
        Drive current.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise ParameterError("path", "a file name ending in .npz", str(path))
    model = build_sensor_model(design, mesh_settings, sigma_S_per_m, contact_impedance_ohm_m2, n_pixels,
                               current_A, cache_dir)
    return save_sensor_model(model, path)


# -- reading ---------------------------------------------------------------------------------------------

def _bad(path: Path, why: str) -> SensorModelError:
    return SensorModelError(f"{path}: not a readable latticeopt sensor-model file ({why})")


def load_sensor_model(path: str | Path) -> SensorModel:
    """Read a file written by :func:`export_sensor_model` (never unpickles).

    Raises
    ------
    SensorModelError
        Missing, truncated or corrupted files, other formats, newer format versions, inconsistent arrays.
    """
    path = Path(path)
    if not path.is_file():
        raise SensorModelError(f"{path}: no such sensor-model file")
    with open(path, "rb") as fh:
        if fh.read(4) != b"PK\x03\x04":  # np.load would try to unpickle anything that is not npy/npz
            raise _bad(path, "not an .npz (zip) archive")
    try:
        with np.load(path, allow_pickle=False) as z:
            if "metadata" not in z.files:
                raise _bad(path, "no 'metadata' entry")
            meta = json.loads(str(z["metadata"]))
            if not isinstance(meta, dict) or meta.get("format") != FORMAT:
                raise _bad(path, f"format is not {FORMAT!r}")
            version = meta.get("format_version")
            if not isinstance(version, int) or version < 1:
                raise _bad(path, f"invalid format_version {version!r}")
            if version > FORMAT_VERSION:
                raise SensorModelError(f"{path}: sensor-model format version {version} was written by a newer "
                                       f"latticeopt ({meta.get('software_version')}); this one reads up to "
                                       f"{FORMAT_VERSION}: upgrade latticeopt")
            missing = [k for k in _ARRAYS if k not in z.files]
            if missing:
                raise _bad(path, f"missing arrays {missing}")
            a = {k: z[k] for k in _ARRAYS}  # reads every member in full, so zip CRCs are checked
    except SensorModelError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, UnicodeDecodeError) as exc:
        raise _bad(path, f"{type(exc).__name__}: {exc}") from None
    try:
        return _assemble(meta, a)
    except (ParameterError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise _bad(path, f"inconsistent content: {exc}") from None


def _assemble(meta: dict, a: dict) -> SensorModel:
    # Files written before layouts were a design parameter hold the square lattice with its rim channel.
    design = LatticeDesign(**{"rim": "channel", **meta["design"]})
    protocol = Protocol.from_matrices(a["drive_currents"], a["measure"], a["row_drive"], meta["protocol"])
    n = int(meta["n_pixels"])
    nodes, tets = a["mesh_nodes_mm"], a["mesh_tets"]
    numbers, tris, w = a["mesh_electrode_number"], a["mesh_electrode_tris"], a["mesh_electrode_weights"]
    n_e = protocol.n_electrodes
    facets = {electrode_name(k): tris[numbers == k] for k in range(1, n_e + 1)}
    weights = {electrode_name(k): w[numbers == k] for k in range(1, n_e + 1)}
    mesh = TetMesh(nodes, tets, np.full(len(tets), REGION_IDS["hydrogel"]), facets, weights,
                   {"design": design.as_dict(), "restricted_to": ["hydrogel"]})
    F = sp.csr_matrix((a["pixel_matrix_data"], a["pixel_matrix_indices"], a["pixel_matrix_indptr"]),
                      shape=(len(tets), n * n))
    checks = {"v_ref": (a["v_ref"].shape, (protocol.n_rows,)),
              "jacobian": (a["jacobian"].shape, (protocol.n_rows, n * n)),
              "sigma_S_per_m": (a["sigma_S_per_m"].shape, (len(tets),)),
              "electrodes": (a["electrodes"].shape, (n_e, 8)),
              "contact_impedance_ohm_m2": (a["contact_impedance_ohm_m2"].shape, (n_e,)),
              "pixel_gel_fraction": (a["pixel_gel_fraction"].shape, (n * n,)),
              "mesh_tets": (tets.shape[1:], (4,))}
    for name, (got, want) in checks.items():
        if tuple(got) != tuple(want):
            raise ValueError(f"{name} has shape {got}, expected {want}")
    if tets.size and (tets.min() < 0 or tets.max() >= len(nodes)):
        raise ValueError("mesh_tets index nodes that do not exist")
    model = SensorModel(design=design, mesh_settings=meta["mesh_settings"], electrodes=a["electrodes"],
                        protocol=protocol, v_ref=a["v_ref"], jacobian=a["jacobian"], n_pixels=n,
                        extent_mm=tuple(float(e) for e in meta["extent_mm"]),
                        pixel_gel_fraction=a["pixel_gel_fraction"], pixel_matrix=F, mesh=mesh,
                        sigma_S_per_m=a["sigma_S_per_m"], sigma0_S_per_m=float(meta["sigma0_S_per_m"]),
                        contact_impedance_ohm_m2=a["contact_impedance_ohm_m2"], current_A=float(meta["current_A"]),
                        electrode_mode=meta["electrode_mode"], software_version=meta["software_version"],
                        created_utc=meta["created_utc"])
    if meta.get("fingerprint") not in (None, model.fingerprint):
        raise ValueError("the arrays do not match the fingerprint in the metadata")
    return model


def __getattr__(name: str):
    # SensorSimulator lives in its own module, which imports this one: resolved on first use, so either module
    # can be imported first (a spawned worker unpickling the simulator's chunk function imports that one first)
    if name == "SensorSimulator":
        from .sensor_simulator import SensorSimulator

        return SensorSimulator
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
