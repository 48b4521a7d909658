"""A candidate middle level for the two-level map: does a finer mechanics mesh follow the fine level more closely?

The two-level map's fine count per design is set by how well the coarse level follows the fine one: the stopping
rule needs about ``N var(F - C) / (0.21 var(F) + var(F - C))`` sampled fine phantoms for an SE of 1.1 x the plain
one. A third level between them pays only if its corrections ``F - M`` vary much less than ``F - C`` at a cost well
below the fine level's. This reads, from a finished paper map's store, the coarse and fine V_rel of the first
``--phantoms`` fine phantoms (in phantom-key order) of each design, presses them on the candidate mechanics mesh
(``--mesh SIZE:CELLS``; the coarse level's physics, electrics on the fine mesh) and prints the variances of the
three differences beside var(F) and the candidate's seconds per press.

    python benchmarks/middle_level.py runs/paper_fig4_takeall --mesh 3:1 --designs 2,1 4,1 6,3 --phantoms 30
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sqlite3
import statistics
import sys
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

from latticeopt.coupled import CoupledModel  # noqa: E402
from latticeopt.study.config import load_study  # noqa: E402
from latticeopt.study.settings import coarse_level_settings  # noqa: E402

STUDY = Path(__file__).resolve().parent.parent / "studies" / "paper_fig4.toml"


def sweep_store(prog: str, folder: Path) -> Path | None:
    """``folder``'s results store, or None after a one-line message on stderr naming ``prog`` (exit status 2)."""
    store = folder / "results.sqlite"
    if store.is_file():
        return store
    print(f"{prog}: folder: expected a sweep folder holding results.sqlite, got {folder}", file=sys.stderr)
    return None


def paper_designs(prog: str, study, pairs: list[str]) -> list | None:
    """The study's designs named by ``"W,T"`` pairs (mm), or None after a one-line message on stderr naming
    ``prog`` for a pair that is not on the paper grid (exit status 2)."""
    designs = []
    for pair in pairs:
        try:
            w, t = (float(x) for x in pair.split(","))
            designs.append(next(d for d in study.designs if d.width_mm == w and d.thickness_mm == t))
        except (ValueError, StopIteration):
            print(f"{prog}: --designs: expected W,T pairs of the paper grid (w 0, 2-6; t 1-5 mm), got {pair!r}",
                  file=sys.stderr)
            return None
    return designs


def _pairs(con, settings_key: str, design_key: str) -> dict[str, float]:
    rows = con.execute("SELECT phantom_key, v_rel FROM evaluations WHERE settings_key = ? AND design_key = ? "
                       "AND status = 'ok'", (settings_key, design_key)).fetchall()
    return dict(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="a finished two-level paper map's folder (holding results.sqlite)")
    ap.add_argument("--mesh", default="3:1", help="candidate mechanics mesh SIZE:CELLS (default 3:1)")
    ap.add_argument("--designs", nargs="+", default=["2,1", "4,1", "6,3"], help="W,T pairs (mm)")
    ap.add_argument("--phantoms", type=int, default=30, help="fine phantoms per design to press (default 30)")
    ap.add_argument("--set", action="append", default=[], help="study override the map ran with (key=value)")
    args = ap.parse_args(argv)
    store = sweep_store("middle_level", args.folder)
    if store is None:
        return 2
    try:
        size, cells = float(args.mesh.split(":")[0]), int(args.mesh.split(":")[1])
        if not (size > 0 and cells >= 1 and args.mesh.count(":") == 1):
            raise ValueError
    except (ValueError, IndexError):
        print(f"middle_level: --mesh: expected SIZE:CELLS with SIZE > 0 mm and CELLS >= 1, got {args.mesh!r}",
              file=sys.stderr)
        return 2
    if args.phantoms < 2:
        print(f"middle_level: --phantoms: expected at least 2, got {args.phantoms}", file=sys.stderr)
        return 2
    study = load_study(STUDY, ["multilevel.pilot=15", *args.set])
    fine = study.settings
    coarse = coarse_level_settings(fine, study.multilevel)
    middle = dataclasses.replace(fine.mesh, size_mm=size, channel_cells=cells)
    by_key = {p.key: p for p in study.phantoms}
    con = sqlite3.connect(f"file:{store}?mode=ro", uri=True)
    designs = paper_designs("middle_level", study, args.designs)
    if designs is None:
        return 2
    print("| design | mechanics nodes | n | var(F) | var(F - C) | var(F - M) | var(M - C) | M s per press |")
    print("|---|---|---|---|---|---|---|---|")
    for design in designs:
        w, t = design.width_mm, design.thickness_mm
        f = _pairs(con, fine.key, design.content_hash())
        c = _pairs(con, coarse.key, design.content_hash())
        keys = sorted(k for k in f if k in c)[:args.phantoms]
        if len(keys) < 2:
            print(f"middle_level: w = {w:g}, t = {t:g}: fewer than 2 fine phantoms in {store}", file=sys.stderr)
            return 2
        model = CoupledModel(design, fine.mesh, coarse.physics_settings, fine.cache_dir, middle)
        m, seconds = {}, []
        for k in keys:
            t0 = time.process_time()
            m[k] = model.simulate(list(by_key[k].touches)).v_rel
            seconds.append(time.process_time() - t0)
        cols = [[f[k] for k in keys], [f[k] - c[k] for k in keys], [f[k] - m[k] for k in keys],
                [m[k] - c[k] for k in keys]]
        print(f"| w = {w:g}, t = {t:g} | {model.mechanics_mesh.n_nodes:,} | {len(keys)} | "
              + " | ".join(f"{statistics.pvariance(x):.2e}" for x in cols)
              + f" | {statistics.mean(seconds):.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
