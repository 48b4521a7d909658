"""What a mould has to make: the narrowest hydrogel and silicone features of a layout, measured on its footprint.

A lattice's channel width ``w`` and island width ``p - w`` hold in the sensor's interior. Where the sensor's
edge clips the pattern they need not: a honeycomb cell whose side runs a fraction of a millimetre inside the
edge leaves a gel strip that thin between it and the wall, a clipped island corner leaves a silicone sliver.
This module measures both on the laid-out footprint (shapely), for any layout:

* the narrowest **gel** feature is the smallest gap between two silicone bodies that do not touch, the four
  walls of the sensor counting as bodies (so a gel strip between an island and the wall is a channel);
* the narrowest **silicone** feature is the smallest island's largest inscribed circle (diameter).

Example
-------
>>> from latticeopt import LatticeDesign
>>> from latticeopt.fabrication import narrowest_features
>>> f = narrowest_features(LatticeDesign(width_mm=4).footprint(), 100.0)
>>> round(f.gel_mm, 6), round(f.silicone_mm, 3)    # the square lattice: w and p - w
(4.0, 8.5)
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from .errors import ParameterError

__all__ = ["TOLERANCE_MM", "Features", "castable_widths", "narrowest_features", "spans_text"]

#: Accuracy of the measured widths (mm): the inscribed circles' tolerance. A feature breaks a limit only when it
#: is narrower by more than this, so a lattice at its bound (an island of exactly ``min_island_mm``) passes.
TOLERANCE_MM = 1e-3


@dataclass(frozen=True)
class Features:
    """The narrowest gel and silicone features of a layout (mm) and where they are (``(x, y)`` in mm, or
    ``None`` when the layout has no such feature: ``inf`` then)."""

    gel_mm: float
    gel_at: tuple[float, float] | None
    silicone_mm: float
    silicone_at: tuple[float, float] | None

    def describe(self) -> str:
        """``"narrowest gel X mm, narrowest silicone Y mm"`` (3 significant digits), as the reports print it."""
        return f"narrowest gel {self.gel_mm:.3g} mm, narrowest silicone {self.silicone_mm:.3g} mm"

    def below(self, min_channel_mm: float, min_island_mm: float,
              keys: tuple[str, str] = ("min_channel_mm", "min_island_mm")) -> list[str]:
        """One phrase per limit the layout breaks (narrower by more than :data:`TOLERANCE_MM`), naming the
        feature, its width and place, and the limit's key (``keys``: the gel's, the silicone's); empty if none."""
        out = []
        for what, width, at, key, limit in (("gel", self.gel_mm, self.gel_at, keys[0], min_channel_mm),
                                            ("silicone", self.silicone_mm, self.silicone_at, keys[1],
                                             min_island_mm)):
            if width < limit - TOLERANCE_MM:
                out.append(f"{what} {width:.3g} mm wide at ({at[0]:.4g}, {at[1]:.4g}) mm < {key} = {limit:g}")
        return out


def narrowest_features(footprint, size_mm: float, tolerance_mm: float = TOLERANCE_MM) -> Features:
    """The narrowest gel and silicone features of the hydrogel ``footprint`` in the ``size_mm`` square.

    Parameters
    ----------
    footprint : shapely geometry
        The hydrogel polygons (mm), as :meth:`LatticeDesign.footprint` gives them.
    size_mm : float
        The sensor's side ``L``; the walls are the square's four sides.
    tolerance_mm : float
        Accuracy of the inscribed circles; bodies closer than ``1e-9 L`` count as touching (no gel between).

    Returns
    -------
    Features
    """
    import shapely
    from shapely.ops import nearest_points

    L = float(size_mm)
    square = shapely.box(0.0, 0.0, L, L)
    silicone = square.difference(footprint)
    islands = [g for g in getattr(silicone, "geoms", [silicone]) if g.area > 1e-12 * L * L]
    walls = [shapely.box(-1.0, 0.0, 0.0, L), shapely.box(L, 0.0, L + 1.0, L), shapely.box(0.0, -1.0, L, 0.0),
             shapely.box(0.0, L, L, L + 1.0)]
    bodies = islands + walls
    gel, gel_at = math.inf, None
    tree = shapely.STRtree(bodies)
    for i, body in enumerate(bodies):
        # only bodies closer than the best gap so far can set a new one
        reach = gel if math.isfinite(gel) else L
        for j in tree.query(body, predicate="dwithin", distance=reach):
            if j <= i or (i >= len(islands) and j >= len(islands)):
                continue  # each pair once; two walls have no gel between them
            gap = body.distance(bodies[j])
            if 1e-9 * L < gap < gel:
                a, b = nearest_points(body, bodies[j])
                gel, gel_at = gap, ((a.x + b.x) / 2, (a.y + b.y) / 2)
    sil, sil_at = math.inf, None
    for island in islands:
        radius = shapely.maximum_inscribed_circle(island, tolerance_mm)
        if 2 * radius.length < sil:
            c = radius.coords[0]
            sil, sil_at = 2 * radius.length, (c[0], c[1])
    return Features(gel, gel_at, sil, sil_at)


def castable_widths(design, lower_mm: float, upper_mm: float, min_channel_mm: float, min_island_mm: float,
                    step_mm: float = 0.1) -> list[tuple[float, float]]:
    """The channel widths of ``design``'s layout (everything else as it is) whose footprint meets both limits
    everywhere, edges included: ``w`` on a ``step_mm`` grid over ``[lower_mm, upper_mm]``, consecutive passing
    widths merged into ``(first, last)`` intervals (:meth:`Features.below`: up to :data:`TOLERANCE_MM` narrower
    passes). A width the design rejects counts as failing.

    The limits of a lattice hold in its interior by its bounds; where the sensor's edge clips the pattern they
    need not, so the castable widths are generally not one interval.

    Examples
    --------
    >>> from latticeopt import LatticeDesign
    >>> castable_widths(LatticeDesign(pattern="hexagonal"), 5.0, 6.0, 1.0, 1.0)
    [(5.4, 5.6)]
    """
    n = int(math.floor((upper_mm - lower_mm) / step_mm + 1e-9))
    out: list[tuple[float, float]] = []
    last_ok = False
    for w in (round(lower_mm + k * step_mm, 9) for k in range(n + 1)):
        try:
            d = dataclasses.replace(design, width_mm=float(w))
        except ParameterError:
            ok = False
        else:
            ok = not narrowest_features(d.footprint(), d.size_mm).below(min_channel_mm, min_island_mm)
        if ok:
            out[-1:] = [(out[-1][0], w)] if last_ok else out[-1:] + [(w, w)]
        last_ok = ok
    return out


def spans_text(spans: list[tuple[float, float]]) -> str:
    """``"1.8-3.5, 5.4"`` for the intervals of :func:`castable_widths`; ``"none"`` for none."""
    return ", ".join(f"{a:g}" if a == b else f"{a:g}-{b:g}" for a, b in spans) or "none"
