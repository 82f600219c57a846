"""``vrcorrect psf``: an eye's PSF at one wavelength, or its whole LMS kernel, as ``.npy`` with a JSON sidecar."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import check_writable, text_writer, write_together
from ..specs.display import get_display
from .common import add_model_options, build_eye_kernel, kernel_decisions, kernel_options, load_eye
from ..studies.plots import plot_psf


def cmd_psf(args: argparse.Namespace) -> int:
    from ..physics.kernel import monochromatic_psf  # on use: start-up time (apps/__init__)

    out = Path(args.output)
    if out.suffix.lower() != ".npy":
        raise ValidationError("--output", str(out), "a path ending in .npy")
    sidecar = out.with_suffix(".json")
    if args.png and Path(args.png).suffix.lower() != ".png":
        raise ValidationError("--png", args.png, "a path ending in .png")
    check_writable(out, force=args.force)
    check_writable(sidecar, force=args.force)
    if args.png:
        check_writable(Path(args.png), force=args.force)
    rx_path, eye = load_eye(args)
    if sidecar.resolve() == rx_path.resolve():
        raise ValidationError("--output", str(out), f"a name whose .json sidecar is not the prescription {rx_path}")
    display = get_display(args.display)
    options = kernel_options(args)
    meta: dict = {"prescription": str(rx_path), "eye": args.eye, "display": display.name,
                  "pixels_per_degree": display.pixels_per_degree,
                  "reference_wavelength_nm": options.optics.reference_wavelength_nm,
                  "chromatic_aberration": options.optics.chromatic_aberration,
                  "energy_fraction": options.energy_fraction}
    if args.wavelength_nm is not None:
        psf, full, state = monochromatic_psf(eye, display, args.wavelength_nm, options)
        array = psf
        meta.update(kind="monochromatic PSF", axes=["y (rows, down the display)", "x (columns, to the right)"],
                    wavelength_nm=args.wavelength_nm, wavelengths_nm=[args.wavelength_nm],
                    kernel_size=int(psf.shape[0]), sum=float(psf.sum()),
                    fft_grid=full.sampling.grid, fine_samples_per_pixel=full.sampling.oversample)
    else:
        kernel = build_eye_kernel(args, eye, display)
        array = kernel.kernel
        meta.update(kind="LMS kernel K[cone, primary, y, x]", axes=["cone (L, M, S)", "primary (R, G, B)",
                    "y (rows, down the display)", "x (columns, to the right)"],
                    kernel_size=kernel.size, wavelengths_nm=list(kernel.node_wavelengths_nm),
                    wavelength_step_nm=kernel.wavelength_step_nm, identity=kernel.identity,
                    rgb_to_lms=kernel.matrix.tolist(), decisions=kernel_decisions(kernel))
    def save_array(tmp: Path) -> None:
        with tmp.open("wb") as f:
            np.save(f, array)

    text = json.dumps(meta, indent=2) + "\n"
    outputs = [(out, save_array), (sidecar, text_writer(text))]
    if args.png:
        outputs.append((Path(args.png), lambda tmp: plot_psf(array, meta, tmp)))
    write_together(outputs, force=args.force)   # all or nothing
    print(f"wrote {out} ({'x'.join(map(str, array.shape))}) and {sidecar}" + (f" and {args.png}" if args.png else ""))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("psf", help="write an eye's PSF (one wavelength) or full LMS kernel as .npy + .json",
                       description="Write one eye's point-spread function at one wavelength (--wavelength-nm), "
                                   "or its whole colour kernel K[cone, primary, y, x] on the display, to OUT.npy "
                                   "with a JSON sidecar that describes it (and a plot with --png).")
    add_model_options(p)
    p.add_argument("--wavelength-nm", type=float, help="monochromatic PSF at this wavelength (default: full kernel)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.npy")
    p.add_argument("--png", metavar="PLOT.png", help="also draw it")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_psf)
