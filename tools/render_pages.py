"""Fresh pages of rendered text for judging a page rule (issue 44, the seventh look): text as a monitor
or a headset shows it (a document, a web page, an e-book), drawn with the fonts matplotlib ships.

    .venv/bin/python tools/render_pages.py DIR        # six 256 px pages, a second
    .venv/bin/python tools/robust_band_choice.py --no-builtin $(for f in DIR/*.png; do echo --image $f; done) "" white-rule

Every page is held out: they were made (2026-12-02) after the white-page rule was written down, and
no band or rule was chosen on them.  The text is this project's own prose.  Each page is drawn at
256 px, the size ``robust_band_choice.py`` works at, so no resampling touches the strokes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

TEXT = (
    "A lens that is too strong for the eye brings distant light to a focus in front of the retina, "
    "and every point of a page spreads into a small disc. Glasses move that focus back. A display "
    "cannot move it, but it can change what it shows, so that the blur the eye adds turns the shown "
    "picture into something close to the picture that was meant. The eye's pupil sets how large the "
    "disc is: in bright light it narrows, and a correction made for a wider pupil then sharpens edges "
    "that the eye no longer blurs so much. Reading is where the blur costs most, because letters are "
    "small, dark and close together, and the paper around them is bright."
)

#: name: (font file in matplotlib's fonts/ttf, size in px, ink, paper, link colour or None)
PAGES = {
    "serif12": ("DejaVuSerif.ttf", 12, (0, 0, 0), (255, 255, 255), None),
    "sans11": ("DejaVuSans.ttf", 11, (34, 34, 34), (255, 255, 255), None),
    "stix14": ("STIXGeneral.ttf", 14, (0, 0, 0), (255, 255, 255), None),
    "mono12": ("DejaVuSansMono.ttf", 12, (20, 20, 20), (250, 250, 250), None),
    "cmr18": ("cmr10.ttf", 18, (0, 0, 0), (255, 255, 255), None),
    "links14": ("DejaVuSans.ttf", 14, (32, 33, 36), (255, 255, 255), (26, 13, 171)),
}
SIDE = 256
MARGIN = 8


def _lines(font, width: int) -> list[list[str]]:
    lines: list[list[str]] = [[]]
    for word in TEXT.split():
        trial = " ".join(lines[-1] + [word])
        if lines[-1] and font.getlength(trial) > width:
            lines.append([word])
        else:
            lines[-1].append(word)
    return lines


def render(name: str):
    """One page as a PIL image (RGB, SIDE x SIDE)."""
    import matplotlib
    from PIL import Image, ImageDraw, ImageFont

    font_file, size, ink, paper, link = PAGES[name]
    font = ImageFont.truetype(str(Path(matplotlib.get_data_path()) / "fonts" / "ttf" / font_file), size)
    page = Image.new("RGB", (SIDE, SIDE), paper)
    draw = ImageDraw.Draw(page)
    step = round(size * 1.35)
    y, n = MARGIN, 0
    while y + step <= SIDE - MARGIN + size // 3:
        for line in _lines(font, SIDE - 2 * MARGIN):
            if y + step > SIDE - MARGIN + size // 3:
                break
            x = MARGIN
            for word in line:
                colour = link if link is not None and n % 7 in (3, 4) else ink   # a link now and then
                draw.text((x, y), word, font=font, fill=colour)
                x += font.getlength(word + " ")
                n += 1
            y += step
        y += step // 2                                                        # a paragraph's gap
    return page


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="render_pages", description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path, help="where the pages go (made if missing)")
    ap.add_argument("--force", action="store_true", help="overwrite pages that are there already")
    args = ap.parse_args(argv)
    try:
        args.folder.mkdir(parents=True, exist_ok=True)
        for name in PAGES:
            out = args.folder / f"{name}.png"
            if out.exists() and not args.force:
                print(f"render_pages: {out}: exists; pass --force to overwrite it", file=sys.stderr)
                return 2
            render(name).save(out)
            print(out)
    except OSError as e:
        print(f"render_pages: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
