"""From a density layout to outlines a mould can be made from: threshold, drop gel that reaches no electrode,
smooth and simplify, then GeoJSON and DXF that ``--layout`` reads and the exact meshers mesh.

>>> import numpy as np
>>> from latticeopt import LatticeDesign
>>> from latticeopt.density import density_of_design
>>> design = LatticeDesign(width_mm=4, thickness_mm=3)
>>> geom, report = density_outline(design, density_of_design(design, 200))   # 0.5 mm cells: exact
>>> report["pieces_dropped"], round(report["hydrogel_fraction"], 3)
(0, 0.482)
"""

from __future__ import annotations

import numpy as np

from .. import _validate as v
from ..layout import electrode_contact_mm
from .field import check_density


def density_outline(design, density: np.ndarray, threshold: float = 0.5, smooth_mm: float = 0.0,
                    simplify_mm: float = 0.05) -> tuple[object, dict]:
    """Hydrogel polygons (shapely, mm) of a density layout.

    Cells with ``density >= threshold`` are gel; pieces of gel that touch no electrode are dropped (their
    potential would float: the conforming model rejects them, and they sense nothing); ``smooth_mm > 0`` rounds
    the staircase of cells by a morphological closing then opening of that radius; ``simplify_mm`` first removes
    vertices closer than that to the outline (the staircase's collinear ones).

    Returns
    -------
    geometry, report
        The footprint and a dict: ``hydrogel_fraction``, ``pieces``, ``pieces_dropped``, ``dropped_area_mm2``.
    """
    import shapely

    d = check_density(density)
    threshold = v.real("threshold", threshold, lo=0.0, lo_open=True, hi=1.0)
    smooth_mm = v.real("smooth_mm", smooth_mm, lo=0.0)
    n, L = d.shape[0], design.size_mm
    iy, ix = np.nonzero(d >= threshold)
    h = L / n
    square = shapely.box(0.0, 0.0, L, L)
    geom = shapely.union_all(shapely.box(ix * h, iy * h, (ix + 1) * h, (iy + 1) * h)) if len(ix) else shapely.Polygon()
    if simplify_mm > 0 and not geom.is_empty:  # before the smoothing: afterwards it would cut the rim's corners
        geom = geom.simplify(simplify_mm)
    if smooth_mm > 0 and not geom.is_empty:
        # two segments per quarter circle: rounded enough for a mould, and no tiny edges for the mesher to resolve
        geom = geom.buffer(smooth_mm, quad_segs=2).buffer(-2 * smooth_mm, quad_segs=2).buffer(smooth_mm, quad_segs=2)
        # round-off leaves the rim edges a hair inside the square, off the electrodes: snap to a 1 nm grid
        geom = shapely.set_precision(geom.intersection(square), 1e-6)
    electrodes = design.electrodes()
    pieces = list(shapely.get_parts(geom)) if not geom.is_empty else []
    kept = [p for p in pieces if np.any(electrode_contact_mm(p, electrodes) > 1e-9)]
    out = shapely.union_all(kept) if kept else shapely.Polygon()
    report = {"hydrogel_fraction": float(out.area / L ** 2), "pieces": len(kept),
              "pieces_dropped": len(pieces) - len(kept),
              "dropped_area_mm2": float(sum(p.area for p in pieces) - out.area)}
    return out, report
