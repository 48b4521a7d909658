"""Where a sweep's time went, read from its results store: evaluations, model seconds and wall time per level.

A two-level map stores its coarse and fine evaluations under two settings keys (the coarse one has its own
mechanics mesh); a plain sweep has one. Per level this prints the evaluations (ok and failed), the model
seconds per evaluation, the worker hours, and the wall hours they come to on ``--workers`` workers; then the
fine evaluations per design and the wall time the store's timestamps span, with the pauses between resumed
runs (gaps longer than ``--gap-min``) left out. Model seconds are what the workers spent in the model, so they
are the numbers to compare between runs on a shared machine; the wall time includes everything else. An
evaluation's seconds are its worker's wall seconds, so a run paused with SIGSTOP counts the pause in the
evaluations it held: stop a timed map with Ctrl-C (SIGINT) and resume it instead.

    python benchmarks/map_time.py runs/paper_fig4_takeall [--workers 2] [--gap-min 10]
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
from collections import Counter, defaultdict
from datetime import datetime
from pathlib import Path

#: A row charged this much (s) beyond the model's own time carries its chunk's per-design set-up.
SETUP_MIN_S = 0.1


def _level(settings: dict) -> str:
    mesh = settings.get("mesh") or {}
    mech = settings.get("mechanics_mesh")
    name = f"{mesh.get('mesher', '?')} {mesh.get('size_mm', '?')} mm / {mesh.get('channel_cells', '?')} cells"
    if mech:
        name = f"mechanics {mech.get('size_mm')} mm / {mech.get('channel_cells')} cells, electrics {name}"
    return name


def _design(d: dict) -> str:
    return f"{d.get('pattern')} w={d.get('width_mm'):g} t={d.get('thickness_mm'):g} rim={d.get('rim')}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="a sweep's output folder (holding results.sqlite)")
    ap.add_argument("--workers", type=int, default=2, help="workers the wall hours are computed for (default 2)")
    ap.add_argument("--gap-min", type=float, default=10.0,
                    help="a pause between two stored rows longer than this (minutes) is not run time (default 10)")
    args = ap.parse_args(argv)
    store = args.folder / "results.sqlite"
    if not store.is_file():
        print(f"map_time: folder: expected a sweep folder holding results.sqlite, got {args.folder}", file=sys.stderr)
        return 2
    if args.workers < 1 or args.gap_min <= 0:
        print(f"map_time: --workers >= 1 and --gap-min > 0, got {args.workers} and {args.gap_min}", file=sys.stderr)
        return 2
    con = sqlite3.connect(f"file:{store}?mode=ro", uri=True)
    rows = con.execute("SELECT settings_key, settings_json, design_json, status, seconds, created_utc, timings_json "
                       "FROM evaluations").fetchall()
    levels: dict[str, dict] = {}
    per_design: dict[str, Counter] = defaultdict(Counter)
    stamps = []
    for key, settings, design, status, seconds, created, timings in rows:
        lv = levels.setdefault(key, {"name": _level(json.loads(settings)), "ok": 0, "failed": 0,
                                     "s_ok": 0.0, "s_failed": 0.0, "setups": 0, "s_setup": 0.0})
        lv[status] += 1
        lv[f"s_{status}"] += seconds or 0.0
        own = (json.loads(timings) if timings else {}).get("total")
        if own is not None and seconds is not None and seconds - own > SETUP_MIN_S:
            lv["setups"] += 1
            lv["s_setup"] += seconds - own
        per_design[key][_design(json.loads(design))] += 1
        stamps.append(datetime.fromisoformat(created.replace("Z", "+00:00")))
    print(f"{store}: {len(rows)} evaluations")
    print("| level | evaluations (failed) | model s per ok evaluation | s per failed | worker hours | "
          f"wall hours on {args.workers} workers |")
    print("|---|---|---|---|---|---|")
    total = 0.0
    for lv in sorted(levels.values(), key=lambda v: -(v["ok"] + v["failed"])):
        hours = (lv["s_ok"] + lv["s_failed"]) / 3600
        total += hours
        per_ok = lv["s_ok"] / lv["ok"] if lv["ok"] else float("nan")
        per_failed = lv["s_failed"] / lv["failed"] if lv["failed"] else float("nan")
        print(f"| {lv['name']} | {lv['ok'] + lv['failed']:,} ({lv['failed']}) | {per_ok:.2f} | {per_failed:.1f} | "
              f"{hours:.2f} | {hours / args.workers:.2f} |")
    print(f"| all | {len(rows):,} | | | {total:.2f} | {total / args.workers:.2f} |")
    print("\n| level | set-ups paid | s per set-up | set-up worker hours | share of the level's hours |")
    print("|---|---|---|---|---|")
    for lv in sorted(levels.values(), key=lambda v: -(v["ok"] + v["failed"])):
        spent = lv["s_ok"] + lv["s_failed"]
        per = lv["s_setup"] / lv["setups"] if lv["setups"] else float("nan")
        print(f"| {lv['name']} | {lv['setups']:,} | {per:.2f} | {lv['s_setup'] / 3600:.2f} | "
              f"{lv['s_setup'] / spent if spent else float('nan'):.3f} |")
    if len(levels) > 1:
        fine = min(levels, key=lambda k: levels[k]["ok"] + levels[k]["failed"])
        counts = sorted(per_design[fine].values())
        mean = sum(counts) / len(counts)
        print(f"\nfine evaluations per design ({levels[fine]['name']}): {len(counts)} designs, "
              f"min {counts[0]}, median {counts[len(counts) // 2]}, max {counts[-1]}, mean {mean:.1f}")
        for name, n in per_design[fine].most_common(5):
            print(f"  {n:4d}  {name}")
    stamps.sort()
    gap = args.gap_min * 60
    run_s = sum(d for d in ((b - a).total_seconds() for a, b in zip(stamps, stamps[1:])) if d <= gap)
    pauses = sum(1 for a, b in zip(stamps, stamps[1:]) if (b - a).total_seconds() > gap)
    span_h = (stamps[-1] - stamps[0]).total_seconds() / 3600
    print(f"\nwall time between the first and last stored row: {span_h:.2f} h; "
          f"without the {pauses} pause(s) longer than {args.gap_min:g} min: {run_s / 3600:.2f} h "
          f"({stamps[0]:%Y-%m-%d %H:%M} to {stamps[-1]:%Y-%m-%d %H:%M} UTC)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
