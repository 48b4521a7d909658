"""Space-time trajectories of the paper's 12 touch gestures (§VII), drawn at random and seeded.

A :class:`Trajectory` gives, for every frame ``t = 0 .. n_frames - 1`` and every touch ``j`` of the gesture,
the disc centre ``(x, y)`` (mm, sensor coordinates: ``x`` to the right along electrodes 1-4, ``y`` up), its
radius (mm) and the relative conductivity change ``delta = sigma / sigma0 - 1`` inside the disc. ``delta = 0``
means the touch is not in contact in that frame; a press *lowers* the conductivity (``-1 < delta < 0``): the
coupled simulation of this package shows a press raising the measured voltages, i.e. the compressed channels
conduct less (see ``docs/gestures.md``).

Every gesture is an intensity envelope (rise, hold, fall, in frames) times a peak drop, on a path. What each
class draws (``U`` uniform; all ranges are :class:`GestureConfig` fields):

==================  ==============================================================================================
class               trajectory
==================  ==============================================================================================
no contact          no touch at all
finger press        one finger disc, fixed position; rise 1-3, hold 4-9, fall 1-3 frames
four-finger scratch four fingertips (0.8 x finger size) in a row about x (tilt +-15 deg), spaced 1.2-1.5 diameters,
                    dragged back and forth perpendicular to the row (2-3 strokes of 8-15 mm) over 7-12 contact
                    frames; lighter (0.6 x the drop)
fist press          one fist disc, fixed position; rise 2-3, hold 4-8, fall 2-3 frames
finger double tap   one finger; two contacts of 1-3 frames separated by 1-3 frames without contact, same place
                    (second tap within 1.5 mm of the first)
palm pat            one palm disc, one short contact: rise 0-1, hold 1-2, fall 0-1 frames; 0.7 x the drop
finger swipe up,    one finger moving 40-70 mm in +y, -y, -x, +x (direction jitter +-10 deg) at constant speed
down, left, right   over 5-11 contact frames, rise and fall one frame each
zoom-in, zoom-out   two fingers (thumb and index, sizes drawn separately) on a random axis through a random
                    centre; separation from 18-28 mm to 50-70 mm (zoom-in, fingers move apart) or back
                    (zoom-out) at constant speed over 5-11 contact frames
==================  ==============================================================================================

Contact intervals start at a random frame so the whole gesture fits in the sequence; positions are uniform
over the places where every disc stays fully on the sensor. ``trajectory(label, rng)`` is deterministic for a
given generator state.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .. import _validate as v
from ..errors import ParameterError

#: The paper's 12 gesture classes in label order (same order as ``latticeopt.learn.GESTURE_CLASSES``).
GESTURES = (
    "no contact", "finger press", "four-finger scratch", "fist press", "finger double tap", "palm pat",
    "finger swipe up", "finger swipe down", "finger swipe left", "finger swipe right", "zoom-in", "zoom-out",
)
N_FRAMES = 15
#: Most touches any gesture uses (the scratch's four fingertips).
MAX_TOUCHES = 4
_SCRATCH_SIZE, _SCRATCH_DROP, _PAT_DROP = 0.8, 0.6, 0.7


def _range(name: str, value, lo: float = 0.0, hi: float | None = None) -> tuple[float, float]:
    try:
        a, b = value
    except (TypeError, ValueError):
        raise ParameterError(name, "a pair (low, high)", value) from None
    a = v.real(name, a, lo=lo, hi=hi)
    b = v.real(name, b, lo=lo, hi=hi)
    if b < a:
        raise ParameterError(name, "a pair (low, high) with low <= high", value)
    return a, b


@dataclass(frozen=True)
class GestureConfig:
    """Random variation of the gesture trajectories (defaults documented in ``docs/gestures.md``).

    Parameters
    ----------
    n_frames
        Frames per sequence (paper: 15).
    finger_diameter_mm, fist_diameter_mm, palm_diameter_mm
        Contact-disc diameters (mm) of a fingertip, a fist and a palm.
    drop
        Peak conductivity drop ``1 - sigma / sigma0`` of a press (its intensity), in ``(0, 1)``.
    swipe_length_mm
        Distance a swiping finger travels.
    zoom_near_mm, zoom_far_mm
        Finger separation (centre to centre) at the closed and open ends of a zoom.
    move_frames
        Contact frames of a swipe or zoom (fewer = faster).
    """

    n_frames: int = N_FRAMES
    finger_diameter_mm: tuple = (11.0, 17.0)
    fist_diameter_mm: tuple = (32.0, 45.0)
    palm_diameter_mm: tuple = (55.0, 72.0)
    drop: tuple = (0.3, 0.8)
    swipe_length_mm: tuple = (40.0, 70.0)
    zoom_near_mm: tuple = (18.0, 28.0)
    zoom_far_mm: tuple = (50.0, 70.0)
    move_frames: tuple = (5, 11)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "n_frames", v.integer("n_frames", self.n_frames, lo=15, expected="an integer >= 15 "
                                         "(a finger press spans up to 15 frames)"))
        for name in ("finger_diameter_mm", "fist_diameter_mm", "palm_diameter_mm", "swipe_length_mm",
                     "zoom_near_mm", "zoom_far_mm"):
            set_(self, name, _range(name, getattr(self, name), lo=0.5, hi=95.0))
        set_(self, "drop", _range("drop", self.drop, lo=0.01, hi=0.99))
        expected = f"a pair (low, high) of integers with 2 <= low <= high <= {self.n_frames - 2}"
        try:
            lo, hi = self.move_frames
        except (TypeError, ValueError):
            raise ParameterError("move_frames", expected, self.move_frames) from None
        lo = v.integer("move_frames", lo, lo=2, hi=self.n_frames - 2, expected=expected)
        hi = v.integer("move_frames", hi, lo=lo, hi=self.n_frames - 2, expected=expected)
        set_(self, "move_frames", (lo, hi))
        if self.zoom_far_mm[0] <= self.zoom_near_mm[1]:
            raise ParameterError("zoom_far_mm", f"a range above zoom_near_mm's upper end {self.zoom_near_mm[1]:g}",
                                 self.zoom_far_mm)

    def as_dict(self) -> dict:
        return {k: list(x) if isinstance(x, tuple) else x for k, x in asdict(self).items()}


@dataclass(frozen=True, eq=False)
class Trajectory:
    """One gesture: touch discs per frame.

    Attributes
    ----------
    label : int
        Class index into :data:`GESTURES`.
    centres_mm : ndarray, shape (n_frames, k, 2)
        Disc centres ``(x, y)``.
    radius_mm : ndarray, shape (n_frames, k)
        Disc radii.
    delta : ndarray, shape (n_frames, k)
        ``sigma / sigma0 - 1`` inside each disc; 0 where the touch is not in contact.
    """

    label: int
    centres_mm: np.ndarray
    radius_mm: np.ndarray
    delta: np.ndarray

    @property
    def name(self) -> str:
        return GESTURES[self.label]

    @property
    def n_frames(self) -> int:
        return self.delta.shape[0]

    @property
    def active(self) -> np.ndarray:
        """Which touch is in contact in which frame, bool ``(n_frames, k)``."""
        return self.delta != 0

    def in_contact(self) -> np.ndarray:
        """Frames with at least one touch in contact, bool ``(n_frames,)``."""
        return self.active.any(axis=1)

    def contact_intervals(self) -> list[tuple[int, int]]:
        """Maximal runs ``[start, stop)`` of frames in contact."""
        c = np.concatenate([[False], self.in_contact(), [False]]).astype(int)
        edges = np.flatnonzero(np.diff(c))
        return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]

    def centroid_mm(self) -> np.ndarray:
        """Mean centre of the touches in contact per frame, ``(n_frames, 2)``; NaN without contact."""
        act = self.active[..., None]
        n = act.sum(axis=1)
        with np.errstate(invalid="ignore"):
            return np.where(n > 0, (self.centres_mm * act).sum(axis=1) / np.maximum(n, 1), np.nan)

    def spread_mm(self) -> np.ndarray:
        """Mean distance between touches in contact per frame, ``(n_frames,)``; NaN with fewer than two."""
        out = np.full(self.n_frames, np.nan)
        for t in range(self.n_frames):
            c = self.centres_mm[t, self.active[t]]
            if len(c) >= 2:
                d = np.linalg.norm(c[:, None] - c[None], axis=-1)
                out[t] = d[np.triu_indices(len(c), 1)].mean()
        return out

    def touches(self, frame: int) -> np.ndarray:
        """Discs in contact in ``frame`` as rows ``(x_mm, y_mm, diameter_mm, sigma / sigma0)``, ``(m, 4)``
        (the input of :func:`latticeopt.recon.dataset.render_touches`)."""
        a = self.active[frame]
        return np.column_stack([self.centres_mm[frame, a], 2 * self.radius_mm[frame, a], 1 + self.delta[frame, a]])

    def padded(self, k: int = MAX_TOUCHES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(centres (n_frames, k, 2), radius (n_frames, k), delta (n_frames, k))`` padded with NaN."""
        n, m = self.delta.shape
        if m > k:
            raise ParameterError("k", f"at least {m} touches", k)
        c, r, d = np.full((n, k, 2), np.nan), np.full((n, k), np.nan), np.full((n, k), np.nan)
        c[:, :m], r[:, :m], d[:, :m] = self.centres_mm, self.radius_mm, self.delta
        return c, r, d

    @classmethod
    def from_padded(cls, label: int, centres_mm, radius_mm, delta) -> Trajectory:
        keep = ~np.all(np.isnan(np.asarray(delta, dtype=float)), axis=0)
        return cls(int(label), np.asarray(centres_mm, float)[:, keep], np.asarray(radius_mm, float)[:, keep],
                   np.asarray(delta, float)[:, keep])


