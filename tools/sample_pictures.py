"""Pictures made from the sample data matplotlib and scikit-image ship, none used by issue 44 so far: two
light ones and three with dark grounds, where a correction gains little and an eye sharper than
modelled sees most.  Made on 2026-12-05 to judge a rule that was dropped before it was written down
(docs/realtime.md, "Standing aside where the correction gains little"); never corrected, so unspent:
held for the next rule's judgement.

    .venv/bin/python tools/sample_pictures.py DIR      # five 256 px PNGs

* ``horse``: scikit-image's horse silhouette (white on black);
* ``logo2``: matplotlib's logo2.png on white;
* ``relief``: matplotlib's jacksboro_fault_dem elevations as shaded relief (gist_earth colours);
* ``bivariate``: matplotlib's axes_grid bivariate_normal.npy, its positive part, in the inferno colour
  map (a bright peak on black);
* ``eeg``: the first 120 samples of four channels of matplotlib's eeg.dat drawn as a dark-mode plot,
  light lines on black.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402  (after the backend)
import numpy as np  # noqa: E402
from matplotlib import cbook  # noqa: E402
from matplotlib.colors import LightSource  # noqa: E402

SIDE = 256


def _figure(background: str):
    fig = plt.figure(figsize=(1, 1), dpi=SIDE, facecolor=background)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.set_facecolor(background)
    return fig, ax


def _save(fig, path: Path) -> None:
    fig.savefig(path, dpi=SIDE, facecolor=fig.get_facecolor())
    plt.close(fig)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    from skimage import data

    horse = np.where(data.horse(), 0, 255).astype(np.uint8)      # True: the ground (black)
    fig, ax = _figure("white")
    ax.imshow(horse, cmap="gray", vmin=0, vmax=255, aspect="auto", interpolation="lanczos")
    _save(fig, out / "horse.png")

    logo = plt.imread(cbook.get_sample_data("logo2.png", asfileobj=False))
    if logo.shape[-1] == 4:                                        # over white
        logo = logo[..., :3] * logo[..., 3:] + (1.0 - logo[..., 3:])
    fig, ax = _figure("white")
    ax.imshow(logo, aspect="auto", interpolation="lanczos")
    _save(fig, out / "logo2.png")

    dem = np.load(cbook.get_sample_data("jacksboro_fault_dem.npz", asfileobj=False))["elevation"]
    shaded = LightSource(azdeg=315, altdeg=45).shade(dem, cmap=plt.get_cmap("gist_earth"), blend_mode="overlay",
                                                     vert_exag=0.05)
    fig, ax = _figure("white")
    ax.imshow(shaded, aspect="auto", interpolation="lanczos")
    _save(fig, out / "relief.png")

    z = np.load(cbook.get_sample_data("axes_grid/bivariate_normal.npy", asfileobj=False))
    fig, ax = _figure("black")
    ax.imshow(np.clip(z, 0.0, None), cmap="inferno", aspect="auto", interpolation="bicubic")
    _save(fig, out / "bivariate.png")

    with cbook.get_sample_data("eeg.dat") as f:
        eeg = np.frombuffer(f.read(), dtype="<i2").reshape(-1, 8)[:, :4].astype(float)
    fig, ax = _figure("black")
    for k, colour in enumerate(("#e0e0e0", "#7fd3ff", "#ffd27f", "#a8ff9f")):
        trace = eeg[:120, k]
        ax.plot((trace - trace.mean()) / (6 * trace.std() + 1e-9) + k, color=colour, linewidth=0.6)
    ax.set_xlim(0, 119)
    ax.set_ylim(-0.7, 3.7)
    _save(fig, out / "eeg.png")
    for name in ("horse", "logo2", "relief", "bivariate", "eeg"):
        print(out / f"{name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
