"""A prescription as the real-time path takes it: :class:`RxSnapshot` (a file read once, with the
stamp that tells a later edit), what a :class:`~vrcorrect.runtime.corrector.Corrector` accepts as
``rx`` (:data:`RxSource`), and the live offsets' arithmetic (:func:`with_offset`).

Layer 5: plain Python; never torch.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Union

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import file_stamp
from ..specs.prescription import EyeRx, Prescription, load_prescription

__all__ = ["RxSnapshot", "RxSource", "load_rx", "eye_text", "with_offset", "file_stamp"]


@dataclass(frozen=True, eq=False)
class RxSnapshot:
    """A prescription file read once: what it held, and the file's stamp (modification time and
    size) taken just before the read.  An application that corrects several eyes reads the file
    once and gives this to every eye's :class:`Corrector`, so all are built from one parse however
    long the builds take; each corrector's :meth:`Corrector.poll` then sees any later change
    (an edit made during the builds included) and handles it as hot reload does, keeping the
    last good prescription when the new file is invalid."""

    prescription: Prescription
    path: Path | None          # None: not from a file (nothing to watch)
    stamp: tuple[int, int] | None

    @classmethod
    def read(cls, path: str | os.PathLike[str]) -> "RxSnapshot":
        path = Path(path)
        stamp = file_stamp(path)
        return cls(load_prescription(path), path, stamp)


RxSource = Union[str, "os.PathLike[str]", Prescription, RxSnapshot]
"""What :class:`Corrector` takes as ``rx``: a prescription JSON path, a prescription, or a snapshot."""


def load_rx(rx: RxSource) -> RxSnapshot:
    """``rx`` as a snapshot (a path is read now)."""
    if isinstance(rx, RxSnapshot):
        return rx
    if isinstance(rx, Prescription):
        return RxSnapshot(rx, None, None)
    if isinstance(rx, (str, os.PathLike)):
        return RxSnapshot.read(rx)
    raise ValidationError("rx", type(rx).__name__, "a prescription JSON path, a Prescription or an RxSnapshot")


def eye_text(e: EyeRx) -> str:
    return (f"sphere {e.sphere_D:+g} D, cylinder {e.cylinder_D:+g} D, axis {e.axis_deg:g} deg, "
            f"pupil {e.pupil_diameter_mm:g} mm" + (", higher order" if e.higher_order is not None else ""))


def with_offset(base: EyeRx, offset: tuple[float, float, float]) -> EyeRx:
    """``base`` changed by live ``(sphere_D, cylinder_D, axis_deg)`` amounts (axis wrapped into [0, 180))."""
    ds, dc, da = offset
    return base.with_changes(sphere_D=base.sphere_D + ds, cylinder_D=base.cylinder_D + dc,
                             axis_deg=(base.axis_deg + da) % 180.0)
