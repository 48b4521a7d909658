"""Figure captions: which layout and which mesh a figure shows, in words a reader of the figure alone can follow.

Every figure the package writes names the layout (lattice family, pitch, whether a hydrogel channel runs round
the rim), the mesh and how many phantoms (presses, targets) its values are over; these helpers give the first
two the same wording everywhere.
"""

from __future__ import annotations

import textwrap
from collections.abc import Iterable, Mapping

from .design import LatticeDesign

__all__ = ["counted", "layout_caption", "mesh_caption", "wrap_title"]


def _join(values: Iterable) -> str:
    return "/".join(f"{v:g}" if isinstance(v, float) else str(v) for v in dict.fromkeys(values))


def counted(n: int, noun: str) -> str:
    """``n`` and ``noun``, plural unless ``n == 1``: ``counted(1, "design")`` is ``"1 design"``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def layout_caption(designs: Iterable[LatticeDesign], thickness: bool = True) -> str:
    """The layout of ``designs`` in words, e.g. ``square lattice (p = 12.5 mm) and uniform layer, no rim channel``.

    A thickness shared by every design is named too (a varied one is on the figure's axis or legend), unless
    ``thickness`` is false (a figure whose axis is the thickness).

    >>> from latticeopt.design import LatticeDesign
    >>> layout_caption([LatticeDesign(width_mm=4, rim="channel")])
    'square lattice (p = 12.5 mm), rim channel, t = 3 mm'
    >>> layout_caption([LatticeDesign(width_mm=0, thickness_mm=1), LatticeDesign(width_mm=2, thickness_mm=3)])
    'square lattice (p = 12.5 mm) and uniform layer, no rim channel'
    """
    designs = list(designs)
    lattices = [d for d in designs if d.has_lattice]
    shared = {d.thickness_mm for d in designs}
    t = f", t = {shared.pop():g} mm" if len(shared) == 1 and thickness else ""  # a varied one is on an axis
    if not lattices:
        return "uniform layer" + t
    custom = [d for d in lattices if d.pattern == "custom"]
    parts = []
    families = [d for d in lattices if d.pattern != "custom"]
    if families:
        patterns = list(dict.fromkeys(d.pattern for d in families))
        parts.append(f"{'/'.join(patterns)} lattice{'s' if len(patterns) > 1 else ''} "
                     f"(p = {_join(d.pitch_mm for d in families)} mm)")
    if custom:
        parts.append("custom layout")
    text = " and ".join(parts) + (" and uniform layer" if len(lattices) < len(designs) else "")
    rims = set(d.rim for d in lattices)
    rim = {frozenset({"none"}): "no rim channel", frozenset({"channel"}): "rim channel"}.get(
        frozenset(rims), "without and with the rim channel")
    text += f", {rim}"
    frames = [d.frame_mm for d in lattices if d.frame_mm]
    if frames:
        text += f", frame {_join(frames)} mm"
    return text + t


def mesh_caption(settings: Mapping) -> str:
    """A resolved mesh (``MeshSettings.resolved(design).as_dict()``) in words, e.g. ``grid mesh, 2 mm, 2 cells
    across a channel, 2 through the layer``.

    >>> mesh_caption({"mesher": "grid", "size_mm": 2.0, "channel_cells": 2, "layer_cells": 2})
    'grid mesh, 2 mm, 2 cells across a channel, 2 through the layer'
    """
    text = f"{settings.get('mesher', 'auto')} mesh, {settings['size_mm']:g} mm"
    if settings.get("mesher") in ("grid", "extruded"):
        cells = settings.get("channel_cells")
        text += f", {cells} cell{'s' if cells != 1 else ''} across a channel, {settings.get('layer_cells')} through " \
                "the layer"
    return text


def wrap_title(text: str, width: int = 70) -> str:
    """Each line of ``text`` wrapped to ``width`` characters (a long title line is otherwise cut at the edges of
    the figure)."""
    return "\n".join(textwrap.fill(line, width) for line in text.splitlines())
