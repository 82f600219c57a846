"""``vrcorrect rx new|validate``: prescription files.

``validate`` prints ``PATH: valid`` and both eyes, or (exit status 2, like any bad input) every
problem at once under a ``vrcorrect: error: PATH: N problems:`` line."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..plumbing.errors import FieldProblem, ValidationError, ValidationErrors
from ..specs.prescription import load_prescription, validate_file, write_template
from ..specs.prescription.files import TEMPLATE_NOTES
from ..specs.prescription.notation import DEFAULT_VERTEX_MM, at_eye, parse_spectacle_rx, split_add
from ..specs.vocabulary import Eye


def cmd_rx_new(args: argparse.Namespace) -> int:
    if args.age is not None and not math.isfinite(args.age):
        raise ValidationError("--age", args.age, "a number of years from 1 to 120")
    if args.lag is not None and not math.isfinite(args.lag):
        raise ValidationError("--lag", args.lag, "a number of dioptres from 0 to 2")
    lines = {Eye.RIGHT: args.right, Eye.LEFT: args.left}
    eyes, adds, lenses = {}, {}, {}
    for name, text in lines.items():
        line, adds[name] = split_add(text)
        lenses[name] = None if text is None else parse_spectacle_rx(line, f"--{name}")
        eyes[name] = None if text is None else at_eye(*lenses[name], args.vertex)
    if all(e is None for e in eyes.values()) and args.age is None and args.lag is None:
        write_template(Path(args.path), force=args.force)
        print(f"wrote {args.path}: a commented prescription template; fill in both eyes, then run "
              f"'vrcorrect rx validate {args.path}' (or write it from your glasses' prescription: "
              f"vrcorrect rx new {args.path} --force --right \"-2.00 -1.00 x 120\" --left \"-1.50\" --age 45)")
        return 0
    given = [f"{name} '{text}'" for name, text in lines.items() if text is not None]
    notes = ("From a spectacle prescription: " + ", ".join(given) + (
        f", the lenses {args.vertex:g} mm from the eye; {MOVED_TO_EYE}." if args.vertex else
        f", {GIVEN_AT_EYE}.") if given else TEMPLATE_NOTES)
    try:
        write_template(Path(args.path), force=args.force, notes=notes, age_years=args.age, lag_D=args.lag, **eyes)
    except ValidationErrors as err:
        raise ValidationErrors(_said_at_eye(p, lenses, eyes, args.vertex) for p in err.problems) from None
    print(f"wrote {args.path}: a commented prescription file" + (f" from {', '.join(given)}" if given else ""))
    if args.vertex and any(eyes[name] != lenses[name] for name in lines):
        print(f"  the powers moved from the lenses, {args.vertex:g} mm in front of the eye, to the eye (each "
              "principal meridian's F / (1 - d F); --vertex 0 keeps them, as for a contact-lens prescription):")
    _print_eyes(load_prescription(Path(args.path)))
    for name, add in adds.items():
        if add is not None:
            print(f"  the {name} eye's ADD {add:+.2f} (the reading addition) is not used: vrcorrect corrects the "
                  "distance prescription at the display's distance, and takes the eye's own focus from --age "
                  "(or accommodation_D in the file), and its lag from --lag")
    missing = [name for name, e in eyes.items() if e is None]
    for name in missing:
        print(f"  the {name} eye is plano (0.00) as a placeholder: give --{name}, or edit the file")
    return 0


def _said_at_eye(problem: FieldProblem, lenses: dict, eyes: dict, vertex_mm: float) -> FieldProblem:
    """A problem with an eye's sphere or cylinder, which were moved from the lenses to the eye, told with
    the lens's power it came from (a -30.00 lens is a -22.06 eye at 12 mm: the user typed the first)."""
    name, _, key = problem.field.partition(".")
    index = {"sphere_D": 0, "cylinder_D": 1}.get(key)
    if index is None or lenses.get(name) is None or lenses[name] == eyes[name]:
        return problem
    return FieldProblem(f"{problem.field} (at the eye, from the lens's {lenses[name][index]:+.2f} D {vertex_mm:g} mm "
                        "in front of it)", problem.value, problem.allowed)


def cmd_rx_validate(args: argparse.Namespace) -> int:
    problems = validate_file(Path(args.path))
    if problems:
        # bad input, reported as every command reports it (cli.main: "vrcorrect: error: ...", exit 2):
        # the file and the number of problems, then one "  - field = value ..." line per problem
        raise ValidationErrors(problems, source=str(args.path))

    rx = load_prescription(Path(args.path))
    print(f"{args.path}: valid")
    _print_eyes(rx)
    from ..physics.refraction import max_meridian_power_D  # on use: start-up time (apps/__init__)

    strong = [name for name in Eye if max_meridian_power_D(rx.eye(name).power_vector()) >= STRONG_D]
    if strong and not any(mark in rx.notes for mark in AT_EYE_MARKS):
        e = rx.eye(strong[0])
        moved = at_eye(e.sphere_D, e.cylinder_D, e.axis_deg, DEFAULT_VERTEX_MM)
        print(f"  the {' and '.join(strong)} eye's powers reach {STRONG_D:g} D: they are modelled as the eye's own, at "
              f"the cornea. If they are your glasses' (the lenses about {DEFAULT_VERTEX_MM:g} mm in front of the eye), "
              f"the eye's are {moved[0]:+.2f} / {moved[1]:+.2f} x {moved[2]:g} for the {strong[0]} eye: 'vrcorrect "
              "rx new PATH --right ... --left ...' writes them (--vertex MM if your prescription states its BVD)")
    return 0


