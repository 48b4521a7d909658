"""latticeopt: design lattice-patterned soft EIT tactile sensors by coupled 3D simulation.

Data flow (see the README): :class:`LatticeDesign` -> region solids (:mod:`latticeopt.geometry`) ->
labelled :class:`TetMesh` (:func:`mesh_design`) -> mechanics -> electrics -> ``V_rel``.
"""

from .design import REGION_IDS, LatticeDesign
from .errors import ConvergenceError, LatticeoptError, MeshError, ParameterError
from .mesh import MeshSettings, TetMesh, mesh_design

__version__ = "0.1.0"

__all__ = [
    "REGION_IDS", "ConvergenceError", "LatticeDesign", "LatticeoptError", "MeshError", "MeshSettings",
    "ParameterError", "TetMesh", "mesh_design", "__version__",
]
