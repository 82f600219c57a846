"""Pictures for people who would rather look than read (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plumbing.fileio import write_with


def pyplot():
    """matplotlib's pyplot on the Agg backend (imported on first use: start-up time of every command)."""
    import matplotlib  # on use: start-up time (apps/__init__)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # on use: matplotlib (heavy)

    return plt


def save_figure(fig, path: Path, *, dpi: int = 100, force: bool = True) -> None:
    """Write ``fig`` to ``path`` as PNG atomically (never a partial file), then close it."""
    try:
        write_with(Path(path), lambda tmp: fig.savefig(tmp, format="png", dpi=dpi), force=force)
    finally:
        pyplot().close(fig)


def plot_psf(array: np.ndarray, meta: dict, path: Path) -> None:
    """Draw a monochromatic PSF (2-D) or a 3x3 LMS kernel (4-D), log scale."""
    plt = pyplot()
    if array.ndim == 2:
        fig, ax = plt.subplots(figsize=(4.5, 4))
        im = ax.imshow(np.log10(np.maximum(array, 1e-7)), cmap="magma", vmin=-7, vmax=0)
        ax.set_title(f"PSF at {meta.get('wavelength_nm', '?')} nm ({array.shape[0]} px)")
        fig.colorbar(im, ax=ax, label="log10 fraction of energy per pixel")
    else:
        fig, axes = plt.subplots(3, 3, figsize=(8, 8))
        for k, cone in enumerate("LMS"):
            for c, prim in enumerate("RGB"):
                ax = axes[k, c]
                kern = array[k, c]
                ax.imshow(np.log10(np.maximum(kern / max(kern.max(), 1e-30), 1e-6)), cmap="magma", vmin=-6, vmax=0)
                ax.set_title(f"{cone} from {prim}: sum {kern.sum():.3f}", fontsize=9)
                ax.set_xticks([])
                ax.set_yticks([])
        fig.suptitle(f"LMS kernel, {array.shape[-1]} px, log10 relative to peak")
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=100)
    plt.close(fig)


def plot_spectra_fit(measured, fit, path: Path) -> None:
    """Measured spectra as points, the smooth proxy as lines."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    colours = ("tab:red", "tab:green", "tab:blue")
    for i, label in enumerate(measured.labels):
        ax.plot(measured.wavelength_nm, measured.values[:, i], ".", color=colours[i % 3], ms=3)
        ax.plot(fit.spectra.wavelength_nm, fit.spectra.values[:, i], "-", color=colours[i % 3],
                label=f"{label}: rms {fit.rms_error[i] * 100:.2f}%")
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("relative radiance")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=100)
    plt.close(fig)