#: Where ``rx validate`` says a spectacle prescription would differ at the eye: a meridian of this many
#: dioptres or more (below it the two differ by under 0.2 D at 12 mm).
STRONG_D = 4.0

#: What ``rx new`` writes in the notes once it has moved the lenses' powers to the eye, and where they
#: were given at the eye (``--vertex 0``).
MOVED_TO_EYE = "the powers here are at the eye"
GIVEN_AT_EYE = "the powers at the eye (--vertex 0)"

#: Notes that say a file's powers are the eye's own (``rx new``'s, the bundled sample's): then ``validate``
#: says nothing of spectacle lenses.
AT_EYE_MARKS = (MOVED_TO_EYE, GIVEN_AT_EYE, "the powers are the eyes' own")


def _print_eyes(rx) -> None:
    """Both eyes in words, and what their accommodation is taken to be."""
    for name in Eye:
        e = rx.eye(name)
        pv = e.power_vector()
        print(f"  {name:5s} {e.sphere_D:+.2f} / {e.cylinder_D:+.2f} x {e.axis_deg:g}, pupil {e.pupil_diameter_mm:g} mm"
              f"  (M {pv.M_D:+.2f}, J0 {pv.J0_D:+.2f}, J45 {pv.J45_D:+.2f} D), accommodation {e.accommodation_D:.2f} D"
              + (f" (expected at age {rx.age_years:g}: none stated)" if name in rx.accommodation_from_age else "")
              + (f", lag {e.accommodative_lag_D:.2f} D at 40 cm" if e.accommodative_lag_D else ""))
    if rx.age_years is None and any(rx.eye(name).accommodation_D == 0.0 for name in Eye):
        print("  no age_years: an eye with accommodation 0 is modelled as one that cannot focus (a presbyope's); if "
              "yours can, give age_years and leave accommodation_D out (or state its amplitude), or a correction may "
              "sharpen what the eye already focuses sharp")


#: ``rx new``'s options whose value is a prescription line, which may start with a minus sign.
LINE_OPTIONS = ("--right", "--left")


def join_line_values(argv: list[str]) -> list[str]:
    """``rx new --left -3.00/+0.50x60`` as ``--left=-3.00/+0.50x60``: argparse would take a value that starts
    with a minus sign and has no space for an option of its own (\"expected one argument\")."""
    if argv[:2] != ["rx", "new"]:
        return argv
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in LINE_OPTIONS and i + 1 < len(argv) and argv[i + 1].startswith("-") and argv[i + 1] not in (
                *LINE_OPTIONS, "--age", "--lag", "--vertex", "--force", "-h", "--help"):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rx", help="prescription files",
                       description="Write a commented prescription template to fill in (new), or check a "
                                   "prescription file and report every problem in it at once (validate).")
    rsub = p.add_subparsers(dest="rx_command", metavar="ACTION")
    rsub.required = True
    q = rsub.add_parser("new", help="write a commented prescription template, or a file from your glasses' "
                        "prescription (--right, --left, --age)")
    q.add_argument("path", metavar="PATH")
    q.add_argument("--right", metavar="RX", help="the right eye (OD) as a spectacle prescription writes it: SPHERE, "
                   "or SPHERE CYLINDER x AXIS, e.g. \"-2.00 -1.00 x 120\", \"-1.50 DS\", \"plano -0.75 x 90\" "
                   "(either cylinder form; a reading addition after it, ADD +2.00, is read and not used)")
    q.add_argument("--left", metavar="RX", help="the left eye (OS), as --right")
    q.add_argument("--age", type=float, metavar="YEARS", help="the wearer's age (age_years, 1 to 120): it sets the "
                   "viewing pupil and how far each eye still focuses")
    q.add_argument("--lag", type=float, metavar="D", help="both eyes' accommodative lag (accommodative_lag_D, 0 to 2 "
                   "D): how far behind a near card at 40 cm they focus, as MEM retinoscopy measures it; left out, 0")
    q.add_argument("--vertex", type=float, metavar="MM", default=DEFAULT_VERTEX_MM,
                   help="the lenses' distance in front of the eye (BVD, 0 to 25 mm; default %(default)g): the "
                   "file holds the eye's own refraction, so each line's powers are moved there (a -6.00 lens at 12 "
                   "mm is a -5.60 eye); 0 for a contact-lens prescription")
    q.add_argument("--force", action="store_true", help="overwrite PATH if it exists")
    q.set_defaults(func=cmd_rx_new)
    q = rsub.add_parser("validate", help="check a prescription file and report every problem")
    q.add_argument("path", metavar="PATH")
    q.set_defaults(func=cmd_rx_validate)
