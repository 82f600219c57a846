"""The eye models a correction was built from, kept between runs, so that an application that starts
again (the OpenXR layer's second launch) corrects within seconds instead of designing both eyes again.

Designing an eye (:func:`~vrcorrect.runtime.eye_model.build_eye_model`: PSFs over wavelengths, the
kernel, the filters) takes seconds of CPU, and loading a display profile imports colour-science (one
to three seconds more).  :func:`store` writes the designed models with the display profile they were
designed for to ``<cache>/eyes/<key>.pickle`` (:func:`~vrcorrect.runtime.glcache.cache_dir`:
``$VRCORRECT_CACHE_DIR``, else ``$XDG_CACHE_HOME/vrcorrect``); :func:`load` reads them back.  The key
(:func:`key`) is a SHA-256 of every eye's prescription as designed, the wearer's age (the pupil's
formula takes it), the display as configured (a
preset's name, or the profile file's bytes), the runtime's view size (which picks the preset when
none is configured), the corrector's options, and vrcorrect's own code and data (any change to the
package, a physics fix included, misses the cache).  A file that does not load (damaged, written by
another version) is a miss.  The files are pickles written by the same user; nothing else is read.

The pupil bank's designs (:mod:`~vrcorrect.runtime.pupil_bank`: the same eye at the pupils the light
asks for) are kept the same way, one file a design under ``<cache>/designs/``
(:func:`design_key`, :func:`load_design`, :func:`store_design`), where a caller asks for it (the
OpenXR layer, :meth:`~vrcorrect.runtime.corrector.Corrector.keep_pupil_designs`): a second launch
switches to the light's pupil within frames instead of designing it again beside the application's.
The windowed commands (``vrcorrect xr``, ``mirror``, ``overlay``) keep those too, and each eye's
first design (:func:`start_key`): launched again, they start without designing.

Layer 5: numpy; never torch.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import pickle
import threading
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .glcache import cache_dir

__all__ = ["key", "load", "store", "code_fingerprint", "design_key", "start_key", "load_design", "store_design"]

_PACKAGE = Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """A hash of vrcorrect's own files (its code and its data), read once per process."""
    digest = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts and path.suffix not in (".pyc", ".so"):
            digest.update(str(path.relative_to(_PACKAGE)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def key(eyes: Mapping[str, Any], display: str | None, view_size: tuple[int, int], options: Any,
        age_years: float | None = None) -> str:
    """The cache key of a design: each eye's :class:`~vrcorrect.specs.prescription.EyeRx` (as
    designed), the prescription's ``age_years`` (``pupil="auto"`` designs for the pupil of that age),
    the configured display (a preset name, a profile path whose bytes are hashed, or ``None``: chosen
    from ``view_size``), the options (their ``repr``), and the package."""
    digest = hashlib.sha256(code_fingerprint().encode())
    for eye in sorted(eyes):
        digest.update(f"\n{eye}={eyes[eye]!r}".encode())
    digest.update(f"\nage={age_years!r}".encode())
    digest.update(f"\ndisplay={display!r}; view={tuple(view_size)!r}".encode())
    if display:
        path = Path(display).expanduser()
        if path.is_file():
            digest.update(path.read_bytes())
    digest.update(f"\noptions={options!r}".encode())
    return digest.hexdigest()


def source_key(source: Any, display: str | None, view_size: tuple[int, int]) -> str:
    """:func:`key` of an :class:`~vrcorrect.runtime.eye_source.EyeSource`'s current design (its eyes
    as designed, its prescription's age, its options): the same key at a start and after a reload."""
    eyes = {eye: source.eye_rx(eye) for eye in source.eyes}
    return key(eyes, display, view_size, source.options, source.prescription.age_years)


def _path(cache_key: str, env: Mapping[str, str] | None, folder: str = "eyes") -> Path:
    return cache_dir(env) / folder / f"{cache_key}.pickle"


def design_key(eye: Any, display: Any, options: Any, age_years: float | None, pupil_mm: float,
               grid_kernel_size: int | None, reach_mm: float | None, band: str = "default") -> str:
    """The cache key of one pupil bank design: the eye as designed, the display profile by its content
    (:func:`_digest_value`), the options, the age, the pupil, the grids' kernel size and reach, the band
    (``"default"`` or ``"page"``) and the package."""
    return _eye_digest(f"pupil={float(pupil_mm)!r}; grid kernel={grid_kernel_size!r}; reach={reach_mm!r}; "
                       f"band={band}", eye, display, options, age_years)


def start_key(eye: Any, display: Any, options: Any, age_years: float | None, pupil_mm: float,
              band: str = "default") -> str:
    """The cache key of an eye's first design in a window (``vrcorrect xr``, ``mirror``, ``overlay``):
    the eye, the display profile by its content, the options, the age, the pupil it is designed for
    (:func:`~vrcorrect.runtime.eye_model.initial_pupil_mm`: with ``pupil="auto"`` the first frame's
    light's), its band (``band="auto"``: the first frame's) and the package.  Kept beside the bank's
    designs (:func:`store_design`)."""
    return _eye_digest(f"first design at pupil={pupil_mm!r}; band={band}", eye, display, options, age_years)


def _eye_digest(what: str, eye: Any, display: Any, options: Any, age_years: float | None) -> str:
    """The key :func:`design_key` and :func:`start_key` share: ``what`` (which design of the eye), the
    eye, the age, the options, the display profile by its content, and the package."""
    digest = hashlib.sha256(code_fingerprint().encode())
    digest.update(f"\n{what}\neye={eye!r}\nage={age_years!r}\noptions={options!r}\n".encode())
    _digest_value(digest, display)
    return digest.hexdigest()


def _digest_value(digest: Any, value: Any) -> None:
    """Add ``value`` to ``digest`` by its content: dataclasses field by field, arrays by their dtype,
    shape and bytes, the rest by ``repr`` (a pickle's bytes differ between a profile loaded and the
    same profile read back from a cache)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        digest.update(f"<{type(value).__name__}".encode())
        for f in dataclasses.fields(value):
            digest.update(f"|{f.name}=".encode())
            _digest_value(digest, getattr(value, f.name))
        digest.update(b">")
    elif isinstance(value, np.ndarray):
        digest.update(f"{value.dtype.str}{value.shape}".encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, (tuple, list)):
        digest.update(b"(")
        for v in value:
            _digest_value(digest, v)
            digest.update(b",")
        digest.update(b")")
    elif isinstance(value, dict):
        _digest_value(digest, sorted(value.items(), key=lambda kv: repr(kv[0])))
    else:
        digest.update(repr(value).encode())


def load_design(cache_key: str, env: Mapping[str, str] | None = None) -> Any | None:
    """The design :func:`store_design` kept under ``cache_key``, or ``None``."""
    try:
        with open(_path(cache_key, env, "designs"), "rb") as f:
            doc = pickle.load(f)
    except Exception:  # noqa: BLE001  (missing, damaged, another version's: a miss)
        return None
    return doc.get("model") if isinstance(doc, dict) and doc.get("key") == cache_key else None


def store_design(cache_key: str, model: Any, env: Mapping[str, str] | None = None) -> Path | None:
    """Keep one design under ``cache_key``; returns the file, or ``None`` when it could not be written."""
    return _write(_path(cache_key, env, "designs"), {"key": cache_key, "model": model})


def _write(path: Path, doc: dict) -> Path | None:
    """Write ``doc`` to ``path`` through a temporary file beside it (never a partial file)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        with open(tmp, "wb") as f:
            pickle.dump(doc, f, protocol=pickle.HIGHEST_PROTOCOL)
        tmp.replace(path)
    except Exception:  # noqa: BLE001  (a read-only cache: the next launch designs again)
        return None
    return path


def load(cache_key: str, env: Mapping[str, str] | None = None) -> dict[str, Any] | None:
    """What :func:`store` kept under ``cache_key`` (``display``, ``why``, ``models``: eye -> model), or
    ``None``."""
    path = _path(cache_key, env)
    try:
        with open(path, "rb") as f:
            doc = pickle.load(f)
    except Exception:  # noqa: BLE001  (missing, damaged, another version's: a miss)
        return None
    if not isinstance(doc, dict) or doc.get("key") != cache_key:
        return None
    return doc


def store(cache_key: str, display: Any, why: str, models: Mapping[str, Any],
          env: Mapping[str, str] | None = None) -> Path | None:
    """Keep the designed ``models`` (eye -> model) and the ``display`` profile (with ``why`` it was
    chosen) under ``cache_key``; returns the file, or ``None`` when it could not be written."""
    return _write(_path(cache_key, env), {"key": cache_key, "display": display, "why": why, "models": dict(models)})
