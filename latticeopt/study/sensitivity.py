"""How robust is a verdict: re-run a study under each uncertain input and report what moves.

``latticeopt sensitivity STUDY.toml --vary KEY=V1,V2 ...`` runs the study once as it is (the baseline) and once
per value of every varied key, one key at a time, each run in its own folder (``<out>/sensitivity/KEY=VALUE``, a
normal resumable sweep store). A key is any dotted study key (``physics.hydrogel_shear_kPa``, ``design.rim``,
``mesh.size_mm``); a bare ``[physics]`` key or design key is completed to ``physics.KEY`` or ``design.KEY``.

Figures per run: for a press study, V_rel of every design at the deepest depth and every ``[[press.compare]]``
ratio (deterministic: a press has no phantom sampling, so its error is the mesh error, which the study's mesh
fixes); for a grid study, every design's mean V_rel with its standard error over the common phantoms, and the
best design. The table has one row per run; the tornado plot shows, per key, how far each figure moves from
the baseline over the values tried, with the sampling error (grid studies) as error bars.
"""

from __future__ import annotations

import copy
import csv
import math
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..design import TABLE_KEYS
from ..errors import AllFailedError, ParameterError
from .config import Study, read_study_table, set_key, study_from_dict

__all__ = ["Variation", "load_variants", "parse_vary", "run_sensitivity", "plot_tornado", "write_table"]


@dataclass(frozen=True)
class Variation:
    """A dotted study key and the values it takes (one run each)."""

    key: str
    values: tuple


def parse_vary(text: str) -> Variation:
    """``"hydrogel_shear_kPa=2,15"`` -> ``Variation("physics.hydrogel_shear_kPa", (2, 15))`` (TOML values)."""
    from ..coupled import PhysicsSettings

    key, sep, vals = str(text).partition("=")
    key = key.strip()
    items = [v.strip() for v in vals.split(",") if v.strip()]
    if not sep or not key or not items:
        raise ParameterError("--vary", "KEY=V1,V2,... e.g. hydrogel_shear_kPa=2,15 or design.rim=channel", text)
    if "." not in key:
        physics = PhysicsSettings.__dataclass_fields__
        if key in physics:
            key = f"physics.{key}"
        elif key in TABLE_KEYS:
            key = f"design.{key}"
        else:
            raise ParameterError("--vary", "a dotted study key, a [physics] key (" + ", ".join(physics) + ") or a "
                                 "design key (" + ", ".join(TABLE_KEYS) + ")", key)
    values = []
    for item in items:
        try:
            values.append(tomllib.loads(f"v = {item}")["v"])
        except tomllib.TOMLDecodeError:
            values.append(item)
    if len({repr(v) for v in values}) != len(values):
        raise ParameterError(f"--vary {key}", "distinct values", items)
    return Variation(key, tuple(values))


def _label(key: str, value) -> str:
    return f"{key}={value}"


def load_variants(path: str | Path, variations: Sequence[Variation], overrides: Sequence[str] = (),
                  physics: Mapping[str, object] | None = None) -> list[tuple[str, str | None, object, Study]]:
    """The baseline and every variant as validated studies (all checked before any work).

    The file is read once (``overrides`` and ``physics`` as in :func:`~latticeopt.study.config.read_study_table`);
    each variant sets its value in a copy of that table. Returns ``(label, key, value, study)`` rows; the baseline
    has key and value ``None``.
    """
    raw, named = read_study_table(path, overrides, physics)

    def variant(out: Path, key: str | None = None, value: object = None) -> Study:
        table = copy.deepcopy(raw)
        if key is not None:
            set_key(table, key, value, flag="--vary")
        table["out"] = out.as_posix()
        where = {**named, **({key: f"--vary {key}"} if key is not None else {})}
        return study_from_dict(table, source=str(path), overridden=where, default_name=Path(path).stem)

    base = study_from_dict(raw, source=str(path), overridden=named, default_name=Path(path).stem)
    if base.kind == "probes":  # its figures would be a mean over the probes, with a sampling SE a fixed grid lacks
        raise ParameterError(f"{path}: kind", "'grid' or 'press' in a sensitivity study (its figures are mean V_rel "
                             "and press ratios; the probe grid's uniformity is not one of them)", base.kind)
    if base.adaptive is not None:  # every run must be compared on the same, full phantom set
        raise ParameterError(f"{path}: phantoms.target_se", "no adaptive phantom counts in a sensitivity study (each "
                             "run is summarized over every phantom)", base.adaptive.target_se)
    if base.kind == "grid" and len(base.designs) * len(base.phantoms) > 400:
        raise ParameterError("STUDY", "a press study or a small grid (at most 400 evaluations per run)",
                             f"{len(base.designs)} designs x {len(base.phantoms)} phantoms")
    root = base.out_dir / "sensitivity"
    runs = [("baseline", None, None, variant(root / "baseline"))]
    for var in variations:
        for val in var.values:
            label = _label(var.key, val)
            try:
                study = variant(root / label, var.key, val)
            except ParameterError as exc:
                raise ParameterError(f"--vary {var.key}", exc.expected, exc.got) from None
            runs.append((label, var.key, val, study))
    return runs


def figures(study: Study, evaluations) -> dict:
    """The figures of one run (module docstring): name -> (value, standard error or NaN)."""
    from .report import _by_design, _fmt, best_design, press_ratios, summarize

    out = {}
    if study.kind == "press":
        for design, group in zip(study.designs, _by_design(study, evaluations)):
            last = group[-1]
            out[f"V_rel {_fmt(design, study.grid_fields)}"] = (last.v_rel if last.ok else math.nan, math.nan)
        for r in press_ratios(study, evaluations):
            out[f"ratio {r['label']}"] = (r["ratio"], math.nan)
    else:
        for design, s in zip(study.designs, summarize(study, evaluations)):
            out[f"V_rel {_fmt(design, study.grid_fields)}"] = (s["v_rel_mean"], s["v_rel_se"])
        best = best_design(study, evaluations)
        out["best design"] = (_fmt(best["design"], study.grid_fields) if best else "none", math.nan)
    return out


