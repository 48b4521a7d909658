"""A front of response against uniformity for density-layout studies, with the parametric lattices beside it.

A ``kind = "graded"`` or ``"freeform"`` study with ``front = [u1, u2, ...]`` in its table runs one optimization per
point, each its own resumable run folder under the output folder: ``free`` (no uniformity floor: the most
responsive layout) and ``u<value>`` (maximize the mean V_rel subject to ``uniformity >= value``: the
epsilon-constraint method). Every point presses the probe grid (:mod:`latticeopt.optimize.probes`). Beside them
the parametric lattices (:data:`REFERENCES`: every family at the study's thickness and pitch, no rim channel, and
the uniform layer) are scored on the *same* density model, phantoms and probes, each as its exact-area density
(:func:`~latticeopt.density.field.density_of_design`), so every point of the plot comes from one model.

Outputs: ``front.csv`` (a row per point: kind, label, mean V_rel, uniformity, worst-to-best ratio, gel fraction,
the point's floor and whether its final layout meets it, folder, and the rows that dominate it: at least its
uniformity and more response, see :func:`dominated_by`; the smallest reference row over the largest and whether
V_rel divides by round-off), ``front.png`` (mean V_rel against uniformity),
``references.json`` (the lattices' results, kept between runs). A point whose ``final.json`` matches its settings
is read, not run again; an interrupted point resumes from its ``state.json``.
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from ..errors import ParameterError
from ..metric import smallest_reference_rel

#: The parametric reference lattices: family -> channel widths (mm); width 0 is the uniform layer.
REFERENCES = {"uniform": (0.0,), "square": (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0),
              "hexagonal": (2.0, 4.0, 6.0), "triangular": (2.0, 4.0, 6.0), "diagonal": (2.0, 4.0, 6.0)}


def front_points(cfg) -> list[tuple[str, object]]:
    """``(label, config)`` of every point of ``cfg.front``: ``free`` first, then one per uniformity floor.

    Each point's settings are those of the study run on its own with ``--set <table>.probes=true`` (``free``) or
    ``--set <table>.min_uniformity=<u>`` and no ``front``: such a run into the point's folder is the point."""
    base = replace(cfg, front=())
    return [("free", replace(base, probes=True))] + [(f"u{u:.3f}", replace(base, min_uniformity=u)) for u in cfg.front]


def reference_designs(design) -> list[tuple[str, object]]:
    """``(label, design)`` of :data:`REFERENCES` on ``design``'s sensor (thickness, pitch, electrodes)."""
    out = []
    for family, widths in REFERENCES.items():
        for w in widths:
            d = design.replace(pattern="square" if family == "uniform" else family, width_mm=w, rim="none",
                               custom_polygons_mm=())
            out.append((family if w == 0 else f"{family} w{w:g}", d))
    return out


def describe_front(study, out: Path) -> list[str]:
    """What a front run will do (``--dry-run``): one line per point and one for the references."""
    cfg = study.config
    lines = [f"{study.name} ({study.kind}) front: {len(cfg.front) + 1} optimizations of mean V_rel over "
             f"{len(study.phantoms)} phantoms, probes {cfg.probe_grid} x {cfg.probe_grid} (radius "
             f"{cfg.probe_radius_mm:g} mm, {cfg.probe_depth_mm:g} mm deep); mesh {study.mesh.size_mm:g} mm, "
             f"{cfg.cells} x {cfg.cells} cells; out {out}"]
    for label, c in front_points(cfg):
        floor = "none" if c.min_uniformity is None else f"{c.min_uniformity:g}"
        done = " (done)" if _finished(study, c, out / label) else ""
        lines.append(f"  point {label}: uniformity >= {floor} -> {out / label}{done}")
    refs = reference_designs(study.design)
    lines.append(f"  references: {len(refs)} parametric layouts (" + ", ".join(lab for lab, _ in refs) + ")")
    return lines


def _finished(study, cfg, folder: Path) -> dict | None:
    from .identity import run_identity, same_run

    path = folder / "final.json"
    if not (path.is_file() and (folder / "report.txt").is_file()):
        return None
    final = json.loads(path.read_text())
    identity = run_identity(study.design, list(study.phantoms), study.mesh, study.physics, cfg)
    same = same_run(final.get("identity"), identity)
    return final if same and "uniformity" in final else None


