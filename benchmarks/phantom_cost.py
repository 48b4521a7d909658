"""CPU seconds and operation counts per paper phantom on both levels of a two-level map, to compare code versions.

The paper map's time is the coarse level's seconds per phantom times 9,000 plus the fine level's times the fine
count. This presses a fixed set of paper phantoms (the first ``--phantoms`` of each touch count; the same every
run) on each design, on the fine level (``studies/paper_fig4.toml``'s mesh and physics) and on the coarse one
(its ``[multilevel]`` level: 4 mm mechanics, one cell across a channel, ``mechanics_rtol = 1e-2``, electrics on
the fine mesh), one process, one BLAS thread, after one untimed press per model, and prints per design and level
the Newton increments, factorizations and Krylov iterations (which a change of speed alone leaves equal), the CPU
seconds per phantom split into mechanics and electrics, and the sum of V_rel (which it leaves equal to round-off).
``--json`` appends one line per design and level with every phantom's V_rel, so two checkouts compare exactly:

    PYTHONPATH=<checkout> python benchmarks/phantom_cost.py --designs 4,3 2,1 0,3 --json before.jsonl
    python benchmarks/phantom_cost.py --compare before.jsonl after.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

STUDY = Path(__file__).resolve().parent.parent / "studies" / "paper_fig4.toml"


def _design(text: str) -> tuple[float, float]:
    try:
        w, t = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"W,T in mm (e.g. 4,3), got {text!r}") from None
    if not (w in (0, 2, 3, 4, 5, 6) and t in (1, 2, 3, 4, 5)):
        raise argparse.ArgumentTypeError(f"a design of the paper grid (w 0, 2-6; t 1-5 mm), got {text!r}")
    return w, t


def _press_all(model, phantoms) -> dict:
    model.simulate(list(phantoms[0].touches))  # untimed: first-call costs off the row
    rows = []
    for p in phantoms:
        c0 = time.process_time()
        r = model.simulate(list(p.touches))
        c1 = time.process_time()
        ops = r.indentation.solver
        rows.append((r.v_rel, r.newton_steps, ops["n_factorizations"], ops["krylov_iterations"], c1 - c0,
                     r.timings["electrics"] / r.timings["total"] * (c1 - c0)))
    a = np.array(rows)
    n = len(a)
    return {"v_rel": a[:, 0].tolist(), "newton": a[:, 1].sum() / n, "factorizations": a[:, 2].sum() / n,
            "krylov": a[:, 3].sum() / n, "cpu_s": a[:, 4].mean(), "electrics_s": a[:, 5].mean()}


def _row(rec: dict) -> str:
    return (f"| {rec['design']} | {rec['level']} | {len(rec['v_rel'])} | {rec['newton']:.1f} | "
            f"{rec['factorizations']:.1f} | {rec['krylov']:.1f} | {rec['cpu_s']:.3f} | {rec['electrics_s']:.3f} | "
            f"{sum(rec['v_rel']):.8f} |")


def _compare(before: Path, after: Path) -> int:
    recs = []
    for path in (before, after):
        try:
            recs.append({(r["design"], r["level"]): r for r in map(json.loads, path.read_text().splitlines())})
        except (OSError, ValueError, KeyError) as exc:
            print(f"phantom_cost: --compare: expected two JSON-lines files written by --json, got {path} ({exc})",
                  file=sys.stderr)
            return 2
    print("| design | level | phantoms | CPU s before | after | ratio | Newton before / after | factorizations | "
          "Krylov | max rel. V_rel change |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for key in (k for k in recs[0] if k in recs[1]):
        b, a = recs[0][key], recs[1][key]
        vb, va = np.array(b["v_rel"]), np.array(a["v_rel"])
        change = float(np.max(np.abs(va / vb - 1))) if len(va) == len(vb) else float("nan")
        print(f"| {key[0]} | {key[1]} | {len(vb)} | {b['cpu_s']:.3f} | {a['cpu_s']:.3f} | "
              f"{a['cpu_s'] / b['cpu_s']:.3f} | {b['newton']:.1f} / {a['newton']:.1f} | "
              f"{b['factorizations']:.1f} / {a['factorizations']:.1f} | {b['krylov']:.1f} / {a['krylov']:.1f} | "
              f"{change:.1e} |")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--designs", type=_design, nargs="+", default=[(4.0, 3.0), (2.0, 1.0), (0.0, 3.0)],
                    help="W,T pairs of the paper grid (mm; default 4,3 2,1 0,3)")
    ap.add_argument("--phantoms", type=int, default=4, help="phantoms per touch count (default 4)")
    ap.add_argument("--levels", nargs="+", choices=["coarse", "fine"], default=["coarse", "fine"])
    ap.add_argument("--json", type=Path, help="append one JSON line per design and level to this file")
    ap.add_argument("--compare", type=Path, nargs=2, metavar=("BEFORE", "AFTER"),
                    help="compare two --json files (computes nothing)")
    args = ap.parse_args(argv)
    if args.compare:
        return _compare(*args.compare)
    if args.phantoms < 1:
        ap.error(f"--phantoms: expected at least 1, got {args.phantoms}")
    from latticeopt import LatticeDesign
    from latticeopt.coupled import model_for_settings
    from latticeopt.study.config import load_study
    from latticeopt.study.settings import coarse_level_settings

    study = load_study(STUDY, ["multilevel.pilot=15"])
    levels = {"fine": study.settings, "coarse": coarse_level_settings(study.settings, study.multilevel)}
    picked = [p for k in (1, 2, 3) for p in [q for q in study.phantoms if q.n_touches == k][:args.phantoms]]
    print(f"{len(picked)} paper phantoms ({args.phantoms} per touch count), load average {os.getloadavg()[0]:.2f}")
    print("| design | level | phantoms | Newton | factorizations | Krylov iterations | CPU s | of it electrics | "
          "sum of V_rel |")
    print("|---|---|---|---|---|---|---|---|---|")
    for w, t in args.designs:
        for level in args.levels:
            model = model_for_settings(LatticeDesign(width_mm=w, thickness_mm=t), levels[level])
            rec = {"design": f"w = {w:g}, t = {t:g}", "level": level, **_press_all(model, picked)}
            print(_row(rec), flush=True)
            if args.json:
                with open(args.json, "a") as fh:
                    fh.write(json.dumps(rec) + "\n")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