def run_sensitivity(runs, run: Callable[[Study], object], progress: Callable[[str], None] | None = None
                    ) -> list[dict]:
    """Run every study (``run(study) -> SweepResult``) and collect one row of figures per run."""
    rows = []
    for label, key, value, study in runs:
        if progress is not None:
            progress(f"== {label} ==")
        try:
            res = run(study)
        except AllFailedError as exc:  # this input breaks every phantom: a finding, not a reason to stop
            rows.append({"run": label, "key": key, "value": value, "figures": {}, "failed": study.n_tasks,
                         "error": str(exc), "caption": caption(study)})
            continue
        rows.append({"run": label, "key": key, "value": value, "figures": figures(study, res.evaluations),
                     "failed": sum(not e.ok for e in res.evaluations), "caption": caption(study)})
    return rows


def write_table(rows: Sequence[dict], path: Path) -> Path:
    """One CSV row per run: the run, the varied key and value, every figure and its SE."""
    names = list(dict.fromkeys(n for r in rows for n in r["figures"]))
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["run", "key", "value", "failed", *[c for n in names for c in (n, f"{n} SE")]])
        for r in rows:
            cells = []
            for n in names:
                val, se = r["figures"].get(n, (math.nan, math.nan))
                cells += [val, se]
            w.writerow([r["run"], r["key"] or "", "" if r["value"] is None else r["value"], r["failed"], *cells])
    return path


def plot_tornado(rows: Sequence[dict], path: Path) -> Path | None:
    """Per numeric figure, how far each varied key moves it from the baseline (bars from the lowest to the highest
    value over the key's values, error bars = sampling SE)."""
    from matplotlib.figure import Figure

    base = rows[0]["figures"]
    names = [n for n, (v, _) in base.items() if isinstance(v, float) and math.isfinite(v)]
    keys = list(dict.fromkeys(r["key"] for r in rows[1:]))
    if not names or not keys:
        return None
    fig = Figure(figsize=(6.0 * min(len(names), 3), 0.6 * len(keys) + 2.2 + 3.0 * ((len(names) - 1) // 3)),
                 layout="constrained")
    axes = fig.subplots((len(names) + 2) // 3, min(len(names), 3), squeeze=False).ravel()
    for ax, name in zip(axes, names):
        b = base[name][0]
        spans = []
        for key in keys:
            vals = [(r["value"], *r["figures"].get(name, (math.nan, math.nan))) for r in rows[1:] if r["key"] == key]
            spans.append((key, vals))
        spans.sort(key=lambda kv: max((abs(v - b) for _, v, _ in kv[1] if math.isfinite(v)), default=0))
        reach = [b]
        for i, (_key, vals) in enumerate(spans):
            finite = [(lab, v, se) for lab, v, se in vals if math.isfinite(v)]
            if not finite:
                continue
            # the bar runs from the baseline too, so a key tried at one value shows how far it moves the figure
            lo, hi = min(b, *(v for _, v, _ in finite)), max(b, *(v for _, v, _ in finite))
            ax.barh(i, hi - lo, left=lo, color="C0", alpha=0.5)
            for j, (lab, v, se) in enumerate(sorted(finite, key=lambda f: f[1])):
                ax.errorbar(v, i, xerr=None if math.isnan(se) else se, fmt="o", color="C0", capsize=3)
                # the lower value's label under its marker, the higher one's above: two values close to
                # each other (a key that hardly moves the figure) would otherwise print over each other
                ax.annotate(str(lab), (v, i), textcoords="offset points", xytext=(0, 6 if j % 2 else -6),
                            ha="center", va="bottom" if j % 2 else "top", fontsize=7)
                reach += [v - (0 if math.isnan(se) else se), v + (0 if math.isnan(se) else se)]
        ax.axvline(b, color="k", lw=0.8)
        lo, hi = min(reach, default=b), max(reach, default=b)
        pad = 0.12 * (hi - lo) or 0.05 * abs(b) or 1.0  # markers and error bars clear of the frame
        ax.set_xlim(lo - pad, hi + pad)
        ax.set_ylim(-0.7, len(spans) - 0.3)
        ax.set_yticks(range(len(spans)), [k for k, _ in spans], fontsize=8)
        ax.set_title(name, fontsize=9)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    fig.suptitle(_tornado_title(rows), fontsize=10)
    fig.savefig(path, dpi=120)
    return path


def caption(study: Study) -> str:
    """What a run's figures are over: its layout, phantoms and mesh (the tornado plot's title gives the
    baseline's; a variant that changes one of them is named on its bar)."""
    from ..captions import layout_caption
    from .plots import _mesh_caption

    if study.kind == "press":
        t = study.phantoms[-1].touches[0]
        what = (f"one press, r = {t.radius_mm:g} mm at ({t.x_mm:g}, {t.y_mm:g}) mm, figures at "
                f"{t.depth_mm:g} mm deep")
    else:
        what = f"{len(study.phantoms)} phantoms per design"
    return f"{layout_caption(study.designs)}; {what}\n{_mesh_caption(study).splitlines()[0]}"


def _tornado_title(rows: Sequence[dict]) -> str:
    from ..captions import wrap_title

    first = "sensitivity: each key varied alone (black line: baseline)"
    return wrap_title(f"{first}\n{rows[0]['caption']}" if rows[0].get("caption") else first, 120)
