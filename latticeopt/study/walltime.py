"""How long a sweep will take, before it runs: the estimate ``sweep --dry-run`` prints.

Per level of the study's estimator (:meth:`~.estimators.PlainEstimator.levels`: one for a plain or adaptive
sweep, coarse and fine for a two-level one): the evaluations still to run (the level's count less those stored
under its settings key) times the seconds one phantom costs one worker, divided by the workers. A two-level or
adaptive sweep decides its counts as it runs, so its estimate is a range, from the least it can run (the pilot,
``min_per_design``) to every phantom.

The seconds per phantom, in order of preference:

- *measured*: the mean of the seconds the store recorded for its rows under the level's settings key (failed
  rows included: they cost time too), when it holds any;
- *estimated*: :data:`SECONDS_AT_2MM` per phantom per worker on a 2 mm mesh (the paper map's fine level,
  ``docs/performance.md``), scaled by ``(2 mm / mechanics mesh size)^3`` on coarser meshes, as a tetrahedral
  mesh's node count scales (the same table's coarse level, 4 mm: 0.96 s, is 0.125 of it; the quick study, 36
  evaluations at 2 mm on 2 workers, 139 s by this rule, took 134 s), and by ``(2 mm / size)^6`` on finer ones,
  where the direct factorization, whose work grows as the square of the node count, takes over (the same 20
  held-out presses on 1.4 mm against 2 mm meshes: 8.0x the seconds on two outlines, 5.9-14x, median 8.3, on
  seven more with the cores shared; ``(2 / 1.4)^6`` = 8.5, the cube 2.9). A custom model's cost is its own: the
  estimate says so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from .estimators import Level
from .settings import DEFAULT_MODEL
from .store import STORE_NAME, ResultStore

__all__ = ["SECONDS_AT_2MM", "LevelCost", "WallTime", "format_seconds", "wall_time"]

#: Seconds of one worker per phantom of the coupled model on a 2 mm mesh (docs/performance.md, the paper map's
#: fine level: 7.71 s over 3,531 phantoms).
SECONDS_AT_2MM = 7.7
_REFERENCE_MM = 2.0


def _size_exponent(mesh_mm: float) -> int:
    """How the seconds per phantom scale with ``2 mm / mesh_mm`` (module docstring): 3 coarser, 6 finer."""
    return 3 if mesh_mm >= _REFERENCE_MM else 6


@dataclass(frozen=True)
class LevelCost:
    """One level's share of the estimate."""

    name: str
    to_run: tuple[int, int]  # least and most evaluations still to run
    seconds: float  # per phantom per worker
    measured_rows: int  # stored rows the seconds are the mean of; 0 for the documented estimate
    mesh_mm: float
    model: str

    def source(self) -> str:
        if self.measured_rows:
            return f"measured: mean of {self.measured_rows} stored rows with these settings"
        other = "" if self.model == DEFAULT_MODEL else f", the cost of {DEFAULT_MODEL}, not of {self.model}"
        scaled = "" if self.mesh_mm == _REFERENCE_MM else f" x (2 / {self.mesh_mm:g})^{_size_exponent(self.mesh_mm)}"
        return (f"estimated: {SECONDS_AT_2MM:g} s at 2 mm from docs/performance.md{scaled}{other}; no stored rows "
                "with these settings")


@dataclass(frozen=True)
class WallTime:
    """The estimate: seconds on ``workers`` workers, least and most, and its parts."""

    least_s: float
    most_s: float
    workers: int
    levels: tuple[LevelCost, ...]

    def line(self) -> str:
        """``estimated wall time: ...`` with where each level's seconds per phantom come from."""
        span = format_seconds(self.most_s) if self.least_s == self.most_s else \
            f"{format_seconds(self.least_s)} to {format_seconds(self.most_s)}"
        parts = []
        for lv in self.levels:
            lo, hi = lv.to_run
            count = f"{hi}" if lo == hi else f"{lo}-{hi}"
            prefix = f"{lv.name}: " if len(self.levels) > 1 else ""
            parts.append(f"{prefix}{count} to run x {lv.seconds:.3g} s per phantom per worker ({lv.source()})")
        return f"estimated wall time: {span} on {self.workers} worker{'s' * (self.workers != 1)}; " + "; ".join(parts)


def format_seconds(seconds: float) -> str:
    """``45 s``, ``12 min``, ``3.4 h``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _mechanics_mm(settings) -> float:
    return (settings.mechanics_mesh or settings.mesh).size_mm


def wall_time(levels: Sequence[Level], tasks: Sequence[tuple[str, str]], out_dir: str | Path,
              workers: int) -> WallTime:
    """Estimate a sweep's wall time (module docstring).

    Parameters
    ----------
    levels
        The estimator's levels (settings and least/most evaluations).
    tasks
        ``(design_key, phantom_key)`` of every task of the study: a stored row counts as done only for these.
    out_dir
        The study's output folder (its store need not exist).
    workers
        Worker processes the sweep will use.
    """
    path = Path(out_dir) / STORE_NAME
    wanted = set(tasks)
    costs = []
    store = ResultStore(path, readonly=True) if path.exists() else None
    try:
        for lv in levels:
            seconds = store.seconds(lv.settings.key) if store is not None else {}
            done = sum(k in seconds for k in wanted)
            mesh = _mechanics_mm(lv.settings)
            if seconds:
                per = sum(seconds.values()) / len(seconds)
            else:
                per = SECONDS_AT_2MM * (_REFERENCE_MM / mesh) ** _size_exponent(mesh)
            costs.append(LevelCost(lv.name, (max(lv.min_evaluations - done, 0), max(lv.max_evaluations - done, 0)),
                                   per, len(seconds), mesh, lv.settings.model))
    finally:
        if store is not None:
            store.close()
    least = sum(c.to_run[0] * c.seconds for c in costs) / workers
    most = sum(c.to_run[1] * c.seconds for c in costs) / workers
    return WallTime(least, most, workers, tuple(costs))
