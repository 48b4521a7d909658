"""The report lines every sweep kind shares: failures named for a re-run, the floor, the round-off warning."""

from pathlib import Path

import pytest

from latticeopt.metric import ROUND_OFF_REL
from latticeopt.study.config import load_study
from latticeopt.study.report_lines import (
    _LISTED,
    failed_lines,
    floor_text,
    phantom_name,
    rerun_lines,
    round_off_lines,
    smallest_reference,
)
from latticeopt.study.store import Evaluation

STUDIES = Path(__file__).resolve().parent.parent / "studies"


@pytest.fixture(scope="module")
def study():
    # 12 designs x 3 phantoms (one of each touch count); nothing is computed
    return load_study(STUDIES / "quick.toml")


def _ev(status="ok", **extra):
    return Evaluation(design_key="d", phantom_key="p", settings_key="s", status=status,
                      v_rel=0.1 if status == "ok" else None, extra=extra)


def test_failed_lines_count_each_level_and_name_each_phantom_once(study):
    # phantom 1 failed on two designs (coarse and fine), phantom 2 on one: two phantoms, counted per level
    failures = [(0, 1, "coarse", "ConvergenceError: load step 7\ntraceback"), (3, 1, "fine", "MeshError: x"),
                (5, 2, "fine", None)]
    lines = failed_lines(study, failures)
    assert lines[0].startswith(f"failed: 1 coarse and 2 fine evaluations, on 2 of {len(study.phantoms)} phantoms")
    p1, p2 = study.phantoms[1], study.phantoms[2]
    assert lines[1].startswith(f"failed phantom {p1.n_touches}:{p1.index} ")
    assert "ConvergenceError: load step 7; fine" in lines[1] and "traceback" not in lines[1]  # first line only
    assert lines[2].startswith(f"failed phantom {p2.n_touches}:{p2.index} ")
    # the last line is the setting that re-runs exactly those phantoms, the names phantoms.only takes
    assert lines[-1].endswith(f"--set 'phantoms.only=[\"{phantom_name(p1)}\", \"{phantom_name(p2)}\"]'")
    assert len(lines) == 4


def test_failed_lines_list_at_most_the_first_few(study):
    # more failed phantoms than are listed: the rest are counted, the re-run setting still names all
    many = study.phantoms * 5  # 15 phantom positions of a 3-phantom study would be out of range: fake a bigger one
    big = type("S", (), {"designs": study.designs, "phantoms": many, "grid_fields": study.grid_fields,
                         "kind": "grid"})()
    failures = [(0, j, "fine", "E: x") for j in range(len(many))]
    lines = failed_lines(big, failures)
    assert sum(line.startswith("failed phantom ") for line in lines) == _LISTED
    assert f"... and {len(many) - _LISTED} more failed phantoms" in lines[-2]
    assert lines[-1].count('"') == 2 * len(many)


def test_rerun_lines_only_for_random_phantoms(study):
    assert rerun_lines(study, []) == []
    press = type("S", (), {"phantoms": study.phantoms, "kind": "press"})()
    assert rerun_lines(press, [0]) == []  # a press study's phantoms are fixed depths, not phantoms.only names


def test_floor_text_names_the_floor_only_when_set():
    assert floor_text(0.0) == ""
    assert floor_text(1e-4) == "; V_rel with an instrument floor of 0.0001 of the largest row"


def test_round_off_warning_names_the_designs_below_the_threshold():
    below, above = 0.1 * ROUND_OFF_REL, 10 * ROUND_OFF_REL
    smallest = [("w = 2", below), ("w = 4", above), ("w = 6", None)] + [(f"d{k}", below) for k in range(5)]
    (line,) = round_off_lines(smallest, floor_rel=0.0)
    assert "in 6 designs (w = 2, d0, d1, d2 and 2 more)" in line and "w = 4" not in line
    assert round_off_lines(smallest, floor_rel=ROUND_OFF_REL) == []  # the floor already lifts those rows
    assert round_off_lines([("w = 4", above), ("w = 6", None)], floor_rel=0.0) == []


def test_smallest_reference_reads_only_successful_evaluations():
    evs = [_ev(min_reference_rel=0.3), _ev(min_reference_rel=0.02), _ev(), _ev("failed", min_reference_rel=1e-9)]
    assert smallest_reference(evs) == 0.02
    assert smallest_reference([_ev(), _ev("failed")]) is None
