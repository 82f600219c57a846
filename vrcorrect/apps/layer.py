"""``vrcorrect layer install | uninstall | status``: vrcorrect as an implicit OpenXR API layer.

The layer's library (``layer/``: ``vrcorrect_layer.c`` and ``vrcorrect_vulkan.c``, the C shim that
embeds this Python and runs :mod:`vrcorrect.runtime.layer.engine`) is compiled when vrcorrect is built
(``pip install``, ``pip wheel``) and ships inside the package.  ``install`` writes the
implicit-layer manifest naming it to ``$XDG_DATA_HOME/openxr/1/api_layers/implicit.d/`` (default
``~/.local/share``: where the OpenXR loader looks for a user's layers), which the loader reads for
every application; ``vrcorrect_layer.cfg`` (the Python home and the ``sys.path`` entries the embedded
interpreter needs) to ``$XDG_DATA_HOME/vrcorrect/layer/``; and the layer configuration
(prescription, display) to ``$XDG_CONFIG_HOME/vrcorrect/layer.json``.  Only a source checkout
without a built library (or with one older than its sources) compiles ``layer/`` there with the
machine's C compiler, and says so (the fallback).  ``DISABLE_VRCORRECT_LAYER=1`` in an application's
environment makes the loader skip the layer.  A user's file is never overwritten without
``--force`` (files the command wrote itself are recognised and replaced).

``status`` says whether the loader will find the layer, which prescription and display it will
use, and the last lines of its log.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Mapping

from ..plumbing.errors import InputError, ValidationError
from ..runtime.layer.build import (
    CFG,
    LIBRARY,
    MARK,
    SOURCE_DIR,
    build_layer,
    manifest_text,
    packaged_library,
    stale_sources,
    write_cfg,
)
from ..runtime.layer.config import DISABLE_ENV, LAYER_NAME, OFF_ENV, config_path, log_path, off_file, read_config
from ..specs.vocabulary import PERIPHERY_DESCRIPTIONS, Periphery, names
from .common import parse_fovea, parse_gaze, parse_pupil
from .realtime_options import parse_budget

MANIFEST = "vrcorrect_layer.json"


def _env(env: Mapping[str, str] | None) -> Mapping[str, str]:
    return os.environ if env is None else env


def manifest_dir(env: Mapping[str, str] | None = None) -> Path:
    """The user's implicit-layer folder the loader searches: ``$XDG_DATA_HOME/openxr/1/api_layers/
    implicit.d`` (default ``~/.local/share``).  The Khronos loader looks for API-layer manifests in
    ``$XDG_DATA_HOME``, ``$XDG_DATA_DIRS``, ``$XDG_CONFIG_DIRS`` and ``/etc``, not in
    ``$XDG_CONFIG_HOME`` (which it reads only for ``active_runtime.json``): checked with pyopenxr's
    loader, ``XR_LOADER_DEBUG=all``."""
    env = _env(env)
    base = env.get("XDG_DATA_HOME") or str(Path(env.get("HOME") or Path.home()) / ".local" / "share")
    return Path(base) / "openxr" / "1" / "api_layers" / "implicit.d"


def library_dir(env: Mapping[str, str] | None = None) -> Path:
    """Where ``install`` puts the compiled layer."""
    env = _env(env)
    base = env.get("XDG_DATA_HOME") or str(Path(env.get("HOME") or Path.home()) / ".local" / "share")
    return Path(base) / "vrcorrect" / "layer"


def _ours(path: Path) -> bool:
    try:
        return MARK in path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return False


def _check_free(path: Path, force: bool) -> None:
    if path.exists() and not force and not _ours(path):
        raise InputError(f"{path} exists and was not written by vrcorrect; pass --force to replace it")


def layer_library(env: Mapping[str, str] | None = None) -> tuple[Path, str]:
    """The library the manifest will name, and a line saying where it came from: the one built into
    the package (``pip install``), else (a source checkout without one, or with one older than the
    sources it was built from) one compiled now into the user's data folder: the fallback."""
    library = packaged_library()
    if library is not None:
        stale = stale_sources(library)
        if not stale:
            return library, f"using the layer built into this installation: {library}"
        why = (f"the built layer {library} is older than its sources ({', '.join(p.name for p in stale)}): "
               "compiling them")
    else:
        why = f"this installation has no built layer (a source checkout): compiling {SOURCE_DIR}"
    built = build_layer(library_dir(env))
    return built, (f"{why} with the machine's C compiler, the fallback for a source checkout "
                   f"(pip install builds the layer into the package): built {built}")