def run_front(study, out_dir, progress: Callable[[str], None] | None = print, jobs: int = 1) -> dict:
    """Run (or resume) every point of ``study.config.front`` and the references; write the table and the plot
    (``jobs`` worker processes press the phantoms of each layout).

    Returns
    -------
    dict
        ``points`` and ``references`` (rows of ``front.csv``), ``files``, and ``warnings`` (lines naming the
        layouts whose V_rel divides by reference rows at round-off, when no instrument floor lifts them).
    """
    from ..density import DensityModel
    from ..density.field import load_density
    from ..study.report_lines import at_round_off, round_off_lines
    from .freeform import run_freeform
    from .graded import run_graded

    reference_designs(study.design)  # every reference layout valid on this sensor, before any work
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run = run_freeform if study.kind == "freeform" else run_graded

    @functools.cache
    def model():  # built on first use: a front whose every point and lattice is stored needs none
        return DensityModel(study.design, study.config.cells, study.mesh, study.physics)

    points = []
    for label, cfg in front_points(study.config):
        folder = out / label
        final = _finished(study, cfg, folder)
        if final is None:
            if progress:
                progress(f"== front point {label} ==")
            t0 = time.perf_counter()
            run(study.design, list(study.phantoms), study.mesh, study.physics, cfg, folder, progress=progress,
                jobs=jobs)
            final = _finished(study, cfg, folder)
            if progress:
                progress(f"point {label}: {time.perf_counter() - t0:.0f} s")
        elif progress:
            progress(f"point {label}: done before, read from {folder / 'final.json'}")
        if "min_reference_rel" not in final:  # a point run before final.json kept it: one electrics solve
            rho = load_density(folder / "density.npz", str(folder / "density.npz"))
            final = {**final, "min_reference_rel": smallest_reference_rel(model().reference_voltages(rho))}
        points.append(_row("optimized", label, final, folder))
    references = _references(study, out, progress, jobs, model)
    rows = points + references
    floor_rel = study.physics.measurement_floor_rel
    for row in rows:
        row["round_off"] = at_round_off(row["min_reference_rel"], floor_rel)
    for row, better in zip(rows, dominated_by(rows)):
        row["dominated_by"] = "; ".join(better)
        if better and row["kind"] == "optimized" and progress:
            progress(f"point {row['label']} is dominated by {', '.join(better)}: each has at least its uniformity "
                     f"and responds more")
    files = {"table": str(_write_table(out / "front.csv", rows)),
             "plot": str(plot_front(out / "front.png", points, references, _title(study)))}
    warnings = round_off_lines([(r["label"], r["min_reference_rel"]) for r in rows], floor_rel)
    return {"points": points, "references": references, "files": files, "warnings": warnings}


def dominated_by(rows: list[dict]) -> list[list[str]]:
    """For each row (``label``, ``uniformity``, ``v_rel``), the labels of the rows that dominate it: at least its
    uniformity and at least its mean V_rel, one of them strictly more.

    A point of the epsilon-constraint front dominated by another layout of the table is not on the front: that
    layout meets the point's floor and responds more, so it answers the point's question better (MMA can overshoot
    a floor and not come back within its iterations)."""
    out = []
    for p in rows:
        out.append([q["label"] for q in rows
                    if q["uniformity"] >= p["uniformity"] and q["v_rel"] >= p["v_rel"]
                    and (q["uniformity"] > p["uniformity"] or q["v_rel"] > p["v_rel"])])
    return out


def _row(kind: str, label: str, final: dict, folder) -> dict:
    from .probes import FLOOR_TOL, floor_of

    floor = floor_of(final)
    return {"kind": kind, "label": label, "v_rel": final["v_rel"], "uniformity": final["uniformity"],
            "worst_to_best": final["probe_worst_to_best"], "hydrogel_fraction": final["hydrogel_fraction"],
            "min_uniformity": "" if floor is None else floor,
            "floor_met": "" if floor is None else final["uniformity"] >= floor - FLOOR_TOL,
            "min_reference_rel": final["min_reference_rel"], "folder": str(folder)}


def _references(study, out: Path, progress, jobs: int, model: Callable) -> list[dict]:
    """Score :data:`REFERENCES` on the study's density model ``model()`` (resumable through ``references.json``)."""
    from ..density.field import density_of_design
    from .freeform import _write_json
    from .identity import run_identity, same_run
    from .probes import ProbeGrid

    cfg = replace(study.config, front=(), min_uniformity=None, probes=True)
    identity = run_identity(study.design, list(study.phantoms), study.mesh, study.physics, cfg)
    path = out / "references.json"
    stored = json.loads(path.read_text()) if path.is_file() else {"identity": identity, "points": {}}
    if not same_run(stored.get("identity"), identity):
        raise ParameterError("out", "a front folder of this same study (references.json holds another study's "
                             "settings; choose another --out)", str(out))
    probes = None
    rows = []
    for label, design in reference_designs(study.design):
        if label not in stored["points"]:
            if probes is None:
                probes = ProbeGrid(study.design, cfg)
            t0 = time.perf_counter()
            rho = density_of_design(design, cfg.cells)
            ev = model().evaluate(rho, list(study.phantoms), gradient=False, jobs=jobs)
            pe = probes.solve(model(), rho, gradient=False, jobs=jobs)
            stored["points"][label] = {"v_rel": ev.v_rel, "uniformity": pe.uniformity,
                                       "probe_worst_to_best": pe.worst_to_best,
                                       "hydrogel_fraction": float(rho.mean()), "probes_solved": pe.solved,
                                       "min_reference_rel": smallest_reference_rel(ev.reference_voltages)}
            _write_json(path, stored)
            if progress:
                progress(f"reference {label}: mean V_rel {ev.v_rel:.5f}, uniformity {pe.uniformity:.4f} "
                         f"({pe.solved} probes solved, {time.perf_counter() - t0:.0f} s)")
        elif "min_reference_rel" not in stored["points"][label]:  # scored before references.json kept it
            rho = density_of_design(design, cfg.cells)
            stored["points"][label]["min_reference_rel"] = smallest_reference_rel(
                model().reference_voltages(rho))
            _write_json(path, stored)
        rows.append(_row("reference", label, stored["points"][label], path))
    return rows


