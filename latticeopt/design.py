"""The sensor design: a frozen, validated description of the layered lattice sensor.

Coordinates (mm): the sensor occupies ``[0, L] x [0, L] x [0, H]`` with ``z = 0`` the fixed bottom face and
``z = H`` the touched top surface. From the bottom: silicone substrate ``[0, s]``, conductive layer
``[s, s + t]`` (hydrogel lattice plus silicone islands), silicone sealing ``[s + t, H]`` with
``s = H - sealing - t``.

Square pattern: hydrogel channels of width ``w`` centred on the lines ``x = k p`` and ``y = k p``
(``k = 0, 1, ...`` while ``k p <= L``) plus a rim line at ``L``; channels are clipped to the sensor, so the rim
carries a half-width channel and every side wall of the conductive layer is hydrogel. ``w = 0`` means no
lattice: the whole conductive layer is hydrogel.

Electrodes: ``n_electrodes / 4`` per side on the side walls of the conductive layer, centred at
``(k + 1/2) L / (n / 4)`` along the side, ``electrode_width_mm`` wide and ``t`` high. Numbered
counter-clockwise seen from above starting with electrode 1 on the side ``y = 0`` at the smallest ``x``;
arrays in the API are 0-based (index 0 is electrode 1).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass

import numpy as np

from . import _validate as v
from .errors import ParameterError

PATTERNS = ("square",)

#: Region ids used for tet labels everywhere (meshes, VTU cell data, mechanics materials).
REGION_IDS = {"substrate": 0, "hydrogel": 1, "islands": 2, "sealing": 3}
REGION_NAMES = {i: n for n, i in REGION_IDS.items()}


@dataclass(frozen=True)
class LatticeDesign:
    """Geometry of one lattice sensor (all lengths in mm).

    Parameters
    ----------
    width_mm
        Hydrogel channel width ``w``; 0 means a uniform hydrogel layer, else ``0 < w < pitch_mm``.
    thickness_mm
        Conductive-layer thickness ``t``; ``0 < t <= total_thickness_mm - sealing_mm``.
    pitch_mm
        Distance ``p`` between channel centre lines (default 12.5 mm puts a channel end under every
        electrode centre of the default layout).
    pattern
        Lattice pattern; one of :data:`PATTERNS`.
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

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "pattern", v.choice("pattern", self.pattern, PATTERNS))
        set_(self, "size_mm", v.real("size_mm", self.size_mm, lo=0, lo_open=True))
        set_(self, "total_thickness_mm",
             v.real("total_thickness_mm", self.total_thickness_mm, lo=0, lo_open=True))
        set_(self, "sealing_mm", v.real("sealing_mm", self.sealing_mm, lo=0,
                                        hi=self.total_thickness_mm, hi_open=True))
        set_(self, "pitch_mm", v.real("pitch_mm", self.pitch_mm, lo=0, lo_open=True, hi=self.size_mm))
        room = self.total_thickness_mm - self.sealing_mm
        set_(self, "thickness_mm", v.real(
            "thickness_mm", self.thickness_mm, lo=0, lo_open=True, hi=room,
            expected=f"0 < thickness_mm <= total_thickness_mm - sealing_mm = {room:g} mm "
                     "(the substrate may not be negative)"))
        w = v.real("width_mm", self.width_mm,
                   expected=f"0 (no lattice) or 0 < width_mm < pitch_mm = {self.pitch_mm:g} mm")
        if w < 0 or w >= self.pitch_mm:
            raise ParameterError(
                "width_mm", f"0 (no lattice) or 0 < width_mm < pitch_mm = {self.pitch_mm:g} mm", self.width_mm)
        set_(self, "width_mm", w)
        n = v.integer("n_electrodes", self.n_electrodes, lo=4,
                      expected="a positive multiple of 4 (equal count per side)")
        if n % 4:
            raise ParameterError("n_electrodes", "a positive multiple of 4 (equal count per side)", n)
        set_(self, "n_electrodes", n)
        spacing = self.size_mm / (n // 4)
        set_(self, "electrode_width_mm", v.real(
            "electrode_width_mm", self.electrode_width_mm, lo=0, lo_open=True, hi=spacing,
            expected=f"0 < electrode_width_mm <= side / electrodes per side = {spacing:g} mm"))

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
        return self.width_mm > 0

    def line_positions_mm(self) -> np.ndarray:
        """Channel centre-line coordinates (same along x and y), shape ``(n_lines,)``."""
        k = np.arange(int(np.floor(self.size_mm / self.pitch_mm + 1e-9)) + 1)
        lines = k * self.pitch_mm
        if self.size_mm - lines[-1] > 1e-9 * self.size_mm:
            lines = np.append(lines, self.size_mm)
        return lines

    def channel_intervals_mm(self) -> np.ndarray:
        """Merged hydrogel intervals along one axis inside ``[0, L]``, shape ``(k, 2)``.

        Empty for ``w = 0`` (the whole layer is hydrogel then; see :attr:`has_lattice`).
        """
        if not self.has_lattice:
            return np.zeros((0, 2))
        h = self.width_mm / 2
        raw = np.clip(np.stack([self.line_positions_mm() - h, self.line_positions_mm() + h], 1),
                      0.0, self.size_mm)
        merged: list[list[float]] = []
        for a, b in raw:
            if merged and a <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        return np.asarray(merged)

    def hydrogel_area_fraction(self) -> float:
        """Fraction of the conductive layer's footprint that is hydrogel."""
        if not self.has_lattice:
            return 1.0
        f = float(np.sum(np.diff(self.channel_intervals_mm(), axis=1))) / self.size_mm
        return f * (2.0 - f)  # = 1 - (1 - f)^2 without the cancellation for narrow channels

    def region_volumes_mm3(self) -> dict[str, float]:
        """Analytic volume of every region (mm^3)."""
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
        p = np.asarray(points_mm, dtype=float)
        z0, z1 = self.layer_z_mm
        out = np.full(len(p), REGION_IDS["islands"], dtype=np.int8)
        out[p[:, 2] < z0] = REGION_IDS["substrate"]
        out[p[:, 2] > z1] = REGION_IDS["sealing"]
        in_layer = (p[:, 2] >= z0) & (p[:, 2] <= z1)
        if not self.has_lattice:
            out[in_layer] = REGION_IDS["hydrogel"]
            return out
        iv = self.channel_intervals_mm()

        def on_channel(c: np.ndarray) -> np.ndarray:
            return np.any((c[:, None] >= iv[:, 0]) & (c[:, None] <= iv[:, 1]), axis=1)

        gel = in_layer & (on_channel(p[:, 0]) | on_channel(p[:, 1]))
        out[gel] = REGION_IDS["hydrogel"]
        return out

    def electrodes(self) -> np.ndarray:
        """Electrode rectangles, one row per electrode in numbering order, shape ``(n_electrodes, 8)``.

        Columns: centre ``x, y, z`` (mm), outward normal ``nx, ny`` (the wall's), tangent axis
        (0 = along x, 1 = along y), width (mm), height (mm).
        """
        L, per = self.size_mm, self.n_electrodes // 4
        c = (np.arange(per) + 0.5) * L / per
        z0, z1 = self.layer_z_mm
        zc, ht, ew = (z0 + z1) / 2, self.thickness_mm, self.electrode_width_mm
        rows = []
        for s in c:  # side y = 0, x increasing
            rows.append([s, 0.0, zc, 0, -1, 0, ew, ht])
        for s in c:  # side x = L, y increasing
            rows.append([L, s, zc, 1, 0, 1, ew, ht])
        for s in c[::-1]:  # side y = L, x decreasing
            rows.append([s, L, zc, 0, 1, 0, ew, ht])
        for s in c[::-1]:  # side x = 0, y decreasing
            rows.append([0.0, s, zc, -1, 0, 1, ew, ht])
        return np.asarray(rows, dtype=float)

    # -- identity ---------------------------------------------------------------------------------
    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    def content_hash(self) -> str:
        """SHA-256 of the canonical JSON of the fields (stable across machines and runs)."""
        return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()

    def replace(self, **changes) -> LatticeDesign:
        """A validated copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def describe(self) -> str:
        kind = "uniform layer" if not self.has_lattice else f"{self.pattern} lattice w = {self.width_mm:g} mm, " \
                                                            f"p = {self.pitch_mm:g} mm"
        return f"{kind}, t = {self.thickness_mm:g} mm, {self.size_mm:g} x {self.size_mm:g} x " \
               f"{self.total_thickness_mm:g} mm, {self.n_electrodes} electrodes"


DESIGN_FIELDS = tuple(f.name for f in dataclasses.fields(LatticeDesign))
