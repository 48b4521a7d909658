"""Measured presses: the calibration data file, read and checked row by row.

A measured press is one row of a CSV file: design keys (any of :data:`latticeopt.design.TABLE_KEYS`, e.g.
``width_mm``, ``thickness_mm``, ``rim``), the touch (``x_mm, y_mm, radius_mm, depth_mm``) and what was measured:
either ``v_rel`` (paper eq. 5) or the 208 voltages ``V1 ... V208`` in pyEIT "std" row order. Voltage rows need
a reference row of the same design and touch position at ``depth_mm = 0``; what the fit compares is the change
of each channel relative to that reference (:func:`measured_changes`), so the unknown drive current and gel
conductivity scale cancel.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..design import TABLE_KEYS, LatticeDesign, design_from_table
from ..errors import ParameterError
from ..touches import Touch, validate_touches

__all__ = ["N_ROWS", "Press", "measured_changes", "read_presses"]

TOUCH_KEYS = ("x_mm", "y_mm", "radius_mm", "depth_mm")
N_ROWS = 208
VOLTAGE_KEYS = tuple(f"V{i}" for i in range(1, N_ROWS + 1))


@dataclass(frozen=True)
class Press:
    """One measured press (mm; ``v_rel`` dimensionless, voltages in the file's unit)."""

    row: int
    design: LatticeDesign
    touch: Touch
    v_rel: float | None = None
    voltages: tuple[float, ...] | None = None
    fields: tuple[tuple[str, str], ...] = ()

    def field(self, key: str) -> str | None:
        return dict(self.fields).get(key)


def read_presses(path: str | Path) -> tuple[Press, ...]:
    """Read and check a measured-press CSV (see the module docstring); errors name the file, row and column."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ParameterError("DATA", "a readable CSV file of measured presses", f"{p} ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ParameterError("DATA", "a UTF-8 text CSV file", str(p)) from None
    reader = csv.DictReader(text.splitlines())
    cols = reader.fieldnames or []
    missing = [k for k in TOUCH_KEYS if k not in cols]
    has_v, n_volt = "v_rel" in cols, sum(k in cols for k in VOLTAGE_KEYS)
    if missing:
        raise ParameterError(f"{p}: columns", "the touch columns " + ", ".join(TOUCH_KEYS), f"missing {missing}")
    if has_v == bool(n_volt) or 0 < n_volt < N_ROWS:
        raise ParameterError(f"{p}: columns", f"either v_rel or all of V1..V{N_ROWS}",
                             f"v_rel {'present' if has_v else 'absent'}, {n_volt} voltage columns")
    unknown = [c for c in cols if c not in (*TABLE_KEYS, *TOUCH_KEYS, "v_rel", *VOLTAGE_KEYS, "label", "source")]
    if unknown:
        raise ParameterError(f"{p}: columns", "design keys (" + ", ".join(TABLE_KEYS) + "), touch columns, v_rel "
                             "or V1..V208, label, source", unknown[0])
    presses = []
    for i, row in enumerate(reader, start=2):
        where = f"{p}: row {i}"
        number = _number_reader(row, where)

        table = {}
        for k in TABLE_KEYS:
            if row.get(k) not in (None, ""):
                val = row[k]
                table[k] = val if k in ("pattern", "rim", "layout") else (
                    val.strip().lower() == "true" if k == "electrode_leads" else number(k))
        for k in ("n_electrodes",):
            if k in table:
                table[k] = int(table[k])
        try:
            design = design_from_table(table, base_dir=str(p.parent))
            touch = Touch(*(number(k) for k in TOUCH_KEYS))
            validate_touches(design, [touch])
        except ParameterError as exc:
            raise ParameterError(f"{where}, {exc.name}", exc.expected, exc.got) from None
        v_rel = volts = None
        if has_v:
            v_rel = number("v_rel")
            if touch.depth_mm <= 0:
                raise ParameterError(f"{where}, depth_mm", "a press (depth_mm > 0) for a v_rel row", row["depth_mm"])
            if v_rel <= 0:
                raise ParameterError(f"{where}, v_rel", "a positive relative change for a press", row["v_rel"])
        else:
            volts = tuple(number(k) for k in VOLTAGE_KEYS)
        presses.append(Press(i, design, touch, v_rel, volts, tuple((k, row[k]) for k in cols if k in TABLE_KEYS)))
    if not presses:
        raise ParameterError(str(p), "at least one measured press", "no rows")
    if not any(pr.touch.depth_mm > 0 for pr in presses):
        raise ParameterError(str(p), "presses with depth_mm > 0", "only zero depths")
    return tuple(presses)


def _number_reader(row: dict, where: str) -> Callable[[str], float]:
    def number(key: str) -> float:
        try:
            val = float(row[key])
        except (TypeError, ValueError):
            raise ParameterError(f"{where}, {key}", "a number", row[key]) from None
        if not math.isfinite(val):
            raise ParameterError(f"{where}, {key}", "a finite number", row[key])
        return val

    return number


def _group_key(pr: Press) -> tuple:
    t = pr.touch
    return pr.design.content_hash(), round(t.x_mm, 9), round(t.y_mm, 9), round(t.radius_mm, 9)


def _references(presses: Sequence[Press]) -> dict:
    """Voltage data: the depth-0 row of every (design, position, radius)."""
    refs = {}
    for pr in presses:
        if pr.voltages is not None and pr.touch.depth_mm == 0:
            refs[_group_key(pr)] = np.asarray(pr.voltages)
    for pr in presses:
        if pr.voltages is not None and pr.touch.depth_mm > 0 and _group_key(pr) not in refs:
            raise ParameterError(f"row {pr.row}", "a reference row (depth_mm = 0) of the same design and touch "
                                 "position for voltage data", "none")
    return refs


def measured_changes(presses: Sequence[Press]) -> list[np.ndarray]:
    """Per press, the measured quantity the fit compares: ``[v_rel]`` or the 208 relative changes."""
    refs = _references(presses)
    out = []
    for pr in presses:
        if pr.v_rel is not None:
            out.append(np.array([pr.v_rel]))
        else:
            ref = refs[_group_key(pr)]
            out.append((np.asarray(pr.voltages) - ref) / np.abs(ref))
    return out
