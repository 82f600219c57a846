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

Layer 5: numpy; never torch.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle
import threading
from pathlib import Path
from typing import Any, Mapping

from .glcache import cache_dir

__all__ = ["key", "load", "store", "code_fingerprint"]

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


def _path(cache_key: str, env: Mapping[str, str] | None) -> Path:
    return cache_dir(env) / "eyes" / f"{cache_key}.pickle"


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
    path = _path(cache_key, env)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        with open(tmp, "wb") as f:
            pickle.dump({"key": cache_key, "display": display, "why": why, "models": dict(models)}, f,
                        protocol=pickle.HIGHEST_PROTOCOL)
        tmp.replace(path)
    except Exception:  # noqa: BLE001  (a read-only cache: the next launch designs again)
        return None
    return path
