"""Touches: rigid round indenters pressed into the top surface, and their validation.

A :class:`Touch` is an indenter of radius ``radius_mm`` centred at ``(x_mm, y_mm)`` on the top surface
``z = H`` and pressed ``depth_mm`` into it. :func:`validate_touches` checks a list of touches against a design
*before any solve*: every indenter fully on the sensor, no two overlapping, every depth below the stack
thickness. Its errors name the touch the way the command line counts them (``touch #1`` for the first;
``--touch #1`` from the CLI, whatever check finds the problem), the parameter, the allowed range and the value
that arrived. The mechanics and the phantom generator both use it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from . import _validate as v
from .errors import ParameterError

TOUCH_FIELDS = ("x_mm", "y_mm", "radius_mm", "depth_mm")


def touch_name(i: int, name: str = "touch") -> str:
    """How errors name the ``i``-th touch (0-based ``i``): ``"touch #1"`` for the first, as a user counts them
    (``name = "--touch"`` in the CLI: ``"--touch #1"``, the first ``--touch`` option)."""
    return f"{name} #{i + 1}"


@dataclass(frozen=True)
class Touch:
    """One rigid round indenter (all lengths in mm).

    Parameters
    ----------
    x_mm, y_mm
        Centre on the top surface (finite).
    radius_mm
        Indenter radius, > 0.
    depth_mm
        Indentation depth, >= 0 (0 leaves the surface untouched).

    Design-dependent limits (on the sensor, below the stack thickness, no overlap) are checked by
    :func:`validate_touches`.
    """

    x_mm: float
    y_mm: float
    radius_mm: float
    depth_mm: float

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "x_mm", v.real("x_mm", self.x_mm))
        set_(self, "y_mm", v.real("y_mm", self.y_mm))
        set_(self, "radius_mm", v.real("radius_mm", self.radius_mm, lo=0, lo_open=True))
        set_(self, "depth_mm", v.real("depth_mm", self.depth_mm, lo=0))

    @classmethod
    def parse(cls, text: str, name: str = "--touch") -> Touch:
        """Parse ``"X,Y,R,D"`` (mm), e.g. ``"50,50,8.75,4"``; errors name ``name``."""
        expected = "X,Y,R,D: four numbers in mm separated by commas, e.g. 50,50,8.75,4"
        parts = [p.strip() for p in str(text).split(",")]
        if len(parts) != 4:
            raise ParameterError(name, expected, text)
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise ParameterError(name, expected, text) from None
        try:
            return cls(*values)
        except ParameterError as exc:
            raise ParameterError(f"{name} {text!r} {exc.name}", exc.expected, exc.got) from None

    def as_dict(self) -> dict:
        return {f: getattr(self, f) for f in TOUCH_FIELDS}


def _as_touch(i: int, t: object, name: str = "touch") -> Touch:
    who = touch_name(i, name)
    if isinstance(t, Touch):
        return t
    try:
        if isinstance(t, dict):
            unknown = sorted(set(t) - set(TOUCH_FIELDS))
            if unknown:
                raise ParameterError(who, f"keys from {list(TOUCH_FIELDS)}", unknown)
            return Touch(**t)
        values = tuple(t)  # type: ignore[arg-type]
    except TypeError:
        raise ParameterError(who, "a Touch, a dict or a sequence (x_mm, y_mm, radius_mm, depth_mm)",
                             t) from None
    except ParameterError as exc:
        raise ParameterError(f"{who} {exc.name}", exc.expected, exc.got) from None
    if len(values) != 4:
        raise ParameterError(who, "four values (x_mm, y_mm, radius_mm, depth_mm)", t)
    try:
        return Touch(*values)
    except ParameterError as exc:
        raise ParameterError(f"{who} {exc.name}", exc.expected, exc.got) from None


def check_touches(touches: Iterable, x_range_mm: tuple[float, float], y_range_mm: tuple[float, float],
                  thickness_mm: float, name: str = "touch") -> tuple[Touch, ...]:
    """Validate touches against a rectangular top surface and a stack thickness (see :func:`validate_touches`)."""
    if isinstance(touches, (Touch, str)):
        raise ParameterError("touches", "a list of touches (use [touch] for one)", touches)
    out = tuple(_as_touch(i, t, name) for i, t in enumerate(touches))
    if not out:
        raise ParameterError("touches", "at least one touch", [])
    x0, x1 = x_range_mm
    y0, y1 = y_range_mm
    for i, t in enumerate(out):
        r = t.radius_mm
        half = 0.5 * min(x1 - x0, y1 - y0)
        if r > half:
            raise ParameterError(f"{touch_name(i, name)} radius_mm",
                                 f"0 < radius_mm <= {half:g} (the indenter must fit on the sensor)", r)
        for field, val, lo, hi in (("x_mm", t.x_mm, x0, x1), ("y_mm", t.y_mm, y0, y1)):
            if not (lo + r <= val <= hi - r):
                raise ParameterError(
                    f"{touch_name(i, name)} {field}",
                    f"{lo + r:g} <= {field} <= {hi - r:g} (radius {r:g} mm: the indenter must lie fully on the "
                    "sensor)", val)
        if not t.depth_mm < thickness_mm:
            raise ParameterError(f"{touch_name(i, name)} depth_mm",
                                 f"0 <= depth_mm < {thickness_mm:g} (the stack thickness)", t.depth_mm)
    for j, b in enumerate(out):
        for i, a in enumerate(out[:j]):
            dist = math.hypot(a.x_mm - b.x_mm, a.y_mm - b.y_mm)
            if dist < a.radius_mm + b.radius_mm:
                raise ParameterError(
                    f"{touch_name(j, name)} (x_mm, y_mm)",
                    f"a centre at least radius sum {a.radius_mm + b.radius_mm:g} mm from {touch_name(i, name)} at "
                    f"({a.x_mm:g}, {a.y_mm:g}) (indenters may not overlap; distance is {dist:.3g} mm)",
                    (b.x_mm, b.y_mm))
    return out


def validate_touches(design, touches: Sequence, name: str = "touch") -> tuple[Touch, ...]:
    """Check touches against a design before any solve.

    Parameters
    ----------
    design : LatticeDesign
        Supplies the sensor side ``size_mm`` and the stack thickness ``total_thickness_mm``.
    touches
        :class:`Touch` objects, dicts with the field names, or sequences ``(x, y, r, d)`` in mm.
    name
        What errors call a touch, numbered from 1: ``"touch"`` gives ``touch #1``; the CLI passes ``"--touch"``.

    Returns
    -------
    tuple of Touch

    Raises
    ------
    ParameterError
        Naming ``touch #k <field>`` (k from 1), the allowed range and the value: non-finite values, radius <= 0,
        depth < 0 or >= the stack thickness, an indenter not fully on the sensor, two indenters overlapping
        (centre distance below the sum of the radii; touching edges are allowed), or no touches at all.
    """
    L = design.size_mm
    return check_touches(touches, (0.0, L), (0.0, L), design.total_thickness_mm, name)