# -- building blocks ---------------------------------------------------------------------------------------

def envelope(n_frames: int, start: int, rise: int, hold: int, fall: int) -> np.ndarray:
    """Contact intensity per frame in ``[0, 1]``: ``rise`` frames ramping up, ``hold`` at 1, ``fall`` down.

    Every frame of the contact is strictly positive (ramps are ``j / (rise + 1)``); frames outside are 0.
    """
    e = np.zeros(n_frames)
    up = np.arange(1, rise + 1) / (rise + 1)
    down = np.arange(fall, 0, -1) / (fall + 1)
    seg = np.concatenate([up, np.ones(hold), down])
    if start < 0 or start + len(seg) > n_frames:
        raise ParameterError("start", f"a contact that fits in {n_frames} frames", (start, len(seg)))
    e[start:start + len(seg)] = seg
    return e


def _start(rng: np.random.Generator, n_frames: int, length: int) -> int:
    return int(rng.integers(0, n_frames - length + 1))


def _place(rng: np.random.Generator, offsets: np.ndarray, radii: np.ndarray, size_mm: float) -> np.ndarray:
    """A reference point such that every disc ``point + offsets[...]`` of radius ``radii`` is on the sensor.

    ``offsets`` has shape ``(..., 2)`` and ``radii`` broadcasts against ``offsets[..., 0]``.
    """
    lo = (-offsets + radii[..., None]).reshape(-1, 2).max(axis=0)
    hi = (size_mm - offsets - radii[..., None]).reshape(-1, 2).min(axis=0)
    if np.any(hi < lo):
        raise ParameterError("size_mm", f"a sensor large enough for the gesture's extent ({size_mm:g} mm given)",
                             size_mm)
    return rng.uniform(lo, hi)


