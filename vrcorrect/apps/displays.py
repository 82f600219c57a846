"""``vrcorrect displays``: the display presets, or a fit of measured spectra."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import check_writable
from ..specs.display import fit_spectra, get_display, preset_names, read_spectra_csv
from ..studies.bench import markdown_table


def cmd_displays(args: argparse.Namespace) -> int:
    if args.fit:
        return _displays_fit(args)
    if args.plot:
        raise ValidationError("--plot", args.plot, "only together with --fit SPECTRA.csv")
    rows = []
    for name in preset_names():
        d = get_display(name)
        dist = "inf" if math.isinf(d.distance_m) else f"{d.distance_m:.2f}"
        res = "x".join(map(str, d.resolution_px)) if d.resolution_px else "-"
        ph = d.photometry
        rows.append([name, d.title, d.kind, f"{d.pixels_per_degree:.1f}", dist, res, d.transfer,
                     f"{ph.peak_luminance_cd_m2:g}", f"{ph.contrast:g}:1", f"{ph.ambient_lux:g}"])
    print(markdown_table(["preset", "display", "kind", "px/deg", "distance m", "resolution", "transfer",
                          "peak cd/m²", "contrast", "ambient lux"], rows))
    if args.verbose:
        for name in preset_names():
            d = get_display(name)
            print(f"\n{name}: {d.sources}\n  Photometry ({d.photometry.describe()}): {d.photometry.sources}")
    else:
        print("\n(sources and estimates: vrcorrect displays -v)")
    return 0


def _displays_fit(args: argparse.Namespace) -> int:
    if args.plot:
        if Path(args.plot).suffix.lower() != ".png":
            raise ValidationError("--plot", args.plot, "a path ending in .png")
        check_writable(Path(args.plot), force=args.force)
    measured = read_spectra_csv(Path(args.fit))
    fit = fit_spectra(measured)
    print(f"{args.fit}: {len(measured.wavelength_nm)} samples, "
          f"{measured.wavelength_nm[0]:.0f}-{measured.wavelength_nm[-1]:.0f} nm")
    for label, rms, mx in zip(measured.labels, fit.rms_error, fit.max_error):
        print(f"  {label:6s} smooth non-negative fit: rms error {rms * 100:.2f}% of peak, max {mx * 100:.2f}%")
    if args.plot:
        from ..plumbing.fileio import write_with  # on use: start-up time (apps/__init__)
        from ..studies.plots import plot_spectra_fit  # on use: start-up time (apps/__init__)

        write_with(Path(args.plot), lambda tmp: plot_spectra_fit(measured, fit, tmp), force=args.force)
        print(f"wrote {args.plot}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("displays", help="list display presets, or fit measured spectra",
                       description="List the display presets (pixels per degree, viewing distance, transfer, "
                                   "photometry; -v: where each number comes from), or fit smooth primaries "
                                   "to a measured wavelength_nm,r,g,b CSV and report the error (--fit).")
    p.add_argument("-v", "--verbose", action="store_true", help="show each preset's sources")
    p.add_argument("--fit", metavar="SPECTRA.csv", help="fit a measured wavelength_nm,r,g,b CSV and report the error")
    p.add_argument("--plot", metavar="FIT.png", help="with --fit: draw the fit")
    p.add_argument("--force", action="store_true", help="overwrite the plot if it exists")
    p.set_defaults(func=cmd_displays)
