"""The GPU's line transform (``shaders/fft_line.glsl``: a mixed-radix Stockham FFT) on a real headless
GL context (llvmpipe in CI) against numpy's FFT, its plans within OpenGL 4.3's least limits at every
5-smooth length up to 4096, and the real-time passes linked at grids of every class up to 4096."""

from __future__ import annotations

import numpy as np
import pytest

from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.runtime.fft import (MAX_INVOCATIONS, MIN_SHARED_BYTES, LinePlan, line_plan, line_radices,
                                   transform_lines, values_per_thread)
from vrcorrect.runtime.strategies.admm import column_lines
from vrcorrect.solvers.spectral import smooth_length


def _smooth(n: int) -> bool:
    for p in (2, 3, 5):
        while n % p == 0:
            n //= p
    return n == 1


SMOOTH = [n for n in range(2, 4097) if _smooth(n)]


def test_smooth_length_is_the_next_5_smooth_number():
    for n in range(1, 5000, 7):
        m = smooth_length(n)
        assert _smooth(m) and m >= n and not any(_smooth(k) for k in range(max(n, 1), m))
    assert smooth_length(2049) == 2160 and smooth_length(4097) == 4320
    assert smooth_length(10, (2,)) == 16
    with pytest.raises(ValidationError, match="primes"):
        smooth_length(10, (1,))


@pytest.mark.parametrize("per", [1, 2, 4, 8, 16, 64])
def test_every_plan_fits_opengl_43s_least_limits(per):
    """At every 5-smooth length up to 4096 and every values-a-thread asked: the radices multiply to
    the length, the threads times the points a thread are the line, at most 1,024 threads, the line
    (and the column passes' lines a work group) within 32 KiB of shared memory, and the radix order
    the same whatever is asked (so every work-group shape computes the same values)."""
    for n in SMOOTH:
        plan = line_plan(n, per)
        assert int(np.prod(plan.radices)) == n and set(plan.radices) <= {2, 3, 4, 5, 8}, plan
        assert plan.threads * plan.per == n and plan.threads <= MAX_INVOCATIONS, plan
        assert plan.radices == line_radices(n)
        assert n * 8 <= MIN_SHARED_BYTES
        lines = column_lines(n, plan.per, 8)
        assert lines * n * 8 <= MIN_SHARED_BYTES and lines * plan.threads <= MAX_INVOCATIONS, (n, per, lines)
        assert plan.exchanges <= len(plan.radices) + 1


def test_a_plan_crosses_shared_memory_once_between_stages_and_not_at_its_ends():
    """A 2048-point column at 4 points a thread: radix 4 then three radix-8 stages; the first reads the
    thread's registers, the last (8 does not divide 4) crosses once more: 4 exchanges, where the radix-2
    transform before it made 11 stages, each through shared memory.  At 8 points a thread both ends
    stay in registers.  A length with a prime factor above 5 is refused, naming it."""
    assert line_plan(2048, 4) == LinePlan(2048, 4, (4, 8, 8, 8)) and line_plan(2048, 4).exchanges == 4
    assert line_plan(2048, 8).exchanges == 3
    assert line_plan(1875, 4).per == 5 and line_plan(1875, 4).exchanges == len(line_radices(1875)) - 1
    assert "fft_stage4(1, sign, !in_line, false, own)" in line_plan(2048, 4).sequence()
    assert line_plan(2048, 4).sequence().endswith("fft_from_line(own, out_line);")
    with pytest.raises(ValidationError, match="5-smooth"):
        line_plan(2 * 7 * 16, 4)
    assert values_per_thread(4096, 1) == 4                 # 1,024 threads at most


CASES = [(16, 4), (16, 8), (45, 8), (75, 4), (80, 8), (81, 4), (135, 8), (2048, 4), (2048, 8), (1875, 4),
         (1944, 8), (2187, 4), (2250, 4), (3750, 8), (4096, 4)]


