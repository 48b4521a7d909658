"""Electrics: steady current flow in the (deformed) hydrogel with rim electrodes.

>>> from latticeopt import LatticeDesign, MeshSettings, mesh_design
>>> from latticeopt.electrics import ForwardModel, Protocol
>>> mesh = mesh_design(LatticeDesign(), MeshSettings(size_mm=6), cache_dir=False)
>>> model = ForwardModel(mesh)                      # the full TetMesh or its hydrogel sub-mesh
>>> model.voltages.shape
(208,)
>>> Protocol.adjacent(16).n_rows
208

* :class:`Protocol` - drive/measurement patterns (pyEIT "std" order by default, reciprocity bookkeeping).
* :class:`ForwardModel` - complete electrode model (or point electrodes), assembled and factorized once;
  voltages, potentials, current density, adjoint Jacobian, pixel Jacobian, cheap re-solves for new
  conductivities (:meth:`ForwardModel.with_conductivity`) or moved nodes (:meth:`ForwardModel.with_nodes`).
* :mod:`latticeopt.electrics.fields` - VTU export and field pictures (imports matplotlib/pyvista lazily).
"""

from .forward import (
    DEFAULT_CONTACT_IMPEDANCE_OHM_M2,
    DEFAULT_CURRENT_A,
    DEFAULT_SIGMA_S_PER_M,
    ELECTRODE_MODES,
    ForwardModel,
)
from .pixels import pixel_matrix
from .protocol import Protocol

__all__ = [
    "DEFAULT_CONTACT_IMPEDANCE_OHM_M2", "DEFAULT_CURRENT_A", "DEFAULT_SIGMA_S_PER_M", "ELECTRODE_MODES",
    "ForwardModel", "Protocol", "pixel_matrix",
]