def _unit(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle)])


def _stationary(rng, cfg: GestureConfig, label: int, diameter, rise, hold, fall, drop_scale, size_mm):
    n = cfg.n_frames
    r = rng.uniform(*diameter) / 2
    rise_, hold_, fall_ = (int(rng.integers(a, b + 1)) for a, b in (rise, hold, fall))
    e = envelope(n, _start(rng, n, rise_ + hold_ + fall_), rise_, hold_, fall_)
    drop = drop_scale * rng.uniform(*cfg.drop)
    c = _place(rng, np.zeros((1, 2)), np.array([r]), size_mm)
    return Trajectory(label, np.broadcast_to(c, (n, 1, 2)).copy(), np.full((n, 1), r), -drop * e[:, None])


def _moving(rng, cfg: GestureConfig, label: int, offsets_fn, radii: np.ndarray, drop_scale: float, size_mm):
    """Touches at ``point + offsets_fn(s)`` for progress ``s`` in [0, 1] over the contact frames."""
    n = cfg.n_frames
    m = int(rng.integers(cfg.move_frames[0], cfg.move_frames[1] + 1))
    start = _start(rng, n, m)
    e = envelope(n, start, 1, m - 2, 1)
    s = np.clip((np.arange(n) - start) / (m - 1), 0.0, 1.0)
    offsets = offsets_fn(s)  # (n, k, 2)
    point = _place(rng, offsets, radii[None, :], size_mm)
    drop = drop_scale * rng.uniform(*cfg.drop)
    k = len(radii)
    return Trajectory(label, point + offsets, np.broadcast_to(radii, (n, k)).copy(),
                      np.repeat(-drop * e[:, None], k, axis=1))


# -- the twelve classes ------------------------------------------------------------------------------------

def _no_contact(rng, cfg, label, size_mm):
    n = cfg.n_frames
    return Trajectory(label, np.zeros((n, 0, 2)), np.zeros((n, 0)), np.zeros((n, 0)))


def _finger_press(rng, cfg, label, size_mm):
    return _stationary(rng, cfg, label, cfg.finger_diameter_mm, (1, 3), (4, 9), (1, 3), 1.0, size_mm)


def _fist_press(rng, cfg, label, size_mm):
    return _stationary(rng, cfg, label, cfg.fist_diameter_mm, (2, 3), (4, 8), (2, 3), 1.0, size_mm)


def _palm_pat(rng, cfg, label, size_mm):
    return _stationary(rng, cfg, label, cfg.palm_diameter_mm, (0, 1), (1, 2), (0, 1), _PAT_DROP, size_mm)


