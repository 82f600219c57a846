"""``vrcorrect bench kernel``: time to build one eye's kernel per headset preset."""

from __future__ import annotations

from pathlib import Path

from ...physics.kernel import build_kernel
from ...specs.display import get_display, preset_names
from ...specs.prescription import EyeRx
from . import machine_description, markdown_table, median_seconds, write_section

HEADSETS = ("quest2", "quest3", "index", "vivepro")


def run_kernel_bench(repeats: int = 5, out: Path = Path("docs/benchmarks.md"), write: bool = True) -> str:
    """Build the kernel of a -3 D eye with a 4 mm pupil for each headset; returns the Markdown."""
    eye = EyeRx(sphere_D=-3.0, cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=4.0)
    rows = []
    names = [n for n in HEADSETS if n in preset_names()] + ["desktop"]
    for name in names:
        display = get_display(name)
        kernel = build_kernel(eye, display)
        step = kernel.report.wavelength                    # None: the identity path, no FFT
        med, times = median_seconds(lambda: build_kernel(eye, display), repeats)
        rows.append([display.title, f"{display.pixels_per_degree:.1f}", f"{med:.3f}",
                     f"{min(times):.3f}-{max(times):.3f}", f"{kernel.size}x{kernel.size}",
                     f"{kernel.wavelength_step_nm} nm", str(len(kernel.node_wavelengths_nm)),
                     str(step.max_fft_grid) if step else "-", "yes" if med < 1.0 else "no"])
    body = (
        "## Kernel build: one eye, -3.00 D sphere, 4 mm pupil, chromatic aberration on\n\n"
        f"Machine: {machine_description()}.\n"
        f"Median of {repeats} runs after one warm-up (`vrcorrect bench kernel`). Target: under 1 s per eye.\n"
        "Viewing distance is each preset's (virtual-image distance for headsets), accommodation 0.\n\n"
        + markdown_table(["display", "px/deg", "median s", "range s", "kernel", "wavelength step", "PSFs",
                          "largest FFT grid", "< 1 s"], rows))
    if write:
        write_section(out, "kernel", body)
    return body
