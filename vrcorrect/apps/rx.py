"""``vrcorrect rx new|validate``: prescription files.

``validate`` prints ``PATH: valid`` and both eyes, or (exit status 2, like any bad input) every
problem at once under a ``vrcorrect: error: PATH: N problems:`` line."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..plumbing.errors import ValidationErrors
from ..specs.prescription import load_prescription, validate_file, write_template
from ..specs.vocabulary import Eye


def cmd_rx_new(args: argparse.Namespace) -> int:
    write_template(Path(args.path), force=args.force)
    print(f"wrote {args.path}: a commented prescription template; fill in both eyes, then run "
          f"'vrcorrect rx validate {args.path}'")
    return 0


def cmd_rx_validate(args: argparse.Namespace) -> int:
    problems = validate_file(Path(args.path))
    if problems:
        # bad input, reported as every command reports it (cli.main: "vrcorrect: error: ...", exit 2):
        # the file and the number of problems, then one "  - field = value ..." line per problem
        raise ValidationErrors(problems, source=str(args.path))

    rx = load_prescription(Path(args.path))
    print(f"{args.path}: valid")
    for name in Eye:
        e = rx.eye(name)
        pv = e.power_vector()
        print(f"  {name:5s} {e.sphere_D:+.2f} / {e.cylinder_D:+.2f} x {e.axis_deg:g}, pupil {e.pupil_diameter_mm:g} mm"
              f"  (M {pv.M_D:+.2f}, J0 {pv.J0_D:+.2f}, J45 {pv.J45_D:+.2f} D), accommodation {e.accommodation_D:.2f} D"
              + (f" (expected at age {rx.age_years:g}: none stated)" if name in rx.accommodation_from_age else ""))
    if rx.age_years is None and any(rx.eye(name).accommodation_D == 0.0 for name in Eye):
        print("  no age_years: an eye with accommodation 0 is modelled as one that cannot focus (a presbyope's); if "
              "yours can, give age_years and leave accommodation_D out (or state its amplitude), or a correction may "
              "sharpen what the eye already focuses sharp")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rx", help="prescription files",
                       description="Write a commented prescription template to fill in (new), or check a "
                                   "prescription file and report every problem in it at once (validate).")
    rsub = p.add_subparsers(dest="rx_command", metavar="ACTION")
    rsub.required = True
    q = rsub.add_parser("new", help="write a commented prescription template")
    q.add_argument("path", metavar="PATH")
    q.add_argument("--force", action="store_true", help="overwrite PATH if it exists")
    q.set_defaults(func=cmd_rx_new)
    q = rsub.add_parser("validate", help="check a prescription file and report every problem")
    q.add_argument("path", metavar="PATH")
    q.set_defaults(func=cmd_rx_validate)
