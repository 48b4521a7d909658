"""What the optimizer maximizes: statistics of V_rel over a design's fixed phantom set.

Every design is evaluated on the *same* phantoms (common random numbers, :mod:`latticeopt.study.phantoms`), so a
difference between two designs is a difference of designs, not of draws, and the objective is a deterministic
function of the design (no sampling noise along the optimizer's path). The terms:

``mean``
    Mean V_rel over the study's random phantoms (the paper's metric, eq. 5 averaged over phantoms).
``robust``
    The lower ``quantile`` (default 0.1: the lower decile) of V_rel over the same phantoms
    (``numpy.quantile``, linear interpolation): how well the design does on its worse touches.
``uniformity``
    Spatial uniformity of sensitivity: ``1 - std / mean`` (population coefficient of variation, ``ddof = 0``)
    of V_rel over a *probe grid* of single touches, identical but for their location: one touch of
    ``probe_radius_mm`` pressed ``probe_depth_mm`` at the centre of every cell of an ``n x n`` partition of the
    sensor (:meth:`Objective.probes`). 1 means every location reads the same V_rel; it is 1 - CV, so it can
    be negative when the spread exceeds the mean. A separate probe set is used, not the random phantoms binned
    by position, because random touches differ in depth, radius and count as well as in location.
``image_cc``
    What a user finally sees is an image: the mean Pearson correlation between the one-step Tikhonov image of
    every probe press (the same probe grid) and its true footprint, a disc of the punch radius at the press
    centre (:mod:`latticeopt.study.imaging`, which also reports the mean GREIT position error in mm beside it).
    The images use the design's own pixel Jacobian at the study's mesh settings, the prior ``image_prior``
    and a *fixed* ``lambda = image_lambda x`` the largest eigenvalue of that design's ``A P^-1 A^T``; why fixed
    and why relative: :mod:`latticeopt.study.imaging`. 1 is a perfect image (up to an affine map of its values).

The score is ``sum(weight_k * term_k)`` with weights >= 0 (the terms have different scales: mean V_rel is a few
percent while uniformity and image_cc are near 1, so choose weights with that in mind). Its standard error over
the phantoms: for ``mean`` alone the usual ``std(ddof=1) / sqrt(n)``; otherwise a bootstrap over phantoms (random
phantoms and probes resampled independently, a probe's V_rel and image correlation together, a fixed seed,
:attr:`Objective.bootstrap` resamples) — deterministic, so a resumed run reports the same numbers. Paired
differences between two designs resample the *same* phantom indices for both, which is what common random
numbers buy.

Failed phantoms. A design is scored on *all* its phantoms or not at all: a failed phantom (NaN) makes the score
NaN, which the optimizer treats as infeasible. Scoring a design on its successes only would compare designs over
different phantom sets — a design whose hardest presses fail would be averaged over easier ones and could beat
one that solved them — and an optimizer cannot use the sweep report's alternative (the phantoms every design
solved), because that set shrinks as candidates arrive and would change the scores it has already compared.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ..study.phantoms import Phantom, ProbePresses, uniformity

__all__ = ["PROBE_TERMS", "TERMS", "Objective", "ObjectiveValue", "Term"]
_BOOTSTRAP_SEED = 20250101


def _mean(o, r, p, c):
    return float(np.mean(r)) if r.size else math.nan


def _mean_grad(o, r, p, gr, gp):
    return np.mean(gr, axis=0), None


def _robust(o, r, p, c):
    return float(np.quantile(r, o.quantile)) if r.size else math.nan


def _robust_grad(o, r, p, gr, gp):
    # numpy's linear quantile: the two order statistics around position q (n - 1), linearly weighted
    pos = o.quantile * (r.size - 1)
    order = np.argsort(r, kind="stable")
    lo, frac = int(np.floor(pos)), pos - np.floor(pos)
    hi = min(lo + 1, r.size - 1)
    return (1 - frac) * gr[order[lo]] + frac * gr[order[hi]], None


def _uniformity(o, r, p, c):
    return uniformity(p)


def _uniformity_grad(o, r, p, gr, gp):
    # 1 - s/m with s the population std: d/dp_k = -(p_k - m) / (n s m) + s / (n m^2)
    n, m, s = p.size, float(np.mean(p)), float(np.std(p))
    w = -(p - m) / (n * s * m) + s / (n * m * m) if s > 0 else np.full(n, 0.0)
    return None, np.tensordot(w, gp, axes=1)


def _image_cc(o, r, p, c):
    return float(np.mean(c)) if c.size else math.nan


@dataclass(frozen=True)
class Term:
    """One objective term: its meaning, the data it needs, its value and (where the adjoint reaches) its gradient.

    ``value(objective, random_v, probe_v, probe_cc) -> float``; ``gradient(objective, random_v, probe_v,
    random_grads, probe_grads) -> (d/d layout through the random phantoms or None, through the probes or None)``,
    the grads stacked per phantom (shape ``(n, ...)``); None: no gradient (``image_cc`` goes through a
    reconstruction).
    """

    name: str
    description: str
    needs: str
    value: object
    gradient: object = None
    label: object = None

    def describe(self, objective) -> str:
        return self.label(objective) if self.label else self.name


#: The objective terms, in score order: the one table of their meanings, data, values and gradients.
TERMS = {t.name: t for t in (
    Term("mean", "mean V_rel over the random phantoms", "random", _mean, _mean_grad, lambda o: "mean V_rel"),
    Term("robust", "lower quantile of V_rel over the random phantoms", "random", _robust, _robust_grad,
         lambda o: f"q{o.quantile:g} V_rel"),
    Term("uniformity", "1 - coefficient of variation of V_rel over the probe grid", "probes", _uniformity,
         _uniformity_grad),
    Term("image_cc", "mean correlation of the probe presses' one-step images with their footprints", "images",
         _image_cc, None, lambda o: f"image CC ({o.image_prior}, lambda {o.image_lambda:g})"),
)}
#: Terms computed on the probe grid.
PROBE_TERMS = tuple(k for k, t in TERMS.items() if t.needs in ("probes", "images"))


@dataclass(frozen=True)
class ObjectiveValue:
    """An objective evaluated on one design.

    Attributes
    ----------
    score
        ``sum(weight * term)``; NaN when a phantom failed or a needed term is undefined.
    se
        Standard error of the score over the phantoms.
    terms
        Every term with a non-zero weight, name -> value.
    """

    score: float
    se: float
    terms: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Objective:
    """Weights of the terms (:data:`TERMS`) and their settings.

    Parameters
    ----------
    weights
        ``(term, weight)`` pairs, weights >= 0, at least one > 0.
    quantile
        Quantile of the ``robust`` term, in (0, 1).
    probe_grid
        ``n`` of the ``n x n`` uniformity probe grid (>= 2).
    probe_radius_mm, probe_depth_mm
        Indenter of every probe (mm).
    bootstrap
        Bootstrap resamples for standard errors (>= 100).
    image_prior
        Prior of the ``image_cc`` reconstructions (one of :data:`latticeopt.recon.classical.PRIORS`).
    image_lambda
        Tikhonov lambda of the ``image_cc`` reconstructions relative to the largest eigenvalue of
        ``A P^-1 A^T`` (> 0, <= 10); the default 1e-3 is where the L-curve corner lies on 40 dB frames of the
        probe presses (:mod:`latticeopt.study.imaging`).
    """

    weights: tuple[tuple[str, float], ...] = (("mean", 1.0),)
    quantile: float = 0.1
    probe_grid: int = 3
    probe_radius_mm: float = 7.5
    probe_depth_mm: float = 3.0
    bootstrap: int = 1000
    image_prior: str = "laplacian"
    image_lambda: float = 1e-3

    def __post_init__(self) -> None:
        from ..recon.classical import PRIORS  # the one list of priors; recon loads scipy, so only when built

        w = dict(self.weights)
        for k, val in w.items():
            if k not in TERMS:
                raise ParameterError("objective", "terms among " + ", ".join(
                    f"{n} ({t.description})" for n, t in TERMS.items()), k)
            w[k] = v.real(k, val, lo=0)
        if not any(x > 0 for x in w.values()):
            raise ParameterError("objective", "at least one term with a weight > 0", dict(self.weights))
        object.__setattr__(self, "weights", tuple((k, w[k]) for k in TERMS if w.get(k, 0) > 0))
        object.__setattr__(self, "quantile", v.real("quantile", self.quantile, lo=0, hi=1, lo_open=True,
                                                    hi_open=True))
        try:  # the probe grid's schema is the sweep's: ProbePresses (grid, radius_mm, depth_mm)
            grid = ProbePresses(self.probe_grid, self.probe_radius_mm, self.probe_depth_mm)
        except ParameterError as exc:
            raise ParameterError(f"probe_{exc.name}", exc.expected, exc.got) from None
        for name in ("grid", "radius_mm", "depth_mm"):
            object.__setattr__(self, f"probe_{name}", getattr(grid, name))
        object.__setattr__(self, "bootstrap", v.integer("bootstrap", self.bootstrap, lo=100))
        object.__setattr__(self, "image_prior", v.choice("image_prior", self.image_prior, PRIORS))
        object.__setattr__(self, "image_lambda", v.real("image_lambda", self.image_lambda, lo=0, lo_open=True,
                                                        hi=10))

    @property
    def needs_probes(self) -> bool:
        return any(k in dict(self.weights) for k in PROBE_TERMS)

    @property
    def needs_images(self) -> bool:
        """Whether the probes' images are scored (``image_cc``): the model must return their voltages."""
        return "image_cc" in dict(self.weights)

    def describe(self) -> str:
        parts = []
        for k, w in self.weights:
            name = TERMS[k].describe(self)
            parts.append(name if w == 1 else f"{w:g} x {name}")
        return " + ".join(parts)

    def probes(self, size_mm: float) -> tuple[Phantom, ...]:
        """The probe grid on a ``size_mm`` sensor (empty unless ``uniformity`` or ``image_cc`` has a weight):
        :meth:`ProbePresses.generate <latticeopt.study.phantoms.ProbePresses.generate>` (touch ``i`` at the centre
        of cell ``(i % n, i // n)`` of the ``n x n`` partition), named ``probe_radius_mm`` when a probe leaves
        its cell."""
        if not self.needs_probes:
            return ()
        try:
            return self.probe_presses.generate(size_mm)
        except ParameterError as exc:
            raise ParameterError(f"probe_{exc.name}", exc.expected, exc.got) from None

    @property
    def probe_presses(self) -> ProbePresses:
        """The probe grid's settings as the sweep's phantom set (``kind = "probes"`` scores the same grid)."""
        return ProbePresses(self.probe_grid, self.probe_radius_mm, self.probe_depth_mm)

    # -- evaluation --------------------------------------------------------------------------------------
    def _terms(self, random_v: np.ndarray, probe_v: np.ndarray, probe_cc: np.ndarray) -> dict:
        return {k: TERMS[k].value(self, random_v, probe_v, probe_cc) for k, _ in self.weights}

    def gradient(self, random_v, probe_v, random_grads, probe_grads):
        """Gradient of the score with respect to a layout, from per-phantom values and gradients.

        Parameters
        ----------
        random_v, probe_v : ndarray, shapes (n,), (m,)
        random_grads, probe_grads : ndarray, shapes (n, ...), (m, ...)
            Each phantom's (probe's) ``d V_rel / d layout``.
        """
        r, p = (np.asarray(x, dtype=float).ravel() for x in (random_v, probe_v))
        total = 0.0
        for k, w in self.weights:
            if TERMS[k].gradient is None:
                raise ParameterError("objective", "terms with adjoint gradients (" + ", ".join(
                    n for n, t in TERMS.items() if t.gradient is not None) + ")", k)
            g_r, g_p = TERMS[k].gradient(self, r, p, np.asarray(random_grads), np.asarray(probe_grads))
            total = total + w * sum(g for g in (g_r, g_p) if g is not None)
        return total

    def _score(self, terms: Mapping[str, float]) -> float:
        return float(sum(w * terms[k] for k, w in self.weights))

    def _bootstrap(self, sets: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
        """Scores of every design in ``sets`` under the same resampled phantom indices, shape ``(B, len(sets))``.

        A resampled probe brings its V_rel and its image correlation together (they are one press)."""
        rng = np.random.default_rng(_BOOTSTRAP_SEED)
        n_r, n_p = sets[0][0].size, max(sets[0][1].size, sets[0][2].size)
        out = np.empty((self.bootstrap, len(sets)))
        for b in range(self.bootstrap):
            ir = rng.integers(0, n_r, n_r) if n_r else np.zeros(0, int)
            ip = rng.integers(0, n_p, n_p) if n_p else np.zeros(0, int)
            for j, (r, p, c) in enumerate(sets):
                out[b, j] = self._score(self._terms(r[ir], p[ip] if p.size else p, c[ip] if c.size else c))
        return out

    def _arrays(self, random_v, probe_v, probe_cc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r, p, c = (np.asarray(x, dtype=float).ravel() for x in (random_v, probe_v, probe_cc))
        if self.needs_images and c.size != p.size:
            raise ParameterError("probe_cc", f"one image correlation per probe ({p.size})", c.size)
        return r, p, c

    def evaluate(self, random_v: Sequence[float], probe_v: Sequence[float] = (),
                 probe_cc: Sequence[float] = ()) -> ObjectiveValue:
        """The score of one design from its V_rel on the random phantoms and on the probes.

        Parameters
        ----------
        random_v
            V_rel of every random phantom, shape ``(n,)``, NaN where a phantom failed.
        probe_v
            V_rel of every probe, shape ``(m,)`` (used by ``uniformity``), NaN where a probe failed.
        probe_cc
            Image correlation of every probe, shape ``(m,)`` (used by ``image_cc``), NaN where a probe failed
            or its image is undefined (:func:`latticeopt.study.imaging.probe_image_figures`).

        Returns
        -------
        ObjectiveValue
            NaN score, SE and terms when a phantom (or a probe the objective uses) failed: a design is scored on
            every phantom or not at all (module docstring).
        """
        r, p, c = self._arrays(random_v, probe_v, probe_cc)
        if (not np.isfinite(r).all() or (self.needs_probes and not np.isfinite(p).all())
                or (self.needs_images and not np.isfinite(c).all())):
            return ObjectiveValue(math.nan, math.nan, {k: math.nan for k, _ in self.weights})
        terms = self._terms(r, p, c)
        score = self._score(terms)
        if not math.isfinite(score):
            return ObjectiveValue(math.nan, math.nan, terms)
        if self.weights == (("mean", self.weights[0][1]),):
            se = self.weights[0][1] * float(np.std(r, ddof=1)) / math.sqrt(r.size) if r.size > 1 else math.nan
        else:
            boot = self._bootstrap([(r, p, c)])[:, 0]
            se = float(np.std(boot[np.isfinite(boot)], ddof=1)) if np.isfinite(boot).sum() > 1 else math.nan
        return ObjectiveValue(score, se, terms)

    def paired_difference(self, a: Sequence[Sequence[float]], b: Sequence[Sequence[float]]) -> tuple[float, float]:
        """``score(a) - score(b)`` and its paired standard error.

        ``a`` and ``b`` are ``(random_v, probe_v)`` or ``(random_v, probe_v, probe_cc)`` of two designs over the
        *same* phantoms, in the same order (only phantoms both evaluated successfully). For ``mean`` alone the SE
        is that of the mean of the per-phantom differences; otherwise a bootstrap resampling the same indices for
        both designs.
        """
        ra, pa, ca = self._arrays(*a, *((),) * (3 - len(a)))
        rb, pb, cb = self._arrays(*b, *((),) * (3 - len(b)))
        if ra.shape != rb.shape or pa.shape != pb.shape or ca.shape != cb.shape:
            raise ParameterError("paired_difference", "values of both designs on the same phantoms",
                                 f"{ra.size}+{pa.size}+{ca.size} vs {rb.size}+{pb.size}+{cb.size} values")
        diff = self.evaluate(ra, pa, ca).score - self.evaluate(rb, pb, cb).score
        if self.weights == (("mean", self.weights[0][1]),):
            d = self.weights[0][1] * (ra - rb)
            return diff, float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else math.nan
        boot = self._bootstrap([(ra, pa, ca), (rb, pb, cb)])
        delta = boot[:, 0] - boot[:, 1]
        delta = delta[np.isfinite(delta)]
        return diff, float(np.std(delta, ddof=1)) if delta.size > 1 else math.nan
