"""Training data for tactile reconstruction as in the paper (§V), simulated with an exported sensor model.

Per sample: 1 to 5 circular touches, diameter uniform in [7.5, 27.5] mm, each with a conductivity uniform in
[0.05, 2] x sigma0, on the 48 x 48 pixel grid over the sensor with background sigma0. Our placement choices
(the paper does not state them): every circle lies fully on the sensor and circles do not overlap (centres
drawn uniformly, redrawn on overlap). Pixel values are area-weighted: a pixel that a circle covers to a
fraction ``c`` (4 x 4 sub-samples) gets ``sigma0 + c (sigma_touch - sigma0)``. Voltages come from the sensor
model's *nonlinear* forward solve (:class:`~latticeopt.sensor_model.SensorSimulator`), in parallel processes.

Each touch count gets ``per_count`` samples (paper: 10 000) split 7:2:1 into train, validation and test
(:func:`latticeopt.learn.splits.stratified_split`). :func:`training_arrays` applies the paper's augmentation to
the training part only: the eight symmetries of the square (:mod:`.augment`) turn each sample into eight,
the identity kept clean and the seven others given Gaussian noise of SNR 35, 40, ..., 65 dB in turn
(280 000 training samples at full size). Noise is white on the absolute voltages with
``std = rms(V) 10^(-SNR/20)`` over the frame's 208 values.

Optionally the training part also holds single presses simulated by the coupled model (:class:`PressSamples`,
added by :func:`latticeopt.recon.presses.with_presses`), stored in the same file so they are simulated once.

Network inputs and classical reconstructions use relative changes ``y = (V - V_ref) / V_ref``; images are the
normalized change ``(sigma - sigma0) / sigma0`` (0 = background, -0.95 to +1 inside touches).
"""

from __future__ import annotations

import logging
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .. import _validate as v
from .._npzfile import load_npz, save_npz
from ..errors import ParameterError
from ..sensor_model import SensorModel, SensorSimulator
from .augment import square_symmetries

log = logging.getLogger(__name__)

PAPER_SNR_DB = (35.0, 40.0, 45.0, 50.0, 55.0, 60.0, 65.0)
DATASET_FORMAT = "latticeopt-recon-dataset"
# version 2 added the optional press samples (press_*); version 1 files still load, without them
DATASET_VERSION = 2
_SUB = 4  # sub-samples per pixel side for the coverage of a circle


@dataclass(frozen=True)
class DatasetConfig:
    """What to simulate (defaults: the paper's dataset).

    Parameters
    ----------
    per_count
        Samples per touch count (paper: 10 000).
    touch_counts
        Touch counts to generate (paper: 1 to 5).
    diameter_mm
        Range of touch diameters.
    ratio
        Range of touch conductivity over sigma0.
    split
        Train, validation, test fractions per touch count.
    seed
        Seed of touches, split and noise.
    """

    per_count: int = 10_000
    touch_counts: tuple = (1, 2, 3, 4, 5)
    diameter_mm: tuple = (7.5, 27.5)
    ratio: tuple = (0.05, 2.0)
    split: tuple = (0.7, 0.2, 0.1)
    seed: int = 0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "per_count", v.integer("per_count", self.per_count, lo=1))
        counts = tuple(v.integer("touch_counts", c, lo=1, hi=12) for c in self.touch_counts)
        if not counts:
            raise ParameterError("touch_counts", "a non-empty list of touch counts", self.touch_counts)
        set_(self, "touch_counts", counts)
        for name in ("diameter_mm", "ratio"):
            lo, hi = (v.real(name, x, lo=0, lo_open=True) for x in getattr(self, name))
            if hi < lo:
                raise ParameterError(name, "(low, high) with low <= high", getattr(self, name))
            set_(self, name, (lo, hi))
        set_(self, "split", tuple(float(x) for x in self.split))
        set_(self, "seed", v.integer("seed", self.seed, lo=0))


