"""Calibrate physics parameters to measured presses: nlopt fit, uncertainty, predictive check.

The measured presses (one CSV row each: design keys, the touch, and ``v_rel`` or the 208 voltages) are read by
:mod:`latticeopt.study.presses`; voltage rows are compared as changes relative to their depth-0 reference row.

The fit minimises the sum of squared relative residuals ``(predicted - measured) / measured`` (``v_rel``
rows; voltage rows contribute their 208 relative changes, weighted ``1 / sqrt(208)`` so a press counts once)
over the chosen ``[physics]`` keys within their bounds, by nlopt's BOBYQA on the unit box. It never leaves the
bounds; a value that ends on one is reported as such (the data want a value outside them). Uncertainty:

* standard errors from the Gauss-Newton covariance ``s^2 (J^T J)^-1`` at the optimum, ``s^2 = RSS / (n - p)``,
  ``J`` by central differences (2 p extra predictions);
* a conditional profile per parameter (the others at their fitted values) over ``profile_points`` values,
  with the likelihood-ratio interval ``RSS <= RSS_min (1 + F(0.95; 1, n - p) / (n - p))``.

The predictive check fits on the rows ``fit_on`` selects and reports the residuals of the others.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..design import TABLE_KEYS
from ..errors import LatticeoptError, ParameterError
from .presses import Press, measured_changes, read_presses

__all__ = ["Calibration", "FitParameter", "Press", "calibrate", "coupled_predictor", "parse_fit", "read_presses"]

def _numeric_physics_keys() -> tuple[str, ...]:
    from ..coupled import PhysicsSettings

    return tuple(f.name for f in dataclasses.fields(PhysicsSettings) if isinstance(f.default, float))


@dataclass(frozen=True)
class FitParameter:
    """A numeric ``[physics]`` key fitted within ``[lower, upper]``."""

    name: str
    lower: float
    upper: float

    def __post_init__(self) -> None:
        from ..coupled import PhysicsSettings

        keys = _numeric_physics_keys()
        if self.name not in keys:
            raise ParameterError("--fit", "KEY=LOW:HIGH with KEY a numeric [physics] key: one of " + ", ".join(keys),
                                 self.name)
        if not (math.isfinite(self.lower) and math.isfinite(self.upper) and self.lower < self.upper):
            raise ParameterError(f"--fit {self.name}", "finite bounds LOW < HIGH", f"{self.lower}:{self.upper}")
        for end in (self.lower, self.upper):
            try:
                PhysicsSettings(**{self.name: end})
            except ParameterError as exc:
                raise ParameterError(f"--fit {self.name}", f"bounds inside the key's range ({exc.expected})",
                                     end) from None


def parse_fit(text: str) -> FitParameter:
    """``"hydrogel_shear_kPa=1:50"`` -> :class:`FitParameter`."""
    name, sep, rng = str(text).partition("=")
    lo, sep2, hi = rng.partition(":")
    try:
        lower, upper = float(lo), float(hi)
    except ValueError:
        lower = upper = math.nan
    if not (sep and sep2 and name.strip()) or math.isnan(lower) or math.isnan(upper):
        raise ParameterError("--fit", "KEY=LOW:HIGH, e.g. hydrogel_shear_kPa=1:50", text)
    return FitParameter(name.strip(), lower, upper)


def residuals(measured: Sequence[np.ndarray], predicted: Sequence[np.ndarray]) -> np.ndarray:
    """Relative residuals of all presses, concatenated (see the module docstring for the weights)."""
    parts = []
    for m, q in zip(measured, predicted):
        if m.size == 1:
            parts.append((q - m) / m)
        else:  # a voltage frame counts as one press
            parts.append((q - m) / np.sqrt(m.size))
    return np.concatenate(parts) if parts else np.zeros(0)


Predictor = Callable[[Sequence[Press], Mapping[str, float]], list[np.ndarray]]


def coupled_predictor(mesh_settings=None, physics: Mapping | None = None, cache_dir=None,
                      progress: Callable[[str], None] | None = None) -> Predictor:
    """The coupled model as a predictor: ``predict(presses, fitted) -> [v_rel] or 208 relative changes``.

    One :class:`~latticeopt.coupled.CoupledModel` per design and physics; the mesh comes from the cache.
    """
    from ..coupled import CoupledModel, PhysicsSettings

    base = dict(physics or {})

    def predict(presses: Sequence[Press], fitted: Mapping[str, float]) -> list[np.ndarray]:
        settings = PhysicsSettings.from_dict({**base, **fitted})
        models: dict[str, CoupledModel] = {}
        out = []
        for pr in presses:
            key = pr.design.content_hash()
            if key not in models:
                models[key] = CoupledModel(pr.design, mesh_settings, settings, cache_dir)
            model = models[key]
            if pr.touch.depth_mm == 0:
                res_v, ref = model.reference_voltages, model.reference_voltages
            else:
                res = model.simulate([pr.touch])
                res_v, ref = res.voltages, res.reference_voltages
            rel = (res_v - ref) / np.abs(ref)
            out.append(np.array([float(np.mean(np.abs(rel)))]) if pr.v_rel is not None else rel)
            if progress is not None:
                progress(f"row {pr.row}: {pr.design.describe()}, depth {pr.touch.depth_mm:g} mm")
        return out

    predict.mesh_settings = mesh_settings  # named in the calibration's figure (None: the default mesh)
    return predict


@dataclass(frozen=True)
class Calibration:
    """Result of :func:`calibrate` (values in the keys' units)."""

    parameters: tuple[FitParameter, ...]
    values: dict
    standard_errors: dict
    intervals: dict
    at_bound: tuple[str, ...]
    rss: float
    dof: int
    evaluations: int
    fit_rows: tuple[int, ...]
    rows: tuple[dict, ...]
    profiles: dict
    caption: str = ""

    def summary(self) -> dict:
        """JSON-ready (NaN as None)."""
        def clean(x):
            if isinstance(x, float) and not math.isfinite(x):
                return None
            if isinstance(x, dict):
                return {k: clean(v) for k, v in x.items()}
            if isinstance(x, (list, tuple)):
                return [clean(v) for v in x]
            return x

        return clean({"fitted": self.values, "standard_errors": self.standard_errors, "intervals_95": self.intervals,
                      "at_bound": list(self.at_bound), "rss": self.rss, "dof": self.dof,
                      "evaluations": self.evaluations, "fit_rows": list(self.fit_rows), "rows": list(self.rows),
                      "bounds": {p.name: [p.lower, p.upper] for p in self.parameters},
                      "profiles": {k: {"values": list(v[0]), "rss": list(v[1])} for k, v in self.profiles.items()}})


def _select(presses: Sequence[Press], fit_on: Mapping[str, Sequence[str]] | None) -> list[bool]:
    if not fit_on:
        return [True] * len(presses)
    chosen = []
    for pr in presses:
        ok = True
        for key, vals in fit_on.items():
            if key not in TABLE_KEYS:
                raise ParameterError("--fit-on", "KEY=V1,V2 with KEY a design key: one of " + ", ".join(TABLE_KEYS),
                                     key)
            val = getattr(pr.design, key) if hasattr(pr.design, key) else pr.field(key)
            ok &= any(_same(val, v) for v in vals)
        # a voltage reference row shares its presses' design keys, so it is selected with them
        chosen.append(ok)
    if not any(chosen) or all(chosen):
        raise ParameterError("--fit-on", "a selection keeping some rows for the fit and some for the check",
                             f"{sum(chosen)} of {len(presses)} rows selected")
    return chosen


def _same(val, text: str) -> bool:
    try:
        return abs(float(val) - float(text)) < 1e-9
    except (TypeError, ValueError):
        return str(val) == str(text)


def calibrate(presses: Sequence[Press], parameters: Sequence[FitParameter], predict: Predictor, *,
              fit_on: Mapping[str, Sequence[str]] | None = None, max_evals: int = 40, profile_points: int = 7,
              progress: Callable[[str], None] | None = None) -> Calibration:
    """Fit ``parameters`` to ``presses`` (module docstring); ``predict`` is :func:`coupled_predictor` or a test
    double."""
    import nlopt
    from scipy.stats import f as f_dist

    if not parameters:
        raise ParameterError("--fit", "at least one KEY=LOW:HIGH", "none")
    chosen = _select(presses, fit_on)
    fit_set = [pr for pr, c in zip(presses, chosen) if c]
    measured_all = measured_changes(presses)
    measured = [m for m, c in zip(measured_all, chosen) if c]
    n_res = sum(pr.touch.depth_mm > 0 for pr in fit_set)  # a voltage frame counts as one press
    p = len(parameters)
    if n_res <= p:
        raise ParameterError("--fit", f"fewer fitted parameters than fitted presses ({n_res} presses)", p)
    lo = np.array([q.lower for q in parameters])
    span = np.array([q.upper - q.lower for q in parameters])
    cache: dict[tuple, float] = {}

    def values(u: np.ndarray) -> dict:
        return {q.name: float(x) for q, x in zip(parameters, lo + np.clip(u, 0, 1) * span)}

    def rss(u: np.ndarray) -> float:
        key = tuple(np.round(np.clip(u, 0, 1), 12))
        if key not in cache:
            r = residuals(measured, predict(fit_set, values(np.array(key))))
            cache[key] = float(r @ r)
            if progress is not None:
                progress(f"evaluation {len(cache)}: {values(np.array(key))} -> RSS {cache[key]:.4g}")
        return cache[key]

    opt = nlopt.opt(nlopt.LN_BOBYQA if p > 1 else nlopt.LN_COBYLA, p)
    opt.set_lower_bounds([0.0] * p)
    opt.set_upper_bounds([1.0] * p)
    opt.set_min_objective(lambda u, grad: rss(np.asarray(u)))
    opt.set_maxeval(max_evals)
    opt.set_xtol_abs(1e-4)
    opt.set_initial_step(0.2)
    try:
        u = np.asarray(opt.optimize([0.5] * p))
    except (nlopt.RoundoffLimited, RuntimeError, ValueError) as exc:
        if not cache:
            raise LatticeoptError(f"calibration failed before any evaluation: {exc}") from None
        u = np.array(min(cache, key=cache.get))
    best = min(cache, key=cache.get)
    u = np.array(best) if cache[best] <= rss(u) else u
    rss_min = rss(u)
    dof = n_res - p
    s2 = rss_min / dof
    # Gauss-Newton covariance from central differences of the residual vector (in the keys' units).
    h = np.minimum(0.02, np.minimum(u, 1 - u) + 1e-12)
    h = np.where(h < 1e-6, 0.02, h)
    jac = []
    for k in range(p):
        up, dn = u.copy(), u.copy()
        up[k] = min(u[k] + h[k], 1.0)
        dn[k] = max(u[k] - h[k], 0.0)
        r_up = residuals(measured, predict(fit_set, values(up)))
        r_dn = residuals(measured, predict(fit_set, values(dn)))
        jac.append((r_up - r_dn) / ((up[k] - dn[k]) * span[k]))
    J = np.stack(jac, axis=1)
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
        se = {q.name: float(np.sqrt(max(cov[k, k], 0.0))) for k, q in enumerate(parameters)}
    except np.linalg.LinAlgError:
        se = {q.name: math.inf for q in parameters}
    # Conditional profiles and likelihood-ratio intervals.
    limit = rss_min * (1 + f_dist.ppf(0.95, 1, dof) / dof)
    profiles, intervals = {}, {}
    for k, q in enumerate(parameters):
        if profile_points < 2:
            break
        grid = np.union1d(np.linspace(0, 1, profile_points), [u[k]])
        vals = []
        for g in grid:
            uu = u.copy()
            uu[k] = g
            vals.append(rss(uu))
        xs = lo[k] + grid * span[k]
        profiles[q.name] = (xs.tolist(), vals)
        inside = [x for x, r in zip(xs, vals) if r <= limit] + [lo[k] + u[k] * span[k]]
        intervals[q.name] = [float(min(inside)), float(max(inside))]
    fitted = values(u)
    at_bound = tuple(q.name for k, q in enumerate(parameters) if u[k] < 1e-3 or u[k] > 1 - 1e-3)
    predicted = predict(presses, fitted)
    rows = []
    for pr, m, q, c in zip(presses, measured_all, predicted, chosen):
        r = residuals([m], [q])
        rows.append({"row": pr.row, "design": pr.design.describe(), "depth_mm": pr.touch.depth_mm,
                     "used_in_fit": bool(c), "measured": float(m[0]) if m.size == 1 else float(np.mean(np.abs(m))),
                     "predicted": float(q[0]) if q.size == 1 else float(np.mean(np.abs(q))),
                     "relative_residual": float(np.sqrt(r @ r))})
    return Calibration(tuple(parameters), fitted, se, intervals, at_bound, rss_min, dof, len(cache),
                       tuple(pr.row for pr in fit_set), tuple(rows), profiles, _caption(presses, fit_set, predict))


def _caption(presses: Sequence[Press], fit_set: Sequence[Press], predict: Predictor) -> str:
    """What the calibration figure shows: the presses (fitted and held out), their layouts and the mesh."""
    from ..captions import layout_caption, mesh_caption
    from ..mesh import MeshSettings

    places = sorted({(pr.touch.x_mm, pr.touch.y_mm, pr.touch.radius_mm) for pr in presses})
    where = (f"r = {places[0][2]:g} mm at ({places[0][0]:g}, {places[0][1]:g}) mm" if len(places) == 1
             else f"{len(places)} places")
    text = (f"{len(presses)} measured presses ({len(fit_set)} fitted, {len(presses) - len(fit_set)} held out), "
            f"{where}\n{layout_caption(pr.design for pr in presses)}")
    if hasattr(predict, "mesh_settings"):  # the coupled model; a test double has no mesh
        settings = predict.mesh_settings or MeshSettings()
        meshes = {mesh_caption(settings.resolved(pr.design).as_dict()) for pr in presses}
        text += "; " + " or ".join(sorted(meshes))
    return text


def plot_calibration(cal: Calibration, path: Path) -> Path:
    """Measured against predicted (fit rows filled, held-out rows open) and the conditional profiles."""
    from matplotlib.figure import Figure

    n_prof = len(cal.profiles)
    fig = Figure(figsize=(5.0 + 4.0 * n_prof, 4.4), layout="constrained")
    axes = fig.subplots(1, 1 + n_prof, squeeze=False)[0]
    ax = axes[0]
    for used, style in ((True, "o"), (False, "s")):
        pts = [(r["measured"], r["predicted"]) for r in cal.rows if r["used_in_fit"] == used]
        if pts:
            m, q = zip(*pts)
            ax.plot(m, q, style, mfc="C0" if used else "none", mec="C0",
                    label="fitted rows" if used else "held-out rows (predicted)")
    lim = [0, 1.1 * max(max(r["measured"], r["predicted"]) for r in cal.rows)]
    ax.plot(lim, lim, "k--", lw=0.8, label="measured = predicted")
    ax.set_xlim(lim)
    ax.set_ylim(lim)
    ax.set_xlabel("measured (V_rel or mean |dV/V|)")
    ax.set_ylabel("predicted")
    fitted = ", ".join(f"{k} = {v:.4g} ± {cal.standard_errors[k]:.2g}" for k, v in cal.values.items())
    ax.set_title(fitted, fontsize="small")
    ax.legend(fontsize="small")
    for ax, (name, (xs, vals)) in zip(axes[1:], cal.profiles.items()):
        ax.plot(xs, vals, "o-")
        ax.axvline(cal.values[name], color="k", lw=0.8)
        lo, hi = cal.intervals[name]
        ax.axvspan(lo, hi, color="C1", alpha=0.2, label="95 % likelihood-ratio interval")
        ax.set_xlabel(name)
        ax.set_ylabel("sum of squared relative residuals")
        ax.set_title("conditional profile (others at their fit)", fontsize="small")
        ax.legend(fontsize="small")
    if cal.caption:
        from ..captions import wrap_title

        fig.suptitle(wrap_title(f"calibration: {cal.caption}", 110), fontsize=9.5)
    fig.savefig(path, dpi=130)
    return path
