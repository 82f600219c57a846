"""``vrcorrect correct --panel PANEL.png``: one picture of what the eye sees with its glasses, with no
correction and with the one written, side by side (each with its JOD, FLIP and objective, and its FLIP
error map), for anyone who would rather look than read the report.

Layer 7: the command line.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import check_writable


def check_panel(args: argparse.Namespace, clip: bool = False) -> None:
    """``--panel``: a new .png (or ``--force``), neither the input nor the output; a still only."""
    if not args.panel:
        return
    if clip:
        raise ValidationError("--panel", args.panel, "nothing for a clip (a still's picture; --report judges a clip)")
    if Path(args.panel).suffix.lower() != ".png":
        raise ValidationError("--panel", args.panel, "a path ending in .png")
    if Path(args.panel).resolve() in (Path(args.output).resolve(), Path(args.input).resolve()):
        raise ValidationError("--panel", args.panel, "a file other than the input and the output")
    check_writable(Path(args.panel), force=args.force)


def panel_writer(args: argparse.Namespace, eye, display, pupil: float, seen: list):
    """The panel's writer for the outputs written together: ``seen`` is each column's (label, metrics,
    images) from :func:`~vrcorrect.vision.metrics.evaluate_seen` (no correction, this correction)."""
    from ..studies.eval_panels import correction_panel  # on use: start-up time (matplotlib's colour map)

    title = (f"{Path(args.input).name}: the {args.eye} eye {eye.sphere_D:+.2f}/{eye.cylinder_D:+.2f} x "
             f"{eye.axis_deg:g} on {display.title}, through a {pupil:.2f} mm pupil")
    panel = correction_panel(title, "with glasses", seen)
    return lambda tmp: panel.save(tmp, format="PNG")