def render_touches(touches: np.ndarray, sigma0: float, n: int = 48,
                   extent_mm=(0.0, 100.0, 0.0, 100.0)) -> np.ndarray:
    """Pixel conductivity image of circular touches.

    Parameters
    ----------
    touches : array, shape (k, 4)
        Rows ``(x_mm, y_mm, diameter_mm, ratio)``; ``ratio`` is the touch conductivity over ``sigma0``. Rows
        with NaN are ignored (padding); overlapping circles: later rows win.
    sigma0
        Background conductivity (S/m).
    n, extent_mm
        Pixel grid (``n x n`` over ``(x0, x1, y0, y1)``).

    Returns
    -------
    ndarray, shape (n, n)
        Conductivity (S/m) per pixel, row ``iy``, column ``ix``.
    """
    x0, x1, y0, y1 = extent_mm
    hx, hy = (x1 - x0) / n, (y1 - y0) / n
    sub = (np.arange(n * _SUB) + 0.5) / _SUB
    xs, ys = x0 + sub * hx, y0 + sub * hy
    img = np.full((n, n), float(sigma0))
    for x, y, d, ratio in np.asarray(touches, dtype=float).reshape(-1, 4):
        if not np.isfinite([x, y, d, ratio]).all():
            continue
        r = d / 2
        ix0, ix1 = max(int((x - r - x0) / hx), 0), min(int((x + r - x0) / hx) + 1, n)
        iy0, iy1 = max(int((y - r - y0) / hy), 0), min(int((y + r - y0) / hy) + 1, n)
        if ix1 <= ix0 or iy1 <= iy0:
            continue
        sx = xs[ix0 * _SUB: ix1 * _SUB] - x
        sy = ys[iy0 * _SUB: iy1 * _SUB] - y
        inside = (sy[:, None] ** 2 + sx[None, :] ** 2) <= r * r
        cover = inside.reshape(iy1 - iy0, _SUB, ix1 - ix0, _SUB).mean(axis=(1, 3))
        block = img[iy0:iy1, ix0:ix1]
        img[iy0:iy1, ix0:ix1] = block + cover * (ratio * sigma0 - block)
    return img


def sample_touches(rng: np.random.Generator, count: int, config: DatasetConfig, size_mm: float) -> np.ndarray:
    """``count`` non-overlapping circles fully on the sensor, shape ``(count, 4)`` (see :func:`render_touches`)."""
    for _ in range(1000):
        d = rng.uniform(*config.diameter_mm, size=count)
        ratio = rng.uniform(*config.ratio, size=count)
        xy = np.empty((count, 2))
        ok = True
        for i in range(count):
            r = d[i] / 2
            for _ in range(200):
                xy[i] = rng.uniform(r, size_mm - r, size=2)
                if i == 0 or np.all(np.linalg.norm(xy[:i] - xy[i], axis=1) >= r + d[:i] / 2):
                    break
            else:
                ok = False
                break
        if ok:
            return np.column_stack([xy, d, ratio])
    raise ParameterError("touch_counts", f"counts whose circles fit on a {size_mm:g} mm sensor", count)


@dataclass(frozen=True, eq=False)
class PressSamples:
    """Single presses simulated by the coupled model, mixed into the training part only.

    Attributes
    ----------
    presses : ndarray, shape (k, 4)
        ``(x_mm, y_mm, radius_mm, depth_mm)`` of each press (:func:`latticeopt.recon.presses.random_presses`).
    y : ndarray, shape (k, n_rows)
        Relative voltage changes ``V / V_ref - 1`` of each press; NaN rows (failed solves) are not trained on.
    images : ndarray, shape (k, n_pix, n_pix), float32
        Target images: normalized change of each punch's footprint disc.
    seed : int
        Seed the presses were drawn with.
    """

    presses: np.ndarray
    y: np.ndarray
    images: np.ndarray
    seed: int

    def __post_init__(self) -> None:
        k = len(self.presses)
        if np.shape(self.presses) != (k, 4) or np.ndim(self.y) != 2 or len(self.y) != k \
                or np.ndim(self.images) != 3 or len(self.images) != k:
            raise ParameterError("presses", "presses (k, 4) with frames (k, n_rows) and images (k, n, n)",
                                 f"shapes {np.shape(self.presses)}, {np.shape(self.y)}, {np.shape(self.images)}")
        object.__setattr__(self, "seed", v.integer("press_seed", self.seed, lo=0))

    @property
    def solved(self) -> np.ndarray:
        """Mask of the presses whose frame is finite, shape (k,)."""
        return np.all(np.isfinite(self.y), axis=1)