def _double_tap(rng, cfg, label, size_mm):
    n = cfg.n_frames
    r = rng.uniform(*cfg.finger_diameter_mm) / 2
    taps = [(int(rng.integers(0, 2)), int(rng.integers(0, 2))) for _ in range(2)]  # (rise, fall) frames
    lengths = [a + 1 + b for a, b in taps]
    gap = int(rng.integers(1, 4))
    start = _start(rng, n, lengths[0] + gap + lengths[1])
    e1 = envelope(n, start, taps[0][0], 1, taps[0][1])
    e2 = envelope(n, start + lengths[0] + gap, taps[1][0], 1, taps[1][1])
    jitter = rng.uniform(0, 1.5) * _unit(rng.uniform(0, 2 * math.pi))
    offsets = np.zeros((n, 1, 2))
    offsets[start + lengths[0]:] = jitter
    c = _place(rng, offsets, np.array([r]), size_mm)
    drop = rng.uniform(*cfg.drop)
    return Trajectory(label, c + offsets, np.full((n, 1), r), -drop * (e1 + e2)[:, None])


def _scratch(rng, cfg, label, size_mm):
    n = cfg.n_frames
    d = _SCRATCH_SIZE * rng.uniform(*cfg.finger_diameter_mm)
    radii = np.full(4, d / 2) * rng.uniform(0.9, 1.1, 4)
    spacing = d * rng.uniform(1.2, 1.5)
    tilt = math.radians(rng.uniform(-15, 15))
    along, across = _unit(tilt), _unit(tilt + math.pi / 2)
    row = (np.arange(4) - 1.5)[:, None] * spacing * along  # (4, 2)
    strokes = int(rng.integers(2, 4))
    amp = rng.uniform(8.0, 15.0)
    m = int(rng.integers(7, 13))
    start = _start(rng, n, m)
    e = envelope(n, start, 1, m - 2, 1)
    s = np.clip((np.arange(n) - start) / (m - 1), 0.0, 1.0)
    phase = s * strokes  # triangle wave: 0 -> amp -> 0 ...
    tri = amp * (1 - np.abs(1 - np.mod(phase, 2.0)))
    offsets = row[None] + tri[:, None, None] * across
    point = _place(rng, offsets, radii[None, :], size_mm)
    drop = _SCRATCH_DROP * rng.uniform(*cfg.drop)
    return Trajectory(label, point + offsets, np.broadcast_to(radii, (n, 4)).copy(),
                      np.repeat(-drop * e[:, None], 4, axis=1))


def _swipe(angle_deg: float):
    def make(rng, cfg, label, size_mm):
        direction = _unit(math.radians(angle_deg + rng.uniform(-10, 10)))
        length = rng.uniform(*cfg.swipe_length_mm)
        r = rng.uniform(*cfg.finger_diameter_mm) / 2
        return _moving(rng, cfg, label, lambda s: (s[:, None] * length * direction)[:, None, :],
                       np.array([r]), 1.0, size_mm)
    return make


def _zoom(opening: bool):
    def make(rng, cfg, label, size_mm):
        axis = _unit(rng.uniform(0, math.pi))
        near, far = rng.uniform(*cfg.zoom_near_mm), rng.uniform(*cfg.zoom_far_mm)
        a, b = (near, far) if opening else (far, near)
        radii = np.array([rng.uniform(*cfg.finger_diameter_mm), rng.uniform(*cfg.finger_diameter_mm)]) / 2

        def offsets(s):
            sep = a + (b - a) * s
            return (np.array([-0.5, 0.5])[None, :, None] * sep[:, None, None]) * axis
        return _moving(rng, cfg, label, offsets, radii, 1.0, size_mm)
    return make


_MAKERS = (_no_contact, _finger_press, _scratch, _fist_press, _double_tap, _palm_pat,
           _swipe(90.0), _swipe(-90.0), _swipe(180.0), _swipe(0.0), _zoom(True), _zoom(False))


def trajectory(label: int, rng: np.random.Generator, config: GestureConfig | None = None,
               size_mm: float = 100.0) -> Trajectory:
    """Draw one random trajectory of gesture class ``label``.

    Parameters
    ----------
    label
        Class index into :data:`GESTURES` (0 = no contact ... 11 = zoom-out).
    rng
        Source of the random variation (consumed; seed it per sequence for reproducibility).
    config
        Ranges of the variation; default :class:`GestureConfig()`.
    size_mm
        Side of the square sensor; every disc stays fully on it.

    Returns
    -------
    Trajectory
    """
    label = v.integer("label", label, lo=0, hi=len(GESTURES) - 1)
    cfg = config or GestureConfig()
    if not isinstance(cfg, GestureConfig):
        raise ParameterError("config", "a GestureConfig", type(cfg).__name__)
    size_mm = v.real("size_mm", size_mm, lo=0, lo_open=True)
    return _MAKERS[label](rng, cfg, label, size_mm)
