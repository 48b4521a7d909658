"""Pictures of density layouts and their gradients (matplotlib, written off-screen)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_sensitivity(density: np.ndarray, gradient: np.ndarray, path, title: str, size_mm: float = 100.0,
                     touches=(), label: str = "dV_rel / d rho per cell") -> Path:
    """Two panels: the density layout and a gradient map (diverging colours centred on 0), touches as circles.

    Parameters
    ----------
    density, gradient : ndarray, shape (n, n)
        Row ``i`` covers ``y`` in ``[i L/n, (i+1) L/n)`` (drawn with ``y`` up).
    path
        PNG file to write.
    title
        Figure title: layout, mesh and phantoms.
    touches
        :class:`~latticeopt.touches.Touch` objects to outline on both panels.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    ext = (0.0, size_mm, 0.0, size_mm)
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 4.8), layout="constrained")
    im0 = axes[0].imshow(density, origin="lower", extent=ext, cmap="Blues", vmin=0, vmax=1)
    fig.colorbar(im0, ax=axes[0], label="density (1 = hydrogel)")
    lim = float(np.abs(gradient).max()) or 1.0
    im1 = axes[1].imshow(gradient, origin="lower", extent=ext, cmap="RdBu_r", vmin=-lim, vmax=lim)
    fig.colorbar(im1, ax=axes[1], label=label)
    axes[0].set_title("layout")
    axes[1].set_title("where more gel raises the response (red)")
    for ax in axes:
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        for t in touches:
            ax.add_patch(Circle((t.x_mm, t.y_mm), t.radius_mm, fill=False, ec="k", lw=1.2, ls="--"))
    fig.suptitle(title, wrap=True)
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_density(density: np.ndarray, path, size_mm: float, title: str) -> Path:
    """A density layout (0 silicone to 1 gel, ``y`` up) with a colour bar, written to the PNG ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.6, 4.2), layout="constrained")
    im = ax.imshow(density, origin="lower", extent=(0, size_mm, 0, size_mm), cmap="Blues", vmin=0, vmax=1)
    fig.colorbar(im, ax=ax, label="density (1 = hydrogel)")
    ax.set_title(title, fontsize=9, wrap=True)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)
