"""The sensor design: a frozen, validated description of the layered lattice sensor.

Coordinates (mm): the sensor occupies ``[0, L] x [0, L] x [0, H]`` with ``z = 0`` the fixed bottom face and
``z = H`` the touched top surface. From the bottom: silicone substrate ``[0, s]``, conductive layer
``[s, s + t]`` (hydrogel lattice plus silicone islands), silicone sealing ``[s + t, H]`` with
``s = H - sealing - t``.

The conductive layer is a 2D layout of hydrogel polygons (:mod:`latticeopt.layout`: the ``square``,
``hexagonal``, ``triangular`` and ``diagonal`` families, or ``custom`` polygons) extruded through ``t``.
``w = 0`` means no lattice: the whole conductive layer is hydrogel. The rim is a design parameter: ``rim =
"none"`` (default) leaves the band along the sensor's sides silicone, so the channels end on the electrodes;
``rim = "channel"`` runs a half-width hydrogel channel round the rim, which shunts current between
neighbouring electrodes (see the README for what it does to ``V_rel``); ``frame_mm`` insets the lattice by a
silicone border.

Electrodes: ``n_electrodes / 4`` per side on the side walls of the conductive layer, centred at
``electrode_positions_mm`` along each side (measured counter-clockwise from the side's first corner; default
``(k + 1/2) L / (n / 4)``), ``electrode_width_mm`` wide and ``t`` high. Numbered counter-clockwise seen from
above starting with electrode 1 on the side ``y = 0`` at the smallest ``x``; arrays in the API are 0-based
(index 0 is electrode 1). Every electrode must touch hydrogel.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from dataclasses import dataclass

import numpy as np

from . import _validate as v
from . import layout as _layout
from .errors import ParameterError
from .layout import PATTERNS, RIMS  # noqa: F401 (PATTERNS: re-exported for the CLI and the optimizer)
from .layout_files import polygons_from_geometry, read_layout

#: Most channel pitches across the sensor.
MAX_PITCHES = 200

#: Narrowest channel (mm): below it a layout is no longer castable, and meshes of it degenerate.
MIN_WIDTH_MM = 0.05

#: Region ids used for tet labels everywhere (meshes, VTU cell data, mechanics materials).
REGION_IDS = {"substrate": 0, "hydrogel": 1, "islands": 2, "sealing": 3}
REGION_NAMES = {i: n for n, i in REGION_IDS.items()}


@dataclass(frozen=True)
class LatticeDesign:
    """Geometry of one lattice sensor (all lengths in mm).

    Parameters
    ----------
    width_mm
        Hydrogel channel width ``w``; 0 means a uniform hydrogel layer, else ``MIN_WIDTH_MM <= w < pitch_mm``
        (``< 2/3 pitch_mm`` for ``triangular``).
    thickness_mm
        Conductive-layer thickness ``t``; ``0 < t <= total_thickness_mm - sealing_mm``.
    pitch_mm
        Distance ``p`` between the centre lines of the channels on either side of an island (default 12.5 mm
        puts a channel end under every electrode centre of the default square layout).
    pattern
        Layout family; one of :data:`~latticeopt.layout.FAMILIES`. ``"custom"`` takes its hydrogel
        from ``custom_polygons_mm`` and ignores ``width_mm`` and ``pitch_mm``.
    size_mm
        Side ``L`` of the square sensor.
    total_thickness_mm
        Stack thickness ``H`` (kept constant while ``t`` varies; the substrate takes up the rest).
    sealing_mm
        Silicone sealing layer on top of the conductive layer.
    n_electrodes
        Number of rim electrodes, a multiple of 4 (equal count per side).
    electrode_width_mm
        Width of each electrode along its side wall; its height is ``t``.
    rim
        ``"none"`` (default: the rim band is silicone; channels end on the electrodes) or ``"channel"`` (a
        ``w / 2`` hydrogel channel along the lattice's outer boundary).
    frame_mm
        Width of a silicone border round the lattice (0: none); leads cross it to the electrodes.
    electrode_leads
        Join an electrode that no channel reaches to the nearest channel by a straight lead of width ``w``
        (parametric families only). False: such a layout is rejected.
    electrode_positions_mm
        Electrode centres along each side (mm from the side's first corner, counter-clockwise), the same on
        every side, increasing; None: evenly spaced. Their number must be ``n_electrodes / 4``.
    custom_polygons_mm
        ``pattern = "custom"`` only: hydrogel polygons as ``((shell, *holes), ...)`` rings of ``(x, y)``
        points (mm), e.g. from :func:`latticeopt.layout_files.read_layout` (GeoJSON or DXF).
    """

    width_mm: float = 4.0
    thickness_mm: float = 3.0
    pitch_mm: float = 12.5
    pattern: str = "square"
    size_mm: float = 100.0
    total_thickness_mm: float = 9.0
    sealing_mm: float = 2.0
    n_electrodes: int = 16
    electrode_width_mm: float = 4.0
    rim: str = "none"
    frame_mm: float = 0.0
    electrode_leads: bool = True
    electrode_positions_mm: tuple | None = None
    custom_polygons_mm: tuple = ()

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "pattern", v.choice("pattern", self.pattern, tuple(_layout.FAMILIES)))
        set_(self, "rim", v.choice("rim", self.rim, RIMS))
        if self.electrode_leads not in (True, False):
            raise ParameterError("electrode_leads", "true or false", self.electrode_leads)
        set_(self, "size_mm", v.real("size_mm", self.size_mm, lo=0, lo_open=True, hi=1e4))
        set_(self, "total_thickness_mm",
             v.real("total_thickness_mm", self.total_thickness_mm, lo=0, lo_open=True))
        set_(self, "sealing_mm", v.real("sealing_mm", self.sealing_mm, lo=0,
                                        hi=self.total_thickness_mm, hi_open=True))
        set_(self, "pitch_mm", v.real("pitch_mm", self.pitch_mm, lo=0, lo_open=True, hi=self.size_mm))
        if self.size_mm / self.pitch_mm > MAX_PITCHES:  # a layout of more cells than that is no sensor, and slow
            raise ParameterError("pitch_mm", f"at least size_mm / {MAX_PITCHES} = {self.size_mm / MAX_PITCHES:g} mm",
                                 self.pitch_mm)
        room = self.total_thickness_mm - self.sealing_mm
        set_(self, "thickness_mm", v.real(
            "thickness_mm", self.thickness_mm, lo=0, lo_open=True, hi=room,
            expected=f"0 < thickness_mm <= total_thickness_mm - sealing_mm = {room:g} mm "
                     "(the substrate may not be negative)"))
        family = _layout.FAMILIES[self.pattern]
        w_max = family.max_width_fraction * self.pitch_mm
        expected = (f"0 (no lattice) or {MIN_WIDTH_MM:g} <= width_mm < {family.max_width_text} = {w_max:g} mm"
                    if family.parametric else f"0 or at least {MIN_WIDTH_MM:g} mm")
        w = v.real("width_mm", self.width_mm, expected=expected)
        if (w != 0 and w < MIN_WIDTH_MM) or w < 0 or w >= w_max:
            raise ParameterError("width_mm", expected, self.width_mm)
        set_(self, "width_mm", w)
        set_(self, "frame_mm", v.real("frame_mm", self.frame_mm, lo=0, hi=self.size_mm / 4,
                                      expected=f"0 <= frame_mm <= size_mm / 4 = {self.size_mm / 4:g} mm"))
        n = v.integer("n_electrodes", self.n_electrodes, lo=4,
                      expected="a positive multiple of 4 (equal count per side)")
        if n % 4:
            raise ParameterError("n_electrodes", "a positive multiple of 4 (equal count per side)", n)
        set_(self, "n_electrodes", n)
        spacing = self.size_mm / (n // 4)
        set_(self, "electrode_width_mm", v.real(
            "electrode_width_mm", self.electrode_width_mm, lo=0, lo_open=True, hi=spacing,
            expected=f"0 < electrode_width_mm <= side / electrodes per side = {spacing:g} mm"))
        set_(self, "electrode_positions_mm", self._checked_positions())
        if self.pattern == "custom":
            if not self.custom_polygons_mm:
                raise ParameterError("custom_polygons_mm", "hydrogel polygons for pattern = 'custom' "
                                     "(--layout FILE.geojson or FILE.dxf)", self.custom_polygons_mm)
            gel = _layout.validate_polygons(self.custom_polygons_mm, self.size_mm)
            set_(self, "custom_polygons_mm", polygons_from_geometry(gel))
        elif self.custom_polygons_mm:
            raise ParameterError("custom_polygons_mm", "no polygons unless pattern = 'custom'",
                                 f"{len(self.custom_polygons_mm)} polygon(s) with pattern = {self.pattern!r}")
        else:
            set_(self, "custom_polygons_mm", ())  # one canonical empty value: [] from a file equals ()
        _layout.check_electrodes(self.footprint(), self.electrodes(), self.size_mm,
                                 name="custom_polygons_mm" if self.pattern == "custom" else "layout")

    def _checked_positions(self) -> tuple | None:
        pos = self.electrode_positions_mm
        if pos is None:
            return None
        per, L, ew = self.n_electrodes // 4, self.size_mm, self.electrode_width_mm
        expected = (f"{per} increasing electrode centres per side (n_electrodes / 4), each in "
                    f"[{ew / 2:g}, {L - ew / 2:g}] mm, at least electrode_width_mm = {ew:g} mm apart")
        try:
            arr = np.asarray(pos, dtype=float)
        except (TypeError, ValueError):
            raise ParameterError("electrode_positions_mm", expected, pos) from None
        if (arr.shape != (per,) or not np.all(np.isfinite(arr)) or np.any(arr < ew / 2 - 1e-12)
                or np.any(arr > L - ew / 2 + 1e-12) or np.any(np.diff(arr) < ew - 1e-12)):
            raise ParameterError("electrode_positions_mm", expected, pos)
        return tuple(float(x) for x in arr)
    # -- derived geometry -------------------------------------------------------------------------
    @property
    def substrate_mm(self) -> float:
        """Thickness of the silicone substrate below the conductive layer."""
        return max(self.total_thickness_mm - self.sealing_mm - self.thickness_mm, 0.0)

    @property
    def layer_z_mm(self) -> tuple[float, float]:
        """``(z_bottom, z_top)`` of the conductive layer."""
        z0 = self.substrate_mm
        return z0, z0 + self.thickness_mm

    @property
    def has_lattice(self) -> bool:
        """False for the uniform layer (``w = 0`` of a parametric family)."""
        return self.pattern == "custom" or self.width_mm > 0

    @property
    def electrode_centres_mm(self) -> np.ndarray:
        """Electrode centres along each side (mm from the side's first corner), shape ``(n_electrodes / 4,)``."""
        if self.electrode_positions_mm is not None:
            return np.asarray(self.electrode_positions_mm, dtype=float)
        per = self.n_electrodes // 4
        return (np.arange(per) + 0.5) * self.size_mm / per

    def line_positions_mm(self) -> np.ndarray:
        """``square`` pattern: channel centre-line coordinates (same along x and y), shape ``(n_lines,)``."""
        return _layout.square_lines_mm(self.size_mm, self.pitch_mm, self.rim)

    def channel_intervals_mm(self) -> np.ndarray:
        """``square`` pattern without frame: merged hydrogel intervals along one axis, shape ``(k, 2)``.

        Empty for ``w = 0`` (the whole layer is hydrogel then; see :attr:`has_lattice`).
        """
        if not self.has_lattice or self.pattern != "square":
            return np.zeros((0, 2))
        h = self.width_mm / 2
        lines = self.line_positions_mm()
        raw = np.clip(np.stack([lines - h, lines + h], 1), 0.0, self.size_mm)
        merged: list[list[float]] = []
        for a, b in raw:
            if merged and a <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        return np.asarray(merged)

    @functools.cached_property
    def _footprint(self):
        L = self.size_mm
        if self.pattern == "custom":
            return _layout.validate_polygons(self.custom_polygons_mm, L)
        gel = _layout.parametric_footprint(self.pattern, L, self.width_mm, self.pitch_mm, self.rim, self.frame_mm)
        if self.electrode_leads and self.has_lattice:
            gel = _layout.add_leads(gel, self.electrodes(), self.width_mm, L)
        return gel

    def footprint(self):
        """The hydrogel polygons of the conductive layer (a shapely ``MultiPolygon``, mm)."""
        return self._footprint

    @property
    def is_axis_aligned(self) -> bool:
        """True when every edge of the layout is parallel to x or y (the grid mesher's condition)."""
        import shapely

        geom = self.footprint()
        if geom.is_empty:
            return True
        for ring in shapely.get_rings(geom):
            d = np.diff(np.asarray(ring.coords), axis=0)
            if not np.all((np.abs(d[:, 0]) < 1e-9) | (np.abs(d[:, 1]) < 1e-9)):
                return False
        return True

    def hydrogel_area_fraction(self) -> float:
        """Fraction of the conductive layer's footprint that is hydrogel."""
        if not self.has_lattice:
            return 1.0
        return float(self.footprint().area) / self.size_mm ** 2

    def region_volumes_mm3(self) -> dict[str, float]:
        """Analytic volume of every region (mm^3): polygon area x layer thickness for the hydrogel."""
        area = self.size_mm ** 2
        gel = self.hydrogel_area_fraction() * area * self.thickness_mm
        return {"substrate": area * self.substrate_mm,
                "hydrogel": gel,
                "islands": area * self.thickness_mm - gel,
                "sealing": area * self.sealing_mm}

    def region_at(self, points_mm: np.ndarray) -> np.ndarray:
        """Region id (:data:`REGION_IDS`) of each point, shape ``(n,)`` for ``points_mm`` of shape ``(n, 3)``.

        Points exactly on an interface go to the region below / the hydrogel; use centroids.
        """
        import shapely

        p = np.asarray(points_mm, dtype=float)
        z0, z1 = self.layer_z_mm
        out = np.full(len(p), REGION_IDS["islands"], dtype=np.int8)
        out[p[:, 2] < z0] = REGION_IDS["substrate"]
        out[p[:, 2] > z1] = REGION_IDS["sealing"]
        in_layer = (p[:, 2] >= z0) & (p[:, 2] <= z1)
        if not self.has_lattice:
            out[in_layer] = REGION_IDS["hydrogel"]
            return out
        geom = self.footprint()
        shapely.prepare(geom)
        idx = np.nonzero(in_layer)[0]
        gel = shapely.intersects_xy(geom, p[idx, 0], p[idx, 1])
        out[idx[gel]] = REGION_IDS["hydrogel"]
        return out

    def electrodes(self) -> np.ndarray:
        """Electrode rectangles, one row per electrode in numbering order, shape ``(n_electrodes, 8)``.

        Columns: centre ``x, y, z`` (mm), outward normal ``nx, ny`` (the wall's), tangent axis
        (0 = along x, 1 = along y), width (mm), height (mm).
        """
        L, c = self.size_mm, self.electrode_centres_mm
        z0, z1 = self.layer_z_mm
        zc, ht, ew = (z0 + z1) / 2, self.thickness_mm, self.electrode_width_mm
        rows = []
        for s in c:  # side y = 0, x increasing
            rows.append([s, 0.0, zc, 0, -1, 0, ew, ht])
        for s in c:  # side x = L, y increasing
            rows.append([L, s, zc, 1, 0, 1, ew, ht])
        for s in c:  # side y = L, x decreasing
            rows.append([L - s, L, zc, 0, 1, 0, ew, ht])
        for s in c:  # side x = 0, y decreasing
            rows.append([0.0, L - s, zc, -1, 0, 1, ew, ht])
        return np.asarray(rows, dtype=float)

    # -- identity ---------------------------------------------------------------------------------
    def as_dict(self) -> dict:
        """The fields as JSON-ready values (tuples become lists)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    def content_hash(self) -> str:
        """SHA-256 of the canonical JSON of the fields (stable across machines and runs)."""
        return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()

    def replace(self, **changes) -> LatticeDesign:
        """A validated copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def describe(self) -> str:
        if not self.has_lattice:
            kind = "uniform layer"
        elif self.pattern == "custom":
            kind = f"custom layout ({len(self.custom_polygons_mm)} polygons, {self.hydrogel_area_fraction():.0%} gel)"
        else:
            kind = f"{self.pattern} lattice w = {self.width_mm:g} mm, p = {self.pitch_mm:g} mm, rim {self.rim}"
            if self.frame_mm:
                kind += f", frame {self.frame_mm:g} mm"
        return f"{kind}, t = {self.thickness_mm:g} mm, {self.size_mm:g} x {self.size_mm:g} x " \
               f"{self.total_thickness_mm:g} mm, {self.n_electrodes} electrodes"


DESIGN_FIELDS = tuple(f.name for f in dataclasses.fields(LatticeDesign))

#: Keys a study table (or the CLI) may give besides the fields: ``layout`` (a GeoJSON file of hydrogel
#: polygons, which makes the pattern ``custom``) and ``hydrogel_fraction`` (the channel width is solved so that
#: this fraction of the layer is hydrogel: layouts compared at equal gel). ``custom_polygons_mm`` comes from
#: ``layout`` only.
TABLE_KEYS = tuple(f for f in DESIGN_FIELDS if f != "custom_polygons_mm") + ("layout", "hydrogel_fraction")


def width_for_fraction(design: LatticeDesign, fraction: float) -> LatticeDesign:
    """``design`` with the channel width that makes ``fraction`` of the conductive layer hydrogel.

    The fraction grows with ``w`` for every parametric family; it is solved by bracketing (Brent) to 1e-9 mm.
    A fraction outside what the family can reach at this pitch is a :class:`ParameterError`.
    """
    from scipy.optimize import brentq

    fraction = v.real("hydrogel_fraction", fraction, lo=0, hi=1, lo_open=True, hi_open=True)
    family = _layout.FAMILIES[design.pattern]
    if not family.parametric:
        raise ParameterError("hydrogel_fraction", "a parametric pattern (a custom layout's gel is fixed)",
                             design.pattern)
    w_max = family.max_width_fraction * design.pitch_mm * (1 - 1e-9)
    lo, hi = (design.replace(width_mm=w).hydrogel_area_fraction() for w in (MIN_WIDTH_MM, w_max))
    if not lo <= fraction <= hi:
        raise ParameterError("hydrogel_fraction", f"a fraction the {design.pattern} pattern reaches at pitch "
                             f"{design.pitch_mm:g} mm: {lo:.4g} to {hi:.4g}", fraction)
    w = brentq(lambda w: design.replace(width_mm=w).hydrogel_area_fraction() - fraction, MIN_WIDTH_MM, w_max,
               xtol=1e-9)
    return design.replace(width_mm=float(w))


def design_from_table(table: dict, base_dir: str | None = None) -> LatticeDesign:
    """A design from a table of :data:`TABLE_KEYS` (a study's ``[design]`` merged with a grid point).

    ``layout`` paths are relative to ``base_dir`` (the study file's folder). Errors name the table key.
    """
    from pathlib import Path

    values = dict(table)
    unknown = sorted(set(values) - set(TABLE_KEYS))
    if unknown:
        raise ParameterError(unknown[0], "a known design key: one of " + ", ".join(TABLE_KEYS), unknown[0])
    if "layout" in values:
        path = Path(str(values.pop("layout")))
        if base_dir is not None and not path.is_absolute():
            path = Path(base_dir) / path
        if values.get("pattern", "custom") != "custom":
            raise ParameterError("pattern", "custom (or nothing) with a layout file", values["pattern"])
        values.update(pattern="custom", custom_polygons_mm=read_layout(path, name="layout"))
    fraction = values.pop("hydrogel_fraction", None)
    if fraction is None:
        return LatticeDesign(**values)
    if "width_mm" in values:
        raise ParameterError("hydrogel_fraction", "either hydrogel_fraction or width_mm, not both",
                             f"hydrogel_fraction = {fraction!r}, width_mm = {values['width_mm']!r}")
    return width_for_fraction(LatticeDesign(**values, width_mm=MIN_WIDTH_MM), fraction)
