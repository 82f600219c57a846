"""``vrcorrect rx new|validate``: prescription files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..specs.prescription import load_prescription, validate_file, write_template


def cmd_rx_new(args: argparse.Namespace) -> int:
    write_template(Path(args.path), force=args.force)
    print(f"wrote {args.path}: a commented prescription template; fill in both eyes, then run "
          f"'vrcorrect rx validate {args.path}'")
    return 0


def cmd_rx_validate(args: argparse.Namespace) -> int:
    problems = validate_file(Path(args.path))
    if problems:
        print(f"{args.path}: {len(problems)} problem{'s' if len(problems) != 1 else ''}:", file=sys.stderr)
        for p in problems:
            print(f"  - {p}", file=sys.stderr)
        return 1

    rx = load_prescription(Path(args.path))
    print(f"{args.path}: valid")
    for name in ("right", "left"):
        e = rx.eye(name)
        pv = e.power_vector()
        print(f"  {name:5s} {e.sphere_D:+.2f} / {e.cylinder_D:+.2f} x {e.axis_deg:g}, pupil {e.pupil_diameter_mm:g} mm"
              f"  (M {pv.M_D:+.2f}, J0 {pv.J0_D:+.2f}, J45 {pv.J45_D:+.2f} D)")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rx", help="prescription files")
    rsub = p.add_subparsers(dest="rx_command", metavar="ACTION")
    rsub.required = True
    q = rsub.add_parser("new", help="write a commented prescription template")
    q.add_argument("path", metavar="PATH")
    q.add_argument("--force", action="store_true", help="overwrite PATH if it exists")
    q.set_defaults(func=cmd_rx_new)
    q = rsub.add_parser("validate", help="check a prescription file and report every problem")
    q.add_argument("path", metavar="PATH")
    q.set_defaults(func=cmd_rx_validate)