@dataclass(frozen=True, eq=False)
class ReconDataset:
    """Simulated samples (unaugmented) with their split.

    Attributes
    ----------
    voltages : ndarray, shape (n, n_rows)
        Noise-free nonlinear voltages (V).
    images : ndarray, shape (n, n_pix, n_pix), float32
        Normalized conductivity change ``(sigma - sigma0) / sigma0``.
    touches : ndarray, shape (n, max_count, 4)
        ``(x_mm, y_mm, diameter_mm, ratio)`` per touch, NaN padded.
    n_touches : ndarray of int, shape (n,)
    train, val, test : ndarray of int
        Sample indices of each part.
    config : DatasetConfig
    model_fingerprint : str
        :attr:`SensorModel.fingerprint` of the model that simulated the voltages.
    presses : PressSamples or None
        Coupled presses added to the training part (not counted in ``len``).
    """

    voltages: np.ndarray
    images: np.ndarray
    touches: np.ndarray
    n_touches: np.ndarray
    train: np.ndarray
    val: np.ndarray
    test: np.ndarray
    config: DatasetConfig
    model_fingerprint: str
    presses: PressSamples | None = None

    def __len__(self) -> int:
        return len(self.voltages)

    def check_model(self, model: SensorModel) -> None:
        if model.fingerprint != self.model_fingerprint:
            raise ParameterError("dataset", f"data simulated with this sensor model (fingerprint "
                                 f"{model.fingerprint})", f"data of model {self.model_fingerprint}")

    def save(self, path: str | Path) -> Path:
        meta = {"config": asdict(self.config), "model_fingerprint": self.model_fingerprint}
        arrays = {"voltages": self.voltages, "images": self.images, "touches": self.touches,
                  "n_touches": self.n_touches, "train": self.train, "val": self.val, "test": self.test}
        if self.presses is not None:
            p = self.presses
            meta["press_seed"] = p.seed
            arrays.update(press_params=p.presses, press_y=p.y, press_images=p.images)
        return save_npz(path, DATASET_FORMAT, DATASET_VERSION, meta, arrays)

    @classmethod
    def load(cls, path: str | Path) -> ReconDataset:
        def build(meta, z):
            cfg = DatasetConfig(**{k: tuple(x) if isinstance(x, list) else x for k, x in meta["config"].items()})
            presses = None
            if "press_params" in z.files:
                presses = PressSamples(z["press_params"], z["press_y"], z["press_images"], meta["press_seed"])
            return cls(z["voltages"], z["images"], z["touches"], z["n_touches"], z["train"], z["val"], z["test"],
                       cfg, meta["model_fingerprint"], presses)

        return load_npz(path, DATASET_FORMAT, DATASET_VERSION, build,
                        f"a dataset file written by latticeopt recon-train ({DATASET_FORMAT} version <= "
                        f"{DATASET_VERSION})")


def generate_dataset(model: SensorModel, config: DatasetConfig | None = None, *, jobs: int = 1,
                     progress: bool = False, simulator: SensorSimulator | None = None) -> ReconDataset:
    """Simulate the paper's dataset with ``model`` (see the module docstring).

    Parameters
    ----------
    model
        Exported sensor model.
    config
        :class:`DatasetConfig` (default: the paper's 50 000 samples).
    jobs
        Worker processes for the forward solves.
    progress
        tqdm progress bar.
    simulator
        A :class:`SensorSimulator` of ``model`` to reuse (built here otherwise).

    Returns
    -------
    ReconDataset
        The same seed gives the same dataset on any machine (touches, split); voltages agree to solver
        rounding.
    """
    from tqdm import tqdm

    from ..learn.splits import stratified_split

    cfg = config or DatasetConfig()
    s0, n = model.sigma0_S_per_m, model.n_pixels
    L = model.design.size_mm
    max_count = max(cfg.touch_counts)
    total = cfg.per_count * len(cfg.touch_counts)
    touches = np.full((total, max_count, 4), np.nan)
    counts = np.repeat(np.asarray(cfg.touch_counts), cfg.per_count)
    sigma = np.empty((total, n, n))
    # Drawing and rendering the paper's 50 000 samples takes tens of seconds: show it, not a silent wait.
    for i, c in enumerate(tqdm(counts, desc="touch images", unit="image", disable=not progress, leave=False)):
        rng = np.random.default_rng([cfg.seed, int(c), i])
        touches[i, :c] = sample_touches(rng, int(c), cfg, L)
        sigma[i] = render_touches(touches[i, :c], s0, n, model.extent_mm)
    if simulator is None:
        if progress:
            tqdm.write("rebuilding the sensor model's forward solver", file=sys.stderr)
        simulator = SensorSimulator(model)
    sim = simulator
    V = sim.voltages(sigma, jobs=jobs, progress=progress)
    train, val, test = stratified_split(counts, cfg.split, cfg.seed)
    images = normalized_change(sigma, s0)
    return ReconDataset(V, images, touches, counts, train, val, test, cfg, model.fingerprint)


