"""The lines every kind of sweep report shares: failed and excluded phantoms, the setting that re-runs them,
the instrument floor, and the round-off warning for reference rows near zero.

Plain sweeps (:mod:`.report`), two-level (:mod:`.multilevel_report`) and adaptive ones (:mod:`.adaptive_report`)
and the optimizer's report (:mod:`latticeopt.optimize.report`) write them into their ``report.txt``.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..captions import counted
from ..metric import ROUND_OFF_REL
from ._rows import _fmt
from .config import Study
from .store import Evaluation

__all__ = ["at_round_off", "failed_lines", "floor_text", "phantom_name", "rerun_lines", "round_off_lines",
           "smallest_reference"]


def _first_line(text: str | None) -> str:
    return (text or "").splitlines()[0] if text else ""


def at_round_off(smallest: float | None, floor_rel: float) -> bool:
    """Whether a ``V_rel`` divides by reference rows at round-off: its smallest row over its largest (``None``:
    not reported) is below :data:`ROUND_OFF_REL` and no instrument floor ``floor_rel`` lifts such rows."""
    return smallest is not None and smallest < ROUND_OFF_REL and floor_rel < ROUND_OFF_REL


def round_off_lines(smallest: Sequence[tuple[str, float | None]], floor_rel: float) -> list[str]:
    """Warnings for designs whose ``V_rel`` divides by reference rows below :data:`ROUND_OFF_REL` of the largest.

    ``smallest`` holds ``(design label, min |V_ref| / max |V_ref|)`` pairs (``None`` where the model did not
    report it); nothing is said when ``floor_rel`` (``[physics] measurement_floor_rel``) already lifts such rows.
    """
    bad = [(label, r) for label, r in smallest if at_round_off(r, floor_rel)]
    if not bad:
        return []
    worst = min(r for _, r in bad)
    names = ", ".join(label for label, _ in bad[:4]) + (f" and {len(bad) - 4} more" if len(bad) > 4 else "")
    return [f"warning: reference rows down to {worst:.1g} of the largest in {counted(len(bad), 'design')} ({names}): "
            "round-off (electrodes on a dead-end channel), which V_rel divides by; set "
            "physics.measurement_floor_rel (1e-4: an 80 dB instrument) to count those rows at a real "
            "instrument's resolution"]


def floor_text(floor_rel: float) -> str:
    """``"; V_rel with an instrument floor of ..."`` for a report line, or ``""`` for the paper's eq. 5."""
    return f"; V_rel with an instrument floor of {floor_rel:g} of the largest row" if floor_rel > 0 else ""


def smallest_reference(evaluations: Sequence[Evaluation]) -> float | None:
    """The smallest ``min_reference_rel`` the model reported over ``evaluations`` (``None``: none reported)."""
    got = [e.extra.get("min_reference_rel") for e in evaluations if e.ok]
    got = [float(r) for r in got if r is not None]
    return min(got) if got else None


#: Excluded phantoms listed in ``report.txt`` (and so printed by the CLI); ``excluded.csv`` has them all.
_LISTED = 10


def phantom_name(phantom) -> str:
    """``"K:I"``: phantom ``I`` with ``K`` touches, the name ``phantoms.only`` takes."""
    return f"{phantom.n_touches}:{phantom.index}"


def failed_lines(study: Study, failures: Sequence[tuple[int, int, str, str | None]]) -> list[str]:
    """Report lines on the failed evaluations of a two-level sweep, ``(design position, phantom position, level,
    error)`` each: their count per level, then one line per phantom (the first :data:`_LISTED`), named ``K:I``,
    then :func:`rerun_lines`."""
    by_phantom: dict[int, list[str]] = {}
    for i, j, level, err in failures:
        by_phantom.setdefault(j, []).append(f"{level}, {_fmt(study.designs[i], study.grid_fields)}: "
                                            f"{_first_line(err)}")
    n_coarse = sum(level == "coarse" for *_, level, _ in failures)
    lines = [f"failed: {n_coarse} coarse and {len(failures) - n_coarse} fine evaluations, on {len(by_phantom)} of "
             f"{len(study.phantoms)} phantoms (a phantom any compared design failed is left out for all)"]
    for k, (j, why) in enumerate(sorted(by_phantom.items())):
        if k == _LISTED:
            lines.append(f"... and {len(by_phantom) - _LISTED} more failed phantoms (results.csv)")
            break
        p = study.phantoms[j]
        lines.append(f"failed phantom {phantom_name(p)} ({p.n_touches} touches, index {p.index}): {'; '.join(why)}")
    return lines + rerun_lines(study, sorted(by_phantom))


def rerun_lines(study: Study, positions: Sequence[int]) -> list[str]:
    """The ``phantoms.only`` setting that re-runs the phantoms at ``positions`` alone (``--set`` on the same
    study, or ``[phantoms] only`` in a copy); none for no phantoms or a study of fixed presses."""
    if not positions or study.kind != "grid":
        return []
    names = ", ".join(f'"{phantom_name(study.phantoms[j])}"' for j in positions)
    return [f"re-run them alone (a plain sweep of the same study, its designs or fewer): --set 'phantoms.only="
            f"[{names}]'"]