@pytest.mark.parametrize("length, per", CASES)
def test_the_line_transform_equals_numpys_fft(gl, length, per):
    """Forward and inverse (unscaled), from and to registers, from shared memory (a row pass's inverse)
    and into it (its forward): numpy's FFT in float64 to 1e-6 of the largest value, at powers of two,
    odd lengths and lengths past 2048."""
    rng = np.random.default_rng(length)
    x = (rng.standard_normal((2, length)) + 1j * rng.standard_normal((2, length))).astype(np.complex64)
    for inverse in (False, True):
        want = np.fft.ifft(x.astype(complex)) * length if inverse else np.fft.fft(x.astype(complex))
        for through in ("", "in", "out"):
            got = transform_lines(gl, x, per, inverse, through=through)
            err = np.abs(got - want).max() / np.abs(want).max()
            assert err < 1e-6, (length, per, inverse, through, err)


def test_lines_side_by_side_in_a_work_group_give_each_lines_transform(gl):
    """Two and four lines a work group (a column pass's several columns, interleaved in shared memory):
    each line's transform, to the last bit the same as one line a work group."""
    rng = np.random.default_rng(3)
    x = (rng.standard_normal((8, 360)) + 1j * rng.standard_normal((8, 360))).astype(np.complex64)
    one = transform_lines(gl, x, 4)
    assert np.abs(one - np.fft.fft(x.astype(complex))).max() / np.abs(one).max() < 1e-6
    for lines in (2, 4):
        assert np.array_equal(transform_lines(gl, x, 4, lines_per_group=lines), one), lines


@pytest.mark.parametrize("size", [(4080, 4080), (3660, 3200), (2064, 2208), (2560, 1440)])
def test_every_real_time_pass_links_up_to_a_4096_grid(gl, size):
    """The ADMM strategy's compute passes (half and single precision, the glasses and the ideal
    target, two columns a column work group asked) compile and link for a 4096 x 4096 grid (the
    largest), a 3660 x 3200 eye, a Quest 3 eye and the desktop preset's full screen: within GL 4.3's
    32 KiB of shared memory and 1,024 threads (before mixed-radix grids anything past 2048 failed to
    link: "Too much shared memory used (40960/32768)")."""
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.runtime.eye_model import WorkGroups
    from vrcorrect.runtime.gl import release
    from vrcorrect.specs.prescription import EyeRx, Prescription

    eye = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
    rx = Prescription(right=eye, left=eye)
    for precision, reference in (("half", "glasses"), ("single", "ideal")):
        c = Corrector(gl, rx, "quest2", "right", filter="admm", precision=precision, reference=reference,
                      work_groups=WorkGroups(column_lines={"full": 2}))
        try:
            grid = c.strategy.grid(size)
            if size == (4080, 4080):
                assert grid == (4096, 4096)
            assert all(_smooth(n) for n in grid) and max(grid) <= 4096
            programs, compiled, lines = c.strategy.compile_passes(size)
            try:
                assert len(programs) == (13 if reference == "glasses" else 11)
                assert lines * grid[0] * 8 <= MIN_SHARED_BYTES
            finally:
                release(*programs.values())
        finally:
            c.release()


def test_a_grid_past_4096_is_refused_naming_the_size_the_grid_and_what_is_allowed(gl):
    """The one-pass bank's grid and the ADMM strategy's: an image whose grid would pass 4096 per side
    (one line of complex float32 in 32 KiB of shared memory) is refused with the field, the size, the
    grid it would need and the largest image allowed."""
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.runtime.fft import fft_grid
    from vrcorrect.specs.prescription import EyeRx, Prescription

    assert fft_grid(4076, 16, 10) == (36, 4096)                 # 16 + 20 = 36 = 2^2 3^2
    with pytest.raises(ValidationError) as e:
        fft_grid(4090, 16, 10)
    assert e.value.field == "image size" and "4090x16" in str(e.value) and "4320x36 grid" in str(e.value)
    assert "at most 4076 px" in str(e.value)
    eye = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
    c = Corrector(gl, Prescription(right=eye, left=eye), "quest2", "right", filter="admm")
    try:
        k = max(c.model.kernel.size, c.model.reference.size)
        assert max(c.strategy.grid((4096 - k + 1, 16))) == 4096
        with pytest.raises(ValidationError) as e:
            c.strategy.grid((4096 - k + 2, 16))
        assert e.value.field == "image size" and f"at most {4096 - k + 1} px per side" in str(e.value)
    finally:
        c.release()