def normalized_change(sigma: np.ndarray, sigma0: float) -> np.ndarray:
    """Image target ``(sigma - sigma0) / sigma0`` of conductivity images ``(..., n, n)`` (S/m), float32."""
    return ((np.asarray(sigma) - sigma0) / sigma0).astype(np.float32)


def relative_change(V: np.ndarray, v_ref: np.ndarray) -> np.ndarray:
    """``(V - V_ref) / V_ref`` per measurement, shape like ``V``."""
    return (np.asarray(V) - v_ref) / v_ref


def add_noise(V: np.ndarray, snr_db, rng: np.random.Generator) -> np.ndarray:
    """``V`` plus white Gaussian noise with ``std = rms(V) 10^(-snr/20)`` per frame (``snr_db`` scalar or (k,))."""
    V = np.atleast_2d(np.asarray(V, dtype=float))
    snr = np.broadcast_to(np.asarray(snr_db, dtype=float), (len(V),))
    std = np.sqrt(np.mean(V ** 2, axis=1)) * 10.0 ** (-snr / 20.0)
    return V + rng.standard_normal(V.shape) * std[:, None]


def part_arrays(data: ReconDataset, model: SensorModel, part: str, snr_db: float | None = None,
                seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unaugmented ``(y, images, n_touches)`` of ``part`` (``"train"``, ``"val"`` or ``"test"``).

    ``y`` are relative changes (float64, ``(k, n_rows)``), optionally with noise of ``snr_db``.
    """
    idx = {"train": data.train, "val": data.val, "test": data.test}[v.choice("part", part, ("train", "val", "test"))]
    V = data.voltages[idx]
    if snr_db is not None:
        V = add_noise(V, v.real("snr_db", snr_db), np.random.default_rng([data.config.seed, seed]))
    return relative_change(V, model.v_ref), data.images[idx], data.n_touches[idx]


def training_arrays(data: ReconDataset, model: SensorModel, snr_db=PAPER_SNR_DB, augment: bool = True
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The augmented training set: ``(y float32 (8k, n_rows), images float32 (8k, n, n))``.

    Sample ``i`` of the training part gives rows ``8 i .. 8 i + 7``: the eight symmetries of
    :func:`~latticeopt.recon.augment.square_symmetries` in order, the first (identity) clean, the others with
    noise of ``snr_db[0]``, ``snr_db[1]``, ... (seven values). The solved presses of ``data.presses`` follow
    the disc samples, augmented alike; their noise has a stream of its own, so the disc rows are the same with
    or without presses. ``augment=False`` returns the clean training part (and presses) unaugmented.
    """
    y, img, _ = part_arrays(data, model, "train")
    parts = [(y, img)]
    if data.presses is not None:
        ok = data.presses.solved
        parts.append((data.presses.y[ok], data.presses.images[ok].astype(np.float32)))
    if not augment:
        return (np.concatenate([p[0] for p in parts]).astype(np.float32), np.concatenate([p[1] for p in parts]))
    syms = square_symmetries(model.design, model.protocol, model.n_pixels)
    snr = tuple(float(s) for s in snr_db)
    if len(snr) != len(syms) - 1:
        raise ParameterError("snr_db", f"{len(syms) - 1} SNR values (one per non-identity symmetry)", snr_db)
    out = [_augment(yp, ip, model, syms, snr, np.random.default_rng([data.config.seed, 2, *([j] if j else [])]))
           for j, (yp, ip) in enumerate(parts)]
    return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])


def _augment(y: np.ndarray, img: np.ndarray, model: SensorModel, syms, snr: tuple, rng: np.random.Generator
             ) -> tuple[np.ndarray, np.ndarray]:
    """Eight-fold augmentation of ``y (k, n_rows)``, ``img (k, n, n)`` (see :func:`training_arrays`)."""
    k, m = y.shape
    y_out = np.empty((k, len(syms), m), dtype=np.float32)
    img_out = np.empty((k, len(syms)) + img.shape[1:], dtype=np.float32)
    for g, sym in enumerate(syms):
        yg = sym.relative(y)
        if g > 0:  # noise on the absolute frame of the symmetric sensor
            Vg = model.v_ref * (1.0 + yg)
            yg = relative_change(add_noise(Vg, snr[g - 1], rng), model.v_ref)
        y_out[:, g] = yg
        img_out[:, g] = sym.images(img)
    return y_out.reshape(k * len(syms), m), img_out.reshape((k * len(syms),) + img.shape[1:])
