"""Fresh pages of rendered text for judging a page rule (issue 44, the seventh look): text as a monitor
or a headset shows it (a document, a web page, an e-book), drawn with the fonts matplotlib ships.

    .venv/bin/python tools/render_pages.py DIR        # six 256 px pages, a second
    .venv/bin/python tools/render_pages.py --set 2 DIR2   # six more: other fonts, sizes, inks and prose
    .venv/bin/python tools/render_pages.py --set 3 DIR3   # and six more (the ninth look's judgement)
    .venv/bin/python tools/render_pages.py --set 4 DIR4   # six pages on grey paper (the tenth look)
    .venv/bin/python tools/robust_band_choice.py --no-builtin $(for f in DIR/*.png; do echo --image $f; done) "" white-rule

Every page is held out: the first set was made (2026-12-02) after the white-page rule was written
down, and no band or rule was chosen on it; it was spent judging that rule and then the real-time
band (docs/realtime.md).  The second set (``--set 2``, 2026-12-03) was written before the real-time
page band's second choice was judged, and was spent on it.  The third (``--set 3``) was written
before the ninth look's band (the pull towards the target) was chosen, and was spent judging it.  The
fourth (``--set 4``), pages on grey paper, was written before the tenth look's sweep for grey paper was
read, and is held out for judging it.  The text is this project's own prose.  Each page is drawn at
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
#: A second set (``--set 2``), written on 2026-12-03 before any correction was made of it, for
#: judging a page band chosen after the first set was spent: other fonts, sizes and inks, other prose.
TEXT2 = (
    "When the light in a headset rises, the iris closes within half a second, and the blur of each "
    "point shrinks with it. A correction that sharpens too much for the eye it meets rings at every "
    "edge, and on a page the ringing sits right beside the strokes of the letters. So the design "
    "must expect an eye a little sharper or a little softer than the one written in the prescription, "
    "and still leave the words easier to read than the plain page would be. Small print on a bright "
    "ground is the hardest case, and the one people notice first when they take their glasses off."
)
PAGES2 = {
    "italic13": ("DejaVuSerif-Italic.ttf", 13, (0, 0, 0), (255, 255, 255), None),
    "cmss15": ("cmss10.ttf", 15, (16, 16, 16), (255, 255, 255), None),
    "stix12": ("STIXGeneral.ttf", 12, (0, 0, 0), (252, 252, 250), None),
    "bold10": ("DejaVuSans-Bold.ttf", 10, (40, 40, 40), (255, 255, 255), None),
    "cmtt14": ("cmtt10.ttf", 14, (0, 0, 0), (248, 246, 240), None),
    "grey16": ("DejaVuSans.ttf", 16, (70, 70, 70), (255, 255, 255), (0, 102, 204)),
}
#: A third set (``--set 3``), written on 2026-12-03 (later) before the pull's band was chosen or
#: judged: again other faces, sizes and inks (two grey inks, a dark blue, a sepia on cream), other prose.
TEXT3 = (
    "Most of what a person reads on a screen is small dark type on a pale ground: mail, menus, code, "
    "the pages of a book. The eye's own lens blurs each letter a little, and more when the prescription "
    "is strong or the room is dim. A display that knows the blur can lean against it, brightening the "
    "paper just beside a stroke and darkening the stroke itself, until the sum on the retina is crisp. "
    "It must not lean too far: an eye rarely matches its prescription to the quarter dioptre, and a "
    "pupil changes with every scene, so the design has to be kind to eyes it was not made for."
)
PAGES3 = {
    "serifb14": ("DejaVuSerif-Bold.ttf", 14, (0, 0, 0), (255, 255, 255), None),
    "oblique12": ("DejaVuSans-Oblique.ttf", 12, (90, 90, 90), (255, 255, 255), None),
    "cmti16": ("cmti10.ttf", 16, (20, 20, 20), (255, 255, 255), None),
    "monob11": ("DejaVuSansMono-Bold.ttf", 11, (0, 32, 96), (255, 255, 255), None),
    "stixb13": ("STIXGeneralBol.ttf", 13, (60, 40, 20), (250, 245, 232), None),
    "grey20": ("DejaVuSans.ttf", 20, (100, 100, 100), (255, 255, 255), (180, 40, 40)),
}
#: A fourth set (``--set 4``), written on 2026-12-03 (the tenth look) before a band for grey paper was
#: chosen: pages on grey paper (newsprint, e-ink, a grey theme; paper from 0.40 to 0.80 of white's
#: light), other faces and prose.
TEXT4 = (
    "Not every page is white. Newsprint is grey, an e-reader's screen is the colour of weak tea, and "
    "many people turn the brightness of a reading app down until the paper is a pale stone. On such a "
    "page there is room above the paper for light the display may add, and a correction is tempted to "
    "spend it all on bright rims around each letter. An eye that focuses a little better than expected "
    "then sees those rims as halos, and the plain grey page would have been kinder to it."
)
PAGES4 = {
    "news12": ("DejaVuSerif.ttf", 12, (30, 30, 30), (200, 200, 196), None),
    "eink14": ("STIXGeneral.ttf", 14, (20, 20, 20), (214, 210, 200), None),
    "sans13": ("DejaVuSans.ttf", 13, (0, 0, 0), (185, 185, 185), None),
    "mono11": ("DejaVuSansMono.ttf", 11, (25, 25, 25), (231, 231, 231), None),
    "cmr16": ("cmr10.ttf", 16, (10, 10, 10), (170, 170, 172), None),
    "bold12": ("DejaVuSans-Bold.ttf", 12, (45, 40, 35), (205, 200, 190), None),
}
SETS = {1: (PAGES, TEXT), 2: (PAGES2, TEXT2), 3: (PAGES3, TEXT3), 4: (PAGES4, TEXT4)}
SIDE = 256
MARGIN = 8


def _lines(font, width: int, text: str = TEXT) -> list[list[str]]:
    lines: list[list[str]] = [[]]
    for word in text.split():
        trial = " ".join(lines[-1] + [word])
        if lines[-1] and font.getlength(trial) > width:
            lines.append([word])
        else:
            lines[-1].append(word)
    return lines


def render(name: str, number: int = 1):
    """One page of set ``number`` as a PIL image (RGB, SIDE x SIDE)."""
    import matplotlib
    from PIL import Image, ImageDraw, ImageFont

    pages, text = SETS[number]
    font_file, size, ink, paper, link = pages[name]
    font = ImageFont.truetype(str(Path(matplotlib.get_data_path()) / "fonts" / "ttf" / font_file), size)
    page = Image.new("RGB", (SIDE, SIDE), paper)
    draw = ImageDraw.Draw(page)
    step = round(size * 1.35)
    y, n = MARGIN, 0
    while y + step <= SIDE - MARGIN + size // 3:
        for line in _lines(font, SIDE - 2 * MARGIN, text):
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
    ap.add_argument("--set", type=int, choices=sorted(SETS), default=1, dest="number",
                    help="which set of pages: 1 (2026-12-02; spent on the white-page rule and the real-time band), "
                    "2 (2026-12-03; spent on the eighth look's band), 3 (2026-12-03, later; spent on the ninth) or "
                    "4 (2026-12-03, pages on grey paper; the tenth look)")
    args = ap.parse_args(argv)
    try:
        args.folder.mkdir(parents=True, exist_ok=True)
        for name in SETS[args.number][0]:
            out = args.folder / f"{name}.png"
            if out.exists() and not args.force:
                print(f"render_pages: {out}: exists; pass --force to overwrite it", file=sys.stderr)
                return 2
            render(name, args.number).save(out)
            print(out)
    except OSError as e:
        print(f"render_pages: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
