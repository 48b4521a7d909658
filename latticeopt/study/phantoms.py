"""Phantoms: the sets of touches a sensor is pressed with (the paper's §III-B).

A random phantom with ``k`` touches draws, for every touch, a radius uniform in ``[r_lo, r_hi]`` mm, a depth
uniform in ``[d_lo, d_hi]`` mm and a centre uniform with the indenter disc fully on the sensor
(``r <= x <= L - r``, same for ``y``). If two discs of the draw overlap (centre distance
``< r_i + r_j + min_gap_mm``) the *whole* draw is rejected and redrawn from the same stream. Rejecting the whole
set, not one touch at a time, gives exactly the independent-uniform distribution conditioned on
non-overlap; redrawing only the offending touch would favour configurations that are easy to complete.

Reproducibility. Phantom ``i`` with ``k`` touches of a study with seed ``s`` is drawn from its own stream
``Generator(PCG64(SeedSequence(s, spawn_key=(k, i))))``, so it does not depend on how many phantoms were drawn
before it or on the machine, and every design of a study sees the same phantoms (common random numbers). Only
``Generator.random`` is used (53 random bits of one 64-bit PCG64 output per double) and mapped to ranges here
(``lo + (hi - lo) * u``): SeedSequence, PCG64 and that map are fixed algorithms, so the phantoms do not
change with the numpy version either.

Probe presses (:class:`ProbePresses`, a ``kind = "probes"`` study and the optimizers' probe grid alike): one flat
punch pressed at the centre of every cell of an ``n x n`` partition of the sensor, to score how uniform a design's
response is over its area; nothing random.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ..touches import Touch

__all__ = ["MAX_TOUCHES", "PROBE_GRID", "Comparison", "Phantom", "PressSeries", "ProbePresses", "RandomPhantoms",
           "phantom_rng", "press_series", "random_phantom", "random_phantoms", "uniformity", "worst_to_best"]

#: Most touches a random phantom may have (the paper uses 1, 2 and 3).
MAX_TOUCHES = 5
#: Whole-set redraws allowed before giving up (3 touches of radius <= 8.75 mm on 100 mm accept ~75 %).
MAX_TRIES = 10_000
#: Probes per side a probe grid may have: two at least (one probe has no spread), ten at most.
PROBE_GRID = (2, 10)


@dataclass(frozen=True)
class Phantom:
    """A set of simultaneous touches.

    Parameters
    ----------
    touches
        The indenters (mm), in order; forces etc. are reported in this order.
    index
        Position in its series: phantom number within its touch count (random) or depth step (press).
    kind
        ``"random"`` or ``"press"``; descriptive only (not part of :attr:`key`).
    """

    touches: tuple[Touch, ...]
    index: int = 0
    kind: str = "random"

    def __post_init__(self) -> None:
        touches = tuple(self.touches)
        if not touches or not all(isinstance(t, Touch) for t in touches):
            raise ParameterError("touches", "a non-empty sequence of Touch", self.touches)
        object.__setattr__(self, "touches", touches)
        object.__setattr__(self, "index", v.integer("index", self.index, lo=0))
        object.__setattr__(self, "kind", v.choice("kind", self.kind, ("random", "press")))

    @property
    def n_touches(self) -> int:
        return len(self.touches)

    @property
    def key(self) -> str:
        """SHA-256 of the touches as canonical JSON: the same loads give the same key anywhere."""
        payload = json.dumps([asdict(t) for t in self.touches], sort_keys=True)
        return hashlib.sha256(payload.encode()).hexdigest()

    def as_dict(self) -> dict:
        return {"index": self.index, "kind": self.kind, "n_touches": self.n_touches, "key": self.key,
                "touches": [asdict(t) for t in self.touches]}

    def to_json(self) -> str:
        return json.dumps(self.as_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, data: Mapping) -> Phantom:
        """Inverse of :meth:`as_dict`; a stored ``key`` must match the touches."""
        try:
            touches = tuple(Touch(**t) for t in data["touches"])
            p = cls(touches, index=data.get("index", 0), kind=data.get("kind", "random"))
        except (KeyError, TypeError) as exc:
            raise ParameterError("phantom", "a dict with 'touches' (x_mm, y_mm, radius_mm, depth_mm each)",
                                 f"{data!r} ({exc})") from None
        if "key" in data and data["key"] != p.key:
            raise ParameterError("phantom.key", f"the touches' content hash {p.key}", data["key"])
        return p

    @classmethod
    def from_json(cls, text: str) -> Phantom:
        return cls.from_dict(json.loads(text))


def phantom_rng(seed: int, n_touches: int, index: int) -> np.random.Generator:
    """The random stream of phantom ``index`` with ``n_touches`` touches under ``seed``."""
    ss = np.random.SeedSequence(v.integer("seed", seed, lo=0), spawn_key=(n_touches, index))
    return np.random.Generator(np.random.PCG64(ss))


def _range(name: str, pair: Sequence[float], lo: float = 0.0) -> tuple[float, float]:
    if len(pair) != 2:
        raise ParameterError(name, "a pair (low, high)", pair)
    a = v.real(name, pair[0], lo=lo, lo_open=True)
    b = v.real(name, pair[1], lo=a)
    return a, b


def random_phantom(size_mm: float, n_touches: int, index: int, seed: int, *,
                   depth_range_mm: Sequence[float] = (1.0, 5.0), radius_range_mm: Sequence[float] = (6.25, 8.75),
                   min_gap_mm: float = 0.0) -> Phantom:
    """Draw one random phantom (see the module docstring for the distribution and the stream).

    Parameters
    ----------
    size_mm
        Side ``L`` of the square sensor (mm).
    n_touches
        Number of simultaneous touches, 1..:data:`MAX_TOUCHES`.
    index
        Phantom number within its touch count; selects the random stream.
    seed
        Study seed (integer >= 0).
    depth_range_mm, radius_range_mm
        ``(low, high)`` of the uniform depth and radius (mm).
    min_gap_mm
        Smallest allowed gap between two indenter discs (mm).

    Raises
    ------
    ParameterError
        On bad arguments, or when no non-overlapping draw is found in :data:`MAX_TRIES` attempts.
    """
    L = v.real("size_mm", size_mm, lo=0, lo_open=True)
    k = v.integer("n_touches", n_touches, lo=1, hi=MAX_TOUCHES)
    d_lo, d_hi = _range("depth_range_mm", depth_range_mm)
    r_lo, r_hi = _range("radius_range_mm", radius_range_mm)
    gap = v.real("min_gap_mm", min_gap_mm, lo=0)
    if 2 * r_hi > L:
        raise ParameterError("radius_range_mm", f"radii with 2 r <= sensor side {L:g} mm", radius_range_mm)
    rng = phantom_rng(seed, k, index)
    for _ in range(MAX_TRIES):
        u = rng.random((k, 4))  # columns: radius, depth, x, y — in this order, forever
        r = r_lo + (r_hi - r_lo) * u[:, 0]
        d = d_lo + (d_hi - d_lo) * u[:, 1]
        x = r + (L - 2 * r) * u[:, 2]
        y = r + (L - 2 * r) * u[:, 3]
        if all(math.hypot(x[i] - x[j], y[i] - y[j]) >= r[i] + r[j] + gap
               for i in range(k) for j in range(i + 1, k)):
            return Phantom(tuple(Touch(x_mm=float(x[i]), y_mm=float(y[i]), radius_mm=float(r[i]),
                                       depth_mm=float(d[i])) for i in range(k)), index=index)
    raise ParameterError("phantoms", f"{k} non-overlapping touches of radius up to {r_hi:g} mm with gap "
                         f"{gap:g} mm on a {L:g} mm sensor (none found in {MAX_TRIES} draws)", k)


def random_phantoms(size_mm: float, counts: Mapping[int, int], seed: int, **ranges) -> tuple[Phantom, ...]:
    """Draw ``counts[k]`` phantoms with ``k`` touches for every ``k`` (ascending ``k``, then index).

    ``ranges`` are passed to :func:`random_phantom`.
    """
    out = []
    for k in sorted(counts):
        n = v.integer(f"counts[{k}]", counts[k], lo=0)
        out.extend(random_phantom(size_mm, k, i, seed, **ranges) for i in range(n))
    return tuple(out)


def press_series(x_mm: float, y_mm: float, radius_mm: float, depths_mm: Sequence[float]) -> tuple[Phantom, ...]:
    """One indenter at ``(x_mm, y_mm)`` pressed to each depth in turn (a press test), index = depth step."""
    return tuple(Phantom((Touch(x_mm=float(x_mm), y_mm=float(y_mm), radius_mm=float(radius_mm),
                                depth_mm=float(d)),), index=i, kind="press") for i, d in enumerate(depths_mm))


# -- phantom sets (a study's [phantoms] or [press] table) --------------------------------------------------
@dataclass(frozen=True)
class RandomPhantoms:
    """Random touches (``kind = "grid"``), as in the paper: see :func:`random_phantoms`.

    ``counts`` holds ``(touches, how many)`` pairs, e.g. ``((1, 100), (2, 100), (3, 100))``: the first ``n``
    phantoms of every touch count. ``only`` keeps just some of those by ``(touches, index)``, e.g. ``((1, 13), (2,
    9))``: phantom 13 of the single touches and phantom 9 of the pairs, the very touches of the whole study (the
    failures of a map, re-run alone).
    """

    seed: int = 0
    counts: tuple[tuple[int, int], ...] = ((1, 100), (2, 100), (3, 100))
    depth_mm: tuple[float, float] = (1.0, 5.0)
    radius_mm: tuple[float, float] = (6.25, 8.75)
    min_gap_mm: float = 0.0
    only: tuple[tuple[int, int], ...] = ()

    def generate(self, size_mm: float) -> tuple[Phantom, ...]:
        ranges = {"depth_range_mm": self.depth_mm, "radius_range_mm": self.radius_mm, "min_gap_mm": self.min_gap_mm}
        if self.only:
            return tuple(random_phantom(size_mm, k, i, self.seed, **ranges) for k, i in self.only)
        return random_phantoms(size_mm, dict(self.counts), self.seed, **ranges)


@dataclass(frozen=True)
class Comparison:
    """A ratio to print for a press study: V_rel of one design over another's at the deepest depth.

    ``numerator``/``denominator`` are ``(field, value)`` pairs selecting exactly one design of the study;
    ``reference`` is a published value printed beside it (for comparison, never for tuning).
    """

    label: str
    numerator: tuple[tuple[str, object], ...]
    denominator: tuple[tuple[str, object], ...]
    reference: float | None = None


@dataclass(frozen=True)
class PressSeries:
    """One indenter pressed ever deeper at a fixed place (``kind = "press"``; the paper's Fig. 8a)."""

    x_mm: float = 50.0
    y_mm: float = 50.0
    radius_mm: float = 8.75
    depths_mm: tuple[float, ...] = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
    compare: tuple[Comparison, ...] = ()

    def generate(self, size_mm: float) -> tuple[Phantom, ...]:
        return press_series(self.x_mm, self.y_mm, self.radius_mm, self.depths_mm)


@dataclass(frozen=True)
class ProbePresses:
    """The probe grid: one flat punch pressed at the centre of every cell of a ``grid x grid`` partition of the
    sensor (``kind = "probes"``; the optimizers' ``uniformity`` term and the density studies' probes use the same).

    Parameters
    ----------
    grid
        Probes per side, :data:`PROBE_GRID` (2 to 10).
    radius_mm
        Punch radius (mm), > 0; it must fit in its cell, ``radius_mm <= L / (2 grid)`` (checked by
        :meth:`generate`, which knows the sensor side ``L``).
    depth_mm
        Indentation depth of every probe (mm), > 0 (below the stack thickness: checked against the designs).
    """

    grid: int = 7
    radius_mm: float = 6.25
    depth_mm: float = 3.0

    def __post_init__(self) -> None:
        lo, hi = PROBE_GRID
        object.__setattr__(self, "grid", v.integer("grid", self.grid, lo=lo, hi=hi,
                                                   expected=f"an integer from {lo} to {hi} (probes per side)"))
        object.__setattr__(self, "radius_mm", v.real("radius_mm", self.radius_mm, lo=0, lo_open=True))
        object.__setattr__(self, "depth_mm", v.real("depth_mm", self.depth_mm, lo=0, lo_open=True))

    @property
    def n_probes(self) -> int:
        return self.grid * self.grid

    def cell(self, index: int) -> tuple[int, int]:
        """Column and row ``(i % grid, i // grid)`` of probe ``index``: x varies fastest, both from the origin."""
        return index % self.grid, index // self.grid

    def max_radius_mm(self, size_mm: float) -> float:
        """The largest radius whose probes stay each in its own cell on a ``size_mm`` sensor."""
        return size_mm / (2 * self.grid)

    def generate(self, size_mm: float) -> tuple[Phantom, ...]:
        """The probes on a ``size_mm`` sensor: probe ``i`` (its phantom index) at the centre of cell
        :meth:`cell` ``(i)``, ``((col + 0.5) L / grid, (row + 0.5) L / grid)``; kind ``"press"``.

        Raises
        ------
        ParameterError
            Named ``radius_mm`` when a probe would leave its cell.
        """
        n, r = self.grid, self.radius_mm
        if r > self.max_radius_mm(size_mm):
            raise ParameterError("radius_mm", f"radius_mm <= L / (2 grid) = {self.max_radius_mm(size_mm):g} mm "
                                 f"(L = {size_mm:g} mm) so every probe of the {n} x {n} grid lies in its own cell", r)
        c = (np.arange(n) + 0.5) * size_mm / n
        return tuple(Phantom((Touch(x_mm=float(c[i % n]), y_mm=float(c[i // n]), radius_mm=r,
                                    depth_mm=self.depth_mm),), index=i, kind="press") for i in range(n * n))


def uniformity(v_rel: Sequence[float]) -> float:
    """``1 - std / mean`` of the probes' V_rel, the population std (``ddof = 0``): 1 when every probe reads the
    same; below 0 when the spread exceeds the mean. NaN for no values, a mean <= 0 or a NaN among them (a failed
    probe): it is a statistic of the whole grid, never of a subset."""
    p = np.asarray(v_rel, dtype=float).ravel()
    m = float(np.mean(p)) if p.size else math.nan
    return 1.0 - float(np.std(p)) / m if m > 0 else math.nan


def worst_to_best(v_rel: Sequence[float]) -> float:
    """Smallest over largest probe V_rel (NaN for no values, a largest <= 0 or a NaN among them)."""
    p = np.asarray(v_rel, dtype=float).ravel()
    best = float(p.max()) if p.size else math.nan
    return float(p.min()) / best if best > 0 else math.nan