def cmd_install(args: argparse.Namespace, env: Mapping[str, str] | None = None) -> int:
    from ..specs.display import get_display  # on use: start-up time (apps/__init__: the parser loads no layer below)
    from ..specs.prescription import (
        load_prescription,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    env = _env(env)
    rx = Path(args.rx).expanduser().resolve() if args.rx else None
    if rx is not None:
        load_prescription(rx)                        # refused before anything is written
    if args.display:
        get_display(args.display)
    if args.iterations is not None and not 1 <= args.iterations <= 64:
        raise ValidationError("--iterations-per-frame", args.iterations, "1 to 64")
    pupil = parse_pupil(args.pupil) if args.pupil is not None else None
    robust = {"on": True, "off": False}[args.robust] if args.robust is not None else None
    fovea = parse_fovea(args.fovea) if args.fovea is not None else None
    gaze = parse_gaze(args.gaze) if args.gaze is not None else None
    if gaze is not None and fovea is None:
        raise ValidationError("--gaze", args.gaze, "only with --fovea DEG (the window it places)")
    if args.periphery is not None and fovea is None:
        raise ValidationError("--periphery", args.periphery, "only with --fovea DEG (outside its window)")
    options = {k: v for k, v in (("iterations_per_frame", args.iterations), ("pupil", pupil), ("robust", robust),
                                 ("band", args.band),
                                 ("fovea_deg", fovea), ("gaze_deg", None if gaze is None else list(gaze)),
                                 ("fovea_periphery", args.periphery),
                                 ("budget_ms", None if args.budget_ms is None else
                                  parse_budget(args.budget_ms, "admm")))
               if v is not None}
    manifest = manifest_dir(env) / MANIFEST
    config = config_path(env)
    _check_free(manifest, args.force)
    if rx is not None or args.display or options:
        _check_free(config, args.force)
    library, how = layer_library(env)
    write_cfg(library_dir(env))
    if rx is not None or args.display or options or not config.exists():
        doc = {"comment": MARK}
        if config.exists() and _ours(config):
            try:
                doc.update(json.loads(config.read_text(encoding="utf-8")))
            except (OSError, json.JSONDecodeError):
                pass
        if rx is not None:
            doc["rx"] = str(rx)
        if args.display:
            doc["display"] = args.display
        if options:
            doc["options"] = {**(doc.get("options") if isinstance(doc.get("options"), dict) else {}), **options}
        config.parent.mkdir(parents=True, exist_ok=True)
        config.write_text(json.dumps(doc, indent=2) + "\n")
    manifest.parent.mkdir(parents=True, exist_ok=True)
    manifest.write_text(manifest_text(library))
    print(how)
    print(f"wrote {manifest} (implicit layer {LAYER_NAME}; {DISABLE_ENV}=1 disables it)")
    print(f"configuration {config}")
    if "rx" not in json.loads(config.read_text(encoding="utf-8")) and not env.get("VRCORRECT_RX"):
        print("no prescription yet: frames pass through until one is set (vrcorrect layer install --rx FILE)")
    return 0


def cmd_uninstall(args: argparse.Namespace, env: Mapping[str, str] | None = None) -> int:
    env = _env(env)
    manifest = manifest_dir(env) / MANIFEST
    if not manifest.exists():
        print(f"not installed ({manifest} does not exist)")
        return 0
    _check_free(manifest, args.force)
    manifest.unlink()
    folder = library_dir(env)
    for name in (LIBRARY, CFG):
        (folder / name).unlink(missing_ok=True)
    print(f"removed {manifest} and the layer in {folder} (the configuration {config_path(env)} is kept)")
    return 0


def status_lines(env: Mapping[str, str] | None = None, tail: int = 10) -> list[str]:
    """What ``status`` prints."""
    env = _env(env)
    lines = []
    manifest = manifest_dir(env) / MANIFEST
    if not manifest.exists():
        lines.append(f"layer: not installed ({manifest} does not exist; run vrcorrect layer install)")
    else:
        try:
            doc = json.loads(manifest.read_text(encoding="utf-8"))
            library = Path(doc["api_layer"]["library_path"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            lines.append(f"layer: {manifest} is not a valid layer manifest ({exc}); the loader will skip it")
            library = None
        if library is not None:
            found = "the loader will find it" if library.is_file() else f"but {library} is missing: the loader will skip it"
            lines.append(f"layer: {manifest} names {library}; {found}")
    if env.get(DISABLE_ENV):
        lines.append(f"disabled in this environment: {DISABLE_ENV}={env[DISABLE_ENV]} (the loader skips the layer)")
    if env.get("XR_RUNTIME_JSON"):
        lines.append(f"runtime: XR_RUNTIME_JSON={env['XR_RUNTIME_JSON']}")
    off = off_file(env)
    value = env.get(OFF_ENV, "").strip().lower()
    if value and value not in ("0", "false", "no", "off"):
        lines.append(f"switched off: {OFF_ENV}={env[OFF_ENV]} (frames pass through)")
    elif off.exists():
        lines.append(f"switched off: {off} exists (frames pass through; delete it to switch on)")
    try:
        config = read_config(env)
    except (InputError, ValidationError) as exc:
        lines.append(f"configuration: {exc}")
        config = None
    if config is not None:
        where = config.source or f"{config_path(env)} (absent)"
        lines.append(f"configuration: {where}")
        if config.rx is None:
            lines.append("prescription: none (frames pass through until one is set)")
        else:
            from ..plumbing.errors import (
                VrcorrectError,  # on use: start-up time (apps/__init__: the parser loads no layer below)
            )
            from ..specs.prescription import (
                load_prescription,  # on use: start-up time (apps/__init__: the parser loads no layer below)
            )

            try:
                load_prescription(config.rx)
                lines.append(f"prescription: {config.rx} (valid)")
            except VrcorrectError as exc:
                lines.append(f"prescription: {config.rx} is not usable, frames pass through: {exc}")
        lines.append(f"display: {config.display or 'the preset matching the runtime view size, else quest2'}")
        # the layer's defaults where the configuration does not say (the pupil from the light, robust on)
        options = config.corrector_options
        pupil, robust = options["pupil"], options["robust"]
        lines.append("pupil: " + ("followed from the light of the frames shown (auto)" if pupil == "auto" else
                                  "the prescription's pupil_diameter_mm (rx)" if pupil == "rx" else f"{pupil} mm")
                     + ("; robust design over the band of pupils and +-0.25 D" if robust is True else
                        "; single-pupil design (robust off)" if robust is False else f"; robust {robust!r}")
                     + ("" if "pupil" in config.options or "robust" in config.options else
                        " (the default; layer install --pupil rx|MM --robust off designs for one pupil)"))
        fovea = config.options.get("fovea_deg")
        gaze = config.options.get("gaze_deg", (0, 0))
        periphery = config.options.get("fovea_periphery", Periphery.QUARTER)
        lines.append("fovea: " + ("off, the whole view corrected (layer install --fovea DEG corrects a window around "
                                  "the gaze)" if fovea is None else
                                  f"a window of radius {fovea:g} deg around the gaze: the eye tracker's where the "
                                  "runtime offers XR_EXT_eye_gaze_interaction, else "
                                  f"({gaze[0]:g}, {gaze[1]:g}) deg from the view's centre; outside it "
                                  + ("the view as the application drew it"
                                     if periphery == Periphery.TARGET else PERIPHERY_DESCRIPTIONS.get(periphery, "?"))))
    log = log_path(env)
    logged = log.read_text(encoding="utf-8", errors="replace").splitlines() if log.exists() else []
    if config is not None and config.options.get("budget_ms") is not None:
        chose = [line for line in logged if "budget: " in line]
        lines.append(f"budget: {config.options['budget_ms']:g} ms of GPU time a frame per eye; "
                     + (f"its latest choice: {chose[-1].split('budget: ', 1)[1]}" if chose else
                        "no choice logged yet (the log reports it every few seconds of corrected frames)"))
    if config is not None and config.corrector_options["pupil"] == "auto":
        seen = [line for line in logged if "pupil: " in line and " pupil " in line]
        lines.append("pupil now: " + (seen[-1].split("pupil: ", 1)[1] if seen else
                                      "none logged yet (the log reports it every few seconds of corrected frames)"))
    if log.exists():
        last = logged[-tail:]
        lines.append(f"log: {log} (last {len(last)} lines)")
        lines.extend(f"  {line}" for line in last)
    else:
        lines.append(f"log: {log} (nothing logged yet)")
    return lines


def cmd_status(args: argparse.Namespace, env: Mapping[str, str] | None = None) -> int:
    print("\n".join(status_lines(env, tail=args.lines)))
    return 0


def cmd_layer(args: argparse.Namespace) -> int:
    return {"install": cmd_install, "uninstall": cmd_uninstall, "status": cmd_status}[args.action](args)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("layer", help="install vrcorrect as an implicit OpenXR API layer (OpenGL and Vulkan applications)",
                       description=__doc__.split("\n\n")[0].replace("``", ""))
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True
    i = actions.add_parser("install", help="write the layer's manifest and configuration (the layer ships built "
                                          "in the package; a source checkout without it compiles it)")
    i.add_argument("--rx", help="prescription JSON the layer corrects for")
    i.add_argument("--display", help="display preset or profile JSON (default: the preset matching the "
                                     "runtime's view size, else quest2)")
    i.add_argument("--iterations-per-frame", dest="iterations", type=int,
                   help="iterations per frame and eye of the real-time method (ADMM by default; 1-64; "
                        "default: the method's own, 2 for ADMM)")
    i.add_argument("--pupil", default=None, metavar="auto|rx|MM",
                   help="the viewing pupil the layer designs for: auto (followed from the light of the frames "
                        "shown; the default), rx (the prescription's pupil_diameter_mm) or a diameter in mm")
    i.add_argument("--robust", choices=("on", "off"), default=None,
                   help="the robust design over the band of pupils and +-0.25 D (default: on)")
    i.add_argument("--band", choices=("auto", "default"), default=None,
                   help="with --robust on: auto (the default): a page of dark text on white paper is designed over "
                        "the page band, chosen every few frames; default: the default band for every picture")
    i.add_argument("--fovea", default=None, metavar="DEG|off",
                   help="correct only a window of this radius in degrees around the gaze (default: off, the whole "
                        "view)")
    i.add_argument("--gaze", default=None, metavar="X,Y",
                   help="with --fovea: where the window stands when the runtime offers no eye tracker "
                        "(XR_EXT_eye_gaze_interaction; with one, the window follows the gaze), degrees from the "
                        "view's centre, x right and y up (default 0,0)")
    i.add_argument("--periphery", choices=names(Periphery), default=None,
                   help="with --fovea: what the view shows outside the window (default quarter: a correction of the "
                        "whole view at a quarter of the resolution; half; target: the application's picture)")
    i.add_argument("--budget-ms", default=None, metavar="MS",
                   help="hold each eye's correction at this much GPU time a frame: the iterations a frame chosen "
                        "to fit, and with --fovea the window's radius shrunk when one iteration overruns (layer "
                        "status and the log say what it chose; default: none, the fixed settings)")
    i.add_argument("--force", action="store_true", help="replace files vrcorrect did not write")
    i.set_defaults(func=cmd_layer)
    u = actions.add_parser("uninstall", help="remove the manifest (and a layer the fallback built)")
    u.add_argument("--force", action="store_true", help="remove a manifest vrcorrect did not write")
    u.set_defaults(func=cmd_layer)
    s = actions.add_parser("status", help="will the loader find it; prescription, display, last log lines")
    s.add_argument("--lines", type=int, default=10, help="log lines to show (default 10)")
    s.set_defaults(func=cmd_layer)
    p.set_defaults(func=cmd_layer)
