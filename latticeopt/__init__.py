"""latticeopt: design lattice-patterned soft EIT tactile sensors by coupled 3D simulation.

Data flow: :class:`LatticeDesign` -> labelled :class:`TetMesh` (:func:`mesh_design`) -> hyperelastic
indentation by :class:`Touch` es -> 16-electrode current flow on the deformed hydrogel -> ``V_rel``
(:class:`CoupledModel`, :func:`simulate`).

>>> from latticeopt import CoupledModel, LatticeDesign, MeshSettings, Touch
>>> model = CoupledModel(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=6))
>>> result = model.simulate([Touch(50, 50, 8.75, 2.0)])
>>> 0 < result.v_rel < 1
True

The light names (designs, meshes, touches, layouts, errors) are imported with the package; the simulation,
study and sensor-model names (:class:`CoupledModel`, :class:`PhysicsSettings`, :func:`simulate`,
:class:`ForwardModel`, :class:`Protocol`, :func:`load_study`, :func:`study_from_dict`, :func:`run_sweep`,
:func:`export_sensor_model`, :func:`load_sensor_model`) on first use, so ``import latticeopt`` stays
quick and pulls in neither numba nor the solvers.
"""

from __future__ import annotations

import importlib

from .design import REGION_IDS, LatticeDesign
from .errors import (
    AllFailedError,
    ConvergenceError,
    FolderLockedError,
    LatticeoptError,
    MeshError,
    ModelBugError,
    ModelFailure,
    ParameterError,
)
from .layout_files import read_geojson, read_layout, write_geojson
from .mesh import MeshSettings, TetMesh, mesh_design
from .touches import Touch

__version__ = "0.2.0.dev0"

#: Names imported on first access (PEP 562): name -> defining module.
_LAZY = {
    "CoupledModel": "latticeopt.coupled",
    "PhysicsSettings": "latticeopt.coupled",
    "simulate": "latticeopt.coupled",
    "ForwardModel": "latticeopt.electrics.forward",
    "Protocol": "latticeopt.electrics.protocol",
    "load_study": "latticeopt.study.config",
    "study_from_dict": "latticeopt.study.config",
    "run_sweep": "latticeopt.study.sweep",
    "export_sensor_model": "latticeopt.sensor_model",
    "load_sensor_model": "latticeopt.sensor_model",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "REGION_IDS", "AllFailedError", "ConvergenceError", "CoupledModel", "FolderLockedError", "ForwardModel",
    "LatticeDesign", "LatticeoptError", "MeshError", "MeshSettings", "ModelBugError", "ModelFailure",
    "ParameterError", "PhysicsSettings", "Protocol", "TetMesh", "Touch", "__version__", "export_sensor_model",
    "load_sensor_model", "load_study", "mesh_design", "read_geojson", "read_layout", "run_sweep", "simulate",
    "study_from_dict", "write_geojson",
]