def _title(study) -> str:
    cfg = study.config
    return (f"{study.name}: mean V_rel against uniformity ({study.kind}), mesh {study.mesh.size_mm:g} mm, "
            f"{cfg.cells} x {cfg.cells} cells, {len(study.phantoms)} phantoms, {cfg.probe_grid} x {cfg.probe_grid} "
            f"probes (r {cfg.probe_radius_mm:g} mm, {cfg.probe_depth_mm:g} mm deep)")


def _write_table(path: Path, rows: list[dict]) -> Path:
    import csv

    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return path


def draw_front(ax, points: list[dict], references: list[dict], mark_dominated: bool = False) -> None:
    """Draw the optimized points (``label``, ``uniformity``, ``v_rel``, ``floor_met``) joined in order of
    uniformity, and the reference lattices (``label`` as "<family> w<width>") in a marker per family, on ``ax``;
    with ``mark_dominated``, an optimized point that another one dominates (:func:`dominated_by`) is drawn apart."""
    # a point that missed its floor, or that another optimized point dominates, is drawn hollow and left off the
    # line: the optimizer stopped short of it
    beaten = [p for p, b in zip(points, dominated_by(points)) if mark_dominated and b and p["floor_met"] is not False]
    missed = [p for p in points if p["floor_met"] is False]
    on = sorted((p for p in points if p not in missed and p not in beaten), key=lambda p: p["uniformity"])
    ax.plot([p["uniformity"] for p in on], [p["v_rel"] for p in on], "o-", color="k", ms=6,
            label="optimized (epsilon-constraint)", zorder=3)
    if missed:
        ax.plot([p["uniformity"] for p in missed], [p["v_rel"] for p in missed], "o", mfc="white", mec="k", ms=6,
                zorder=4, label="floor not reached")
    if beaten:
        ax.plot([p["uniformity"] for p in beaten], [p["v_rel"] for p in beaten], "o", mfc="white", mec="0.5", ms=6,
                zorder=4, label="dominated by another optimized point")
    # labels alternate above and below in order of uniformity: neighbouring points on the front do not overprint
    for i, p in enumerate(sorted(points, key=lambda p: p["uniformity"])):
        ax.annotate(p["label"], (p["uniformity"], p["v_rel"]), textcoords="offset points",
                    xytext=(5, 4 if i % 2 == 0 else -10), fontsize=7)
    shaky = [r for r in points + references if r.get("round_off")]
    if shaky:
        ax.plot([r["uniformity"] for r in shaky], [r["v_rel"] for r in shaky], "x", color="red", ms=9, zorder=5,
                label="V_rel divides by rows at round-off")
    markers = {"uniform": "*", "square": "s", "hexagonal": "h", "triangular": "^", "diagonal": "D"}
    for family, marker in markers.items():
        rows = [r for r in references if r["label"].split()[0] == family]
        if not rows:
            continue
        line, = ax.plot([r["uniformity"] for r in rows], [r["v_rel"] for r in rows], marker, ms=6, alpha=0.8,
                        linestyle=":" if len(rows) > 1 else "none", label=family)
        for r in rows:
            if " " in r["label"]:
                ax.annotate(r["label"].split()[1], (r["uniformity"], r["v_rel"]), textcoords="offset points",
                            xytext=(4, -8), fontsize=6, color=line.get_color())


def plot_front(path: Path, points: list[dict], references: list[dict], title: str) -> Path:
    """Mean V_rel against uniformity: the optimized points joined in order of their floor, every reference
    family in its own marker with its widths written beside it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.0, 5.0), layout="constrained")
    draw_front(ax, points, references, mark_dominated=True)
    ax.set_xlabel("uniformity over the probe grid (1 - CV of V_rel)")
    ax.set_ylabel("mean V_rel over the study's phantoms")
    ax.set_title(title, fontsize=8, wrap=True)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
