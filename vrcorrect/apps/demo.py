"""The bundled default job: what the sample prescription's eyes see of the
sample image, plus a sweep showing blur growing with dioptres and turning
with the cylinder axis."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path
from typing import Iterator

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..plumbing.charts import sample_image_path, siemens_star
from ..plumbing.errors import InputError
from ..plumbing.fileio import check_writable
from ..plumbing.imageio import read_image, write_png
from ..specs.display import decode, encode, get_display
from ..specs.prescription import EyeRx, bundled_sample_path, load_prescription
from ..specs.vocabulary import Eye


def _label(img: np.ndarray, text: str) -> np.ndarray:
    """Put a caption strip above an sRGB image."""
    h, w, _ = img.shape
    strip = Image.new("RGB", (w, 22), "white")
    draw = ImageDraw.Draw(strip)
    try:
        font = ImageFont.load_default(size=14)
    except TypeError:
        font = ImageFont.load_default()
    draw.text((4, 3), text, fill="black", font=font)
    return np.concatenate([np.asarray(strip, dtype=np.float32) / 255.0, img], axis=0)


def _row(images: list[np.ndarray], gap: int = 6) -> np.ndarray:
    h = max(i.shape[0] for i in images)
    parts = []
    for i, img in enumerate(images):
        pad = np.ones((h, img.shape[1], 3), dtype=np.float32)
        pad[:img.shape[0]] = img
        parts.append(pad)
        if i < len(images) - 1:
            parts.append(np.ones((h, gap, 3), dtype=np.float32))
    return np.concatenate(parts, axis=1)


def run_demo(out: Path, display_name: str = "quest2", force: bool = False) -> Iterator[str]:
    """Write the demo pictures into ``out``; yields one line per file."""
    # the physics is imported here, not above: every vrcorrect run imports this module to build its parser
    from ..physics.kernel import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
        KernelOptions,
        build_kernel,
    )
    from ..physics.options import (
        OpticsOptions,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )
    from ..vision.forward import (
        what_the_eye_sees,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    out = Path(out)
    names = ["right_eye_sees.png", "left_eye_sees.png", "demo_panel.png", "dioptre_sweep.png"]
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    display = get_display(display_name)  # before creating the folder: a bad name leaves nothing behind
    out.mkdir(parents=True, exist_ok=True)
    for n in names:
        check_writable(out / n, force=force)
    rx = load_prescription(bundled_sample_path())
    image = read_image(sample_image_path())
    linear = decode(display, image)
    seen = {}
    for eye_name in Eye:
        eye = rx.eye(eye_name)
        kernel = build_kernel(eye, display)
        view, _ = what_the_eye_sees(linear, kernel)
        seen[eye_name] = encode(display, view)
        write_png(out / f"{eye_name}_eye_sees.png", seen[eye_name], force=force)
        yield (f"wrote {out / (eye_name + '_eye_sees.png')}: {eye_name} eye {eye.sphere_D:+.2f} / "
               f"{eye.cylinder_D:+.2f} x {eye.axis_deg:g} on {display.title} ({kernel.size} px kernel)")
    r, left = rx.eye(Eye.RIGHT), rx.eye(Eye.LEFT)
    panel = _row([_label(image, "displayed image"),
                  _label(seen[Eye.RIGHT], f"right eye {r.sphere_D:+.2f}/{r.cylinder_D:+.2f}x{r.axis_deg:g}"),
                  _label(seen[Eye.LEFT], f"left eye {left.sphere_D:+.2f}/{left.cylinder_D:+.2f}x{left.axis_deg:g}")])
    write_png(out / "demo_panel.png", panel, force=force)
    yield f"wrote {out / 'demo_panel.png'}: displayed image | right eye sees | left eye sees"

    # Sweep at optical infinity (the paper's setting), 4 mm pupil, on this display.
    star = siemens_star(160, spokes=16)
    star_lin = decode(display, star)
    opts = KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf))
    rows = []
    base = EyeRx(sphere_D=0.0, cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=4.0)
    sphere_row = [_label(star, "displayed")]
    for s in (-0.5, -1.0, -2.0, -4.0):
        k = build_kernel(replace(base, sphere_D=s), display, opts)
        sphere_row.append(_label(encode(display, what_the_eye_sees(star_lin, k)[0]), f"sphere {s:+.1f} D"))
    rows.append(_row(sphere_row))
    cyl_row = [_label(star, "displayed")]
    for axis in (0, 45, 90, 135):
        k = build_kernel(replace(base, cylinder_D=-2.0, axis_deg=float(axis)), display, opts)
        cyl_row.append(_label(encode(display, what_the_eye_sees(star_lin, k)[0]), f"plano/-2.00 x {axis}"))
    rows.append(_row(cyl_row))
    sheet = np.concatenate([rows[0], np.ones((8, rows[0].shape[1], 3), np.float32), rows[1]], axis=0)
    write_png(out / "dioptre_sweep.png", sheet, force=force)
    yield (f"wrote {out / 'dioptre_sweep.png'}: top, blur grows with myopia; bottom, the blur of a "
           f"-2.00 D cylinder turns with its axis (it smears perpendicular to the axis)")


def cmd_demo(args: argparse.Namespace) -> int:
    for line in run_demo(Path(args.out), display_name=args.display, force=args.force):
        print(line)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the bundled default: what the sample eyes see of the sample image",
                       description="Write four pictures to --out: what each eye of the bundled sample "
                                   "prescription sees of the bundled sample image, the two side by side, and a "
                                   "sweep of the blur growing with dioptres and turning with the cylinder axis.")
    p.add_argument("--out", default="out", help="output folder (default ./out)")
    p.add_argument("--display", default="quest2", metavar="PRESET")
    p.add_argument("--force", action="store_true", help="overwrite earlier demo outputs")
    p.set_defaults(func=cmd_demo)
