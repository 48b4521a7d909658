"""Hydrogel conductivity under load: the laws of ``[physics] conductivity_law`` and the kinematics they read.

Laws (``sigma0`` is ``sigma_S_per_m``, the conductivity at rest; ``m`` the measure named by
``conductivity_measure``: ``"thickness"``, the layer's through-thickness stretch ``lambda_t``, default, or
``"J"``, the volume ratio; ``k`` is ``conductivity_k``):

* ``"geometry"`` (default): ``sigma = sigma0`` (``k`` and the measure are not used). The response comes from
  the deformed geometry alone: the gel keeps its conductivity per unit volume while the channels thin, widen
  and move.
* ``"linear"``: ``sigma = sigma0 (1 + k (1 - m))``, linear in the strain ``1 - m`` (positive under a press:
  ``1 - lambda_t`` the thinning, ``1 - J`` the volume lost).
* ``"power"``: ``sigma = sigma0 m^k``. For an ionic gel whose ions stay while its volume changes, with
  unchanged mobility, the conductivity follows the ion concentration, ``1 / J``: the power law in ``J`` with
  ``k = -1`` is that idealisation (more conductive when compressed).

No value of ``k`` is assumed here: ``k = 0`` is the geometry law. To measure it, compress a strip of the gel
between insulating plates at several strains (in seconds, as a press does, for the undrained response), record
its four-probe resistance ``R`` and dimensions, and fit ``sigma / sigma0 = (R0 / R) (L / L0) (A0 / A)``
against the strain measure; or fit ``k`` to presses of a finished sensor with ``latticeopt calibrate --fit
conductivity_k=LO:HI``.

Kinematics consistent with the mechanics: the indentation constrains only the mean dilatation of each patch of
tets (a grid cell or a prism pair, :func:`latticeopt.mechanics.assembly.dilatation_patches`); single tets
inside a patch can reach det F from 0.24 to 1.85 while the patch keeps its volume. A law evaluated per tet
would turn that noise into conductivity, so every measure is a patch average: ``J`` is the patch's deformed
volume over its reference volume (the mechanics' mean dilatation) and ``lambda_t = det Fbar / |Fbar e_x x Fbar
e_y|`` with ``Fbar`` the volume-weighted mean deformation gradient of the patch.

``lambda_t`` is how far apart two neighbouring material planes ``z = const`` end up, over how far apart they
were: the thinning of the layer the current flows along. It is blind to shear (a simple shear in ``x-z`` leaves
it 1) and to rotation. The stretch of a vertical fibre, ``|Fbar e_z|``, is not: it grows as
``sqrt(1 + gamma^2)`` in the shear band under the punch rim, which sharpens as the mesh is refined, and a law in
it changed V_rel by +21 % and then +11 % over two halvings of the cell size where laws in ``lambda_t`` or ``J``
settled to 1-2 % (``benchmarks/convergence_laws.py``; ``docs/verification.md``).
"""

from __future__ import annotations

import numpy as np

from .errors import ModelFailure

__all__ = ["CONDUCTIVITY_LAWS", "CONDUCTIVITY_MEASURES", "LAW_MESH", "ConductivityError", "conductivity_factor",
           "law_mesh_shortfall", "patch_measures"]

CONDUCTIVITY_LAWS = ("geometry", "linear", "power")
#: What ``m`` of a law is (module docstring); the first is the default.
CONDUCTIVITY_MEASURES = ("thickness", "J")


#: The coarsest mesh a law's V_rel was within about 2 % of the next finer one (1 mm, 4 cells): element size
#: (mm) and cells across a channel and through the layer. Laws in J and linear laws in the thickness stretch;
#: the geometry law settles at the default 2 mm / 2 cells, and at that mesh the laws read 9-19 % low
#: (``benchmarks/convergence_laws.py``, ``docs/verification.md``).
LAW_MESH = {"size_mm": 1.4, "channel_cells": 3, "layer_cells": 3}


def law_mesh_shortfall(size_mm: float, channel_cells: int, layer_cells: int) -> list[str]:
    """The ways a resolved mesh is coarser than :data:`LAW_MESH`, as ``"key = value (law needs ...)"`` texts
    (empty when it is fine enough)."""
    got = {"size_mm": size_mm, "channel_cells": channel_cells, "layer_cells": layer_cells}
    return [f"{k} = {got[k]:g} (needs {'<=' if k == 'size_mm' else '>='} {need:g})" for k, need in LAW_MESH.items()
            if (got[k] > need if k == "size_mm" else got[k] < need)]


class ConductivityError(ModelFailure):
    """A conductivity law gave a non-positive or non-finite conductivity for this deformation."""


def _edges(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    x = nodes[tets]
    return np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)  # (M, 3, 3) columns


def patch_measures(ref_nodes_mm: np.ndarray, nodes_mm: np.ndarray, tets: np.ndarray,
                   patch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Patch-averaged volume ratio and through-thickness stretch of the layer, given to every tet of the patch.

    Parameters
    ----------
    ref_nodes_mm, nodes_mm : ndarray, shape (N, 3)
        Reference and deformed node coordinates (mm).
    tets : ndarray of int, shape (M, 4)
        The tets the measures are wanted for (for example the hydrogel tets).
    patch : ndarray of int, shape (M,)
        Patch index of each of those tets.

    Returns
    -------
    J, thickness : ndarray, shape (M,)
        ``sum V_e / sum V0_e`` and ``det Fbar / |Fbar e_x x Fbar e_y|`` of each tet's patch,
        ``Fbar = sum V0_e F_e / sum V0_e``.
    """
    D0, D = _edges(ref_nodes_mm, tets), _edges(nodes_mm, tets)
    vol0, vol = np.linalg.det(D0) / 6.0, np.linalg.det(D) / 6.0
    F = D @ np.linalg.inv(D0)
    _, p = np.unique(patch, return_inverse=True)
    n = p.max() + 1 if len(p) else 0
    v0 = np.bincount(p, np.abs(vol0), minlength=n)
    J = np.bincount(p, vol * np.sign(vol0), minlength=n) / v0
    Fbar = np.stack([np.stack([np.bincount(p, np.abs(vol0) * F[:, i, j], minlength=n) for j in range(3)], axis=1)
                     for i in range(3)], axis=1) / v0[:, None, None]  # (P, 3, 3)
    # the deformed patch's volume per unit deformed area of its material z-plane
    thickness = np.linalg.det(Fbar) / np.linalg.norm(np.cross(Fbar[:, :, 0], Fbar[:, :, 1]), axis=1)
    return J[p], thickness[p]


def conductivity_factor(law: str, measure: str, k: float, J: np.ndarray, thickness: np.ndarray) -> np.ndarray:
    """``sigma / sigma0`` per tet for a law (module docstring); raises :class:`ConductivityError` when it is not
    positive and finite everywhere."""
    if law == "geometry":
        return np.ones_like(J)
    m = J if measure == "J" else thickness
    if law == "linear":
        factor = 1.0 + k * (1.0 - m)
    elif law == "power":
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            factor = np.where(m > 0, np.abs(m) ** k, np.nan)
    else:
        raise ValueError(f"unknown conductivity law {law!r}")
    bad = ~(np.isfinite(factor) & (factor > 0))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ConductivityError(f"conductivity law {law} ({measure}, k = {k:g}) gives sigma / sigma0 = "
                                f"{factor[i]:.3g} in {int(bad.sum())} hydrogel tet(s) (J = {J[i]:.3g}, "
                                f"lambda_t = {thickness[i]:.3g}): the law does not hold this far")
    return factor
