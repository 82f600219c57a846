"""Regenerate vrcorrect/data/sample.png, the bundled sample image.

The photograph is scikit-image's "astronaut" (NASA, public domain); the other
three quadrants are vrcorrect's procedural charts.  Run:
    .venv/bin/python tools/make_sample.py [--force]
"""
import argparse
import sys

from skimage import data

from vrcorrect.plumbing.charts import make_sample_image, sample_image_path
from vrcorrect.plumbing.imageio import write_png


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--force", action="store_true", help="overwrite the existing sample")
    args = ap.parse_args()
    img = make_sample_image(data.astronaut() / 255.0)
    write_png(sample_image_path(), img, force=args.force)
    print(f"wrote {sample_image_path()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
