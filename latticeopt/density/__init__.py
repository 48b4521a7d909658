"""Density layouts of the conductive layer and adjoint gradients through the coupled model.

:mod:`.field` (file format, material interpolation, parametric layouts as densities), :mod:`.mesh` (the fixed mesh
and the cell map), :mod:`.model` (:class:`DensityModel`: V_rel, force, stretch and their gradients),
:mod:`.connectivity` (:class:`CellNetwork`: how far apart a layout puts its electrodes, the isolation bound).
"""

from .connectivity import CellNetwork
from .field import (
    InterpolationLaw,
    check_density,
    density_of_design,
    load_density,
    parameter_gradient,
    save_density,
)
from .model import DensityEvaluation, DensityModel, PressResult

__all__ = ["CellNetwork", "DensityEvaluation", "DensityModel", "InterpolationLaw", "PressResult", "check_density",
           "density_of_design", "load_density", "parameter_gradient", "save_density"]
