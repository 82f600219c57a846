"""Tests of vrcorrect.specs.display: profiles, spectra, CSV/JSON readers, proxy fit,
transfer functions. Expected values are computed by hand or from the
definitions (IEC 61966-2-1, colour-science's tables), never from the code
under test."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrcorrect.specs import display as D
from vrcorrect.plumbing.errors import InputError, ValidationError, ValidationErrors

RGB = ("red", "green", "blue")


def gauss(wl: np.ndarray, centre: float, fwhm: float) -> np.ndarray:
    sigma = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    return np.exp(-0.5 * ((wl - centre) / sigma) ** 2)


def truth_rgb(wl: np.ndarray) -> np.ndarray:
    """Smooth known spectra: LED-like bands with shoulders."""
    return np.stack(
        [
            gauss(wl, 615, 30) + 0.3 * gauss(wl, 580, 60),
            gauss(wl, 535, 40),
            gauss(wl, 455, 22) + 0.2 * gauss(wl, 500, 50),
        ],
        axis=1,
    )


def write_csv(path: Path, wl: np.ndarray, values: np.ndarray, header: str = "wavelength_nm,r,g,b") -> Path:
    lines = [header] + [f"{w:.6g},{r:.9g},{g:.9g},{b:.9g}" for w, (r, g, b) in zip(wl, values)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


GOOD_ROWS = ["400,0.1,0.2,0.3", "450,0.2,0.3,0.4", "500,0.3,0.4,0.5", "550,0.4,0.5,0.6", "600,0.5,0.6,0.7"]


# --------------------------------------------------------------------------- geometry


def test_ppd_from_pitch_hand_computation():
    # 0.25 mm at 0.5 m: one pixel subtends 2*atan(0.125e-3 / 0.5) = 5.0e-4 rad
    # = 0.0286479 deg  ->  34.9066 pixels per degree.
    assert D.ppd_from_pitch(0.25, 0.5) == pytest.approx(34.9066, abs=1e-3)
    # Doubling the distance doubles the density (small angles).
    assert D.ppd_from_pitch(0.25, 1.0) == pytest.approx(2 * 34.9066, rel=1e-6)


def test_ppd_from_pitch_small_angle_limit():
    for pitch_mm, d in [(0.001, 10.0), (0.01, 3.0), (0.2331, 0.6)]:
        small_angle = math.pi * d / (180.0 * pitch_mm / 1000.0)
        assert D.ppd_from_pitch(pitch_mm, d) == pytest.approx(small_angle, rel=1e-6)


def test_ppd_from_pitch_large_angle_is_exact():
    # pitch equal to twice the distance subtends 2*atan(1) = 90 degrees.
    assert D.ppd_from_pitch(2000.0, 1.0) == pytest.approx(1.0 / 90.0, rel=1e-12)


@pytest.mark.parametrize("pitch, d, field", [(0, 0.5, "pixel_pitch_mm"), (-1, 0.5, "pixel_pitch_mm"),
                                             (0.25, 0, "distance_m"), (0.25, math.inf, "distance_m"),
                                             (math.nan, 0.5, "pixel_pitch_mm"), (True, 0.5, "pixel_pitch_mm")])
def test_ppd_from_pitch_rejects(pitch, d, field):
    with pytest.raises(ValidationError) as info:
        D.ppd_from_pitch(pitch, d)
    assert info.value.field == field


def test_ppd_from_fov():
    assert D.ppd_from_fov(1832, 97.0) == pytest.approx(18.8866, abs=1e-4)
    assert D.ppd_from_fov(2000, 100) == 20.0
    for pixels, fov in [(0, 90), (1.5, 90), (100, 0), (100, 180), (100, -5), (100, math.nan)]:
        with pytest.raises(ValidationError):
            D.ppd_from_fov(pixels, fov)


# --------------------------------------------------------------------------- presets


def test_preset_names_order():
    names = D.preset_names()
    assert names[:5] == ("desktop", "crt", "quest2", "quest3", "index")
    assert len(set(names)) == len(names)


@pytest.mark.parametrize("name", D.preset_names())
def test_preset_is_valid_and_plausible(name):
    p = D.get_display(name)
    assert isinstance(p, D.DisplayProfile)
    assert p.name == name and p.title
    # Re-validate by constructing a copy from its fields.
    D.DisplayProfile(p.name, p.title, p.kind, p.primaries, p.pixels_per_degree, p.distance_m,
                     p.transfer, p.resolution_px, p.sources)
    assert p.kind in ("monitor", "headset")
    if p.kind == "headset":
        assert 10 <= p.pixels_per_degree <= 40
        assert p.resolution_px is not None
    else:
        assert 20 <= p.pixels_per_degree <= 100
        assert math.isfinite(p.distance_m)
    assert p.distance_m > 0
    assert p.transfer in ("srgb", "gamma2.2", "linear")
    spd = p.primaries
    assert spd.labels == RGB
    assert spd.values.shape == (spd.wavelength_nm.size, 3)
    assert np.all(spd.values >= 0) and np.all(np.isfinite(spd.values))
    assert np.all(np.diff(spd.wavelength_nm) > 0)
    peaks = spd.wavelength_nm[np.argmax(spd.values, axis=0)]
    assert peaks[0] > peaks[1] > peaks[2]
    assert 590 <= peaks[0] <= 650 and 500 <= peaks[1] <= 570 and 420 <= peaks[2] <= 480
    # Every preset states where its numbers come from.
    assert len(p.sources) > 40
    assert "ppd" in p.sources or "pixels per degree" in p.sources.lower()


def test_preset_lookup_is_case_insensitive_and_cached():
    assert D.get_display("Quest2") is D.get_display("quest2")
    assert D.get_display("  DESKTOP ") is D.get_display("desktop")


def test_desktop_geometry_from_pitch():
    p = D.get_display("desktop")
    # 0.2331 mm at 0.60 m: 2*atan(0.11655e-3/0.6) = 3.8850e-4 rad = 0.022259 deg -> 44.92 ppd
    assert p.pixels_per_degree == pytest.approx(44.925, abs=0.01)
    assert p.distance_m == 0.60
    assert p.resolution_px == (2560, 1440)
    assert "0.2331" in p.sources and "0.60 m" in p.sources


def test_crt_geometry():
    p = D.get_display("crt")
    # 0.28 mm at 0.6 m: 4.6667e-4 rad = 0.026738 deg -> 37.40 ppd
    assert p.pixels_per_degree == pytest.approx(37.40, abs=0.01)
    assert "estimate" in p.sources


def test_headset_sources_mark_estimates_and_proxies():
    for name in ("quest2", "quest3", "index"):
        p = D.get_display(name)
        assert "proxy" in p.sources and "Apple Studio Display" in p.sources
        assert "estimate" in p.sources
    assert D.get_display("quest3").pixels_per_degree == 25.0
    assert D.get_display("quest2").resolution_px == (1832, 1920)
    assert D.get_display("quest3").resolution_px == (2064, 2208)
    assert D.get_display("index").resolution_px == (1440, 1600)


@pytest.mark.parametrize("preset, table", [("desktop", "Apple Studio Display"),
                                           ("quest2", "Apple Studio Display"),
                                           ("crt", "Typical CRT Brainard 1997")])
def test_primaries_equal_colour_science_table(preset, table):
    import colour

    msds = colour.MSDS_DISPLAY_PRIMARIES[table]
    spd = D.get_display(preset).primaries
    np.testing.assert_array_equal(spd.wavelength_nm, msds.wavelengths)
    np.testing.assert_array_equal(spd.values, msds.values)
    assert table in spd.source


def test_oled_proxy_is_parametric_gaussians():
    spd = D.get_display("vivepro").primaries
    assert "estimate" in spd.source
    wl = spd.wavelength_nm
    for label, centre, fwhm in [("red", 620, 35), ("green", 530, 35), ("blue", 460, 25)]:
        s = spd.channel(label)
        assert wl[np.argmax(s)] == centre
        above = wl[s >= 0.5 * s.max()]
        assert above[-1] - above[0] == pytest.approx(fwhm, abs=1.0)


def test_preset_arrays_are_read_only():
    spd = D.get_display("desktop").primaries
    with pytest.raises(ValueError):
        spd.values[0, 0] = 1.0
    with pytest.raises(ValueError):
        spd.wavelength_nm[0] = 1.0


def _preset_file(name: str) -> Path:
    return Path(D.__file__).resolve().parents[2] / "data" / "displays" / f"{name}.json"


def test_preset_files_are_the_presets():
    """One profile file per preset under vrcorrect/data/displays/, and no other file there."""
    folder = _preset_file("desktop").parent
    assert sorted(p.name for p in folder.iterdir()) == sorted(f"{n}.json" for n in D.preset_names())


@pytest.mark.parametrize("name", D.preset_names())
def test_a_copy_of_a_preset_file_loads_as_a_user_profile_equal_to_the_preset(name, tmp_path):
    """A preset file is a user's profile file: copied elsewhere and loaded by path, it gives the
    same profile, number for number, and its file states where its numbers come from."""
    text = _preset_file(name).read_text(encoding="utf-8")
    doc = json.loads(text)
    assert doc["schema"] == D.PROFILE_SCHEMA and doc["name"] == name
    assert doc["sources"] and doc["photometry_sources"]
    copy = tmp_path / f"my_{name}.json"
    copy.write_text(text, encoding="utf-8")
    mine, preset = D.get_display(str(copy)), D.get_display(name)
    assert mine is not preset
    for field in ("name", "title", "kind", "pixels_per_degree", "distance_m", "transfer", "resolution_px",
                  "sources", "photometry"):
        assert getattr(mine, field) == getattr(preset, field), field
    np.testing.assert_array_equal(mine.primaries.wavelength_nm, preset.primaries.wavelength_nm)
    np.testing.assert_array_equal(mine.primaries.values, preset.primaries.values)
    assert (mine.primaries.labels, mine.primaries.source) == (preset.primaries.labels, preset.primaries.source)


@pytest.mark.parametrize("name", D.preset_names())
def test_the_ppd_a_preset_file_states_is_the_one_its_geometry_gives(name):
    """The sources' "-> N ppd" is written text: it must agree with the pitch or field of view."""
    p = D.get_display(name)
    stated = re.findall(r"-> ([0-9.]+) ppd", p.sources)
    assert len(stated) <= 1
    for value in stated:
        assert value == f"{p.pixels_per_degree:.2f}"


def test_oled_proxy_bands():
    assert D.OLED_PROXY_BANDS == {"red": ((620.0, 35.0, 1.0),), "green": ((530.0, 35.0, 1.0),),
                                  "blue": ((460.0, 25.0, 1.0),)}


def test_get_display_unknown_lists_presets():
    with pytest.raises(ValidationError) as info:
        D.get_display("oculus-rift-dk1")
    err = info.value
    assert err.field == "display" and err.value == "oculus-rift-dk1"
    for name in D.preset_names():
        assert name in str(err)
    assert ".json" in str(err)


def test_get_display_missing_json_is_input_error(tmp_path):
    with pytest.raises(InputError):
        D.get_display(str(tmp_path / "nope.json"))


# --------------------------------------------------------------------------- Spectra


def make_spectra(wl=(400.0, 500.0, 600.0), values=((0, 1, 2), (1, 2, 3), (2, 3, 4))) -> D.Spectra:
    return D.Spectra(np.array(wl, float), np.array(values, float), RGB, "test")


@pytest.mark.parametrize("wl, values, labels, field", [
    ([400, 400, 600], np.ones((3, 3)), RGB, "wavelength_nm"),
    ([400, 500, 450], np.ones((3, 3)), RGB, "wavelength_nm"),
    ([400, np.nan, 600], np.ones((3, 3)), RGB, "wavelength_nm"),
    ([[400, 500, 600]], np.ones((3, 3)), RGB, "wavelength_nm"),
    ([400, 500, 600], -np.ones((3, 3)), RGB, "values"),
    ([400, 500, 600], np.full((3, 3), np.inf), RGB, "values"),
    ([400, 500, 600], np.ones((4, 3)), RGB, "values"),
    ([400, 500, 600], np.ones(3), ("red",), "values"),
    ([400, 500, 600], np.ones((3, 3)), ("red", "green"), "labels"),
    ([400, 500, 600], np.ones((3, 3)), ("red", "red", "blue"), "labels"),
])
def test_spectra_validation(wl, values, labels, field):
    with pytest.raises(ValidationError) as info:
        D.Spectra(np.asarray(wl, float), np.asarray(values, float), labels, "x")
    assert info.value.field == field


def test_spectra_copies_inputs():
    wl = np.array([400.0, 500.0, 600.0])
    v = np.ones((3, 3))
    s = D.Spectra(wl, v, RGB, "x")
    wl[0] = 1.0
    v[0, 0] = 99.0
    assert s.wavelength_nm[0] == 400.0 and s.values[0, 0] == 1.0
    assert not s.values.flags.writeable


def test_spectra_channel():
    s = make_spectra()
    np.testing.assert_array_equal(s.channel("green"), [1, 2, 3])
    with pytest.raises(ValidationError) as info:
        s.channel("yellow")
    assert "red" in str(info.value)


def test_resample_exact_at_nodes_linear_between_zero_outside():
    s = make_spectra()
    same = s.resample(s.wavelength_nm)
    np.testing.assert_array_equal(same.values, s.values)
    r = s.resample(np.array([300.0, 399.9, 400.0, 450.0, 575.0, 600.0, 600.1, 700.0]))
    np.testing.assert_allclose(r.values[:, 2], [0, 0, 2, 2.5, 3.75, 4, 0, 0])
    np.testing.assert_allclose(r.values[:, 0], [0, 0, 0, 0.5, 1.75, 2, 0, 0])
    assert r.labels == s.labels
    with pytest.raises(ValidationError):
        s.resample(np.array([500.0, 400.0]))


# --------------------------------------------------------------------------- CSV reader


def test_read_spectra_csv_good(tmp_path):
    text = "# measured with a spectroradiometer\n\n WaveLength_NM , R ,G, b \n" + "\n".join(
        " " + row.replace(",", " , ") for row in GOOD_ROWS) + "\n\n"
    path = tmp_path / "ok.csv"
    path.write_text(text, encoding="utf-8")
    s = D.read_spectra_csv(path)
    assert s.labels == RGB
    np.testing.assert_array_equal(s.wavelength_nm, [400, 450, 500, 550, 600])
    np.testing.assert_allclose(s.channel("blue"), [0.3, 0.4, 0.5, 0.6, 0.7])
    assert str(path) in s.source


@pytest.mark.parametrize("lines, bad_line, words", [
    (["wavelength,r,g,b"] + GOOD_ROWS, 1, "header"),
    (["wavelength_nm,r,g"] + GOOD_ROWS, 1, "header"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:2] + ["500,0.1,0.2"] + GOOD_ROWS[3:], 4, "columns"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:3] + ["550,0.1,0.2,0.3,0.4"] + GOOD_ROWS[4:], 5, "columns"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:1] + ["450,abc,0.2,0.3"] + GOOD_ROWS[2:], 3, "not a number"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:4] + ["600,0.1,nan,0.3"], 6, "not finite"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:2] + ["500,0.1,0.2,inf"] + GOOD_ROWS[3:], 4, "not finite"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:3] + ["550,0.1,-0.2,0.3"] + GOOD_ROWS[4:], 5, "negative"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:2] + ["440,0.1,0.2,0.3"] + GOOD_ROWS[3:], 4, "increase"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:2] + ["450,0.1,0.2,0.3"] + GOOD_ROWS[3:], 4, "repeats"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS[:4], 5, "at least 5"),
    (["# comment", "wavelength_nm,r,g,b", "250,0,0,0"] + GOOD_ROWS, 3, "outside"),
    (["wavelength_nm,r,g,b"] + GOOD_ROWS + ["1200,0,0,0"], 7, "outside"),
    ([], 1, "header"),
])
def test_read_spectra_csv_rejects_with_line_number(tmp_path, lines, bad_line, words):
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines) + ("\n" if lines else ""), encoding="utf-8")
    with pytest.raises(InputError) as info:
        D.read_spectra_csv(path)
    msg = str(info.value)
    assert str(path) in msg
    assert f"line {bad_line}:" in msg
    assert words in msg


def test_read_spectra_csv_missing_and_binary(tmp_path):
    with pytest.raises(InputError, match="not found"):
        D.read_spectra_csv(tmp_path / "missing.csv")
    with pytest.raises(InputError):
        D.read_spectra_csv(tmp_path)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"\xff\xfe\x00\x80garbage")
    with pytest.raises(InputError):
        D.read_spectra_csv(binary)


# --------------------------------------------------------------------------- proxy fit


def test_fit_recovers_known_gaussians_from_csv(tmp_path):
    wl = np.arange(380.0, 781.0, 2.0)
    path = write_csv(tmp_path / "smooth.csv", wl, truth_rgb(wl))
    fit = D.fit_spectra(D.read_spectra_csv(path))
    grid = fit.spectra.wavelength_nm
    np.testing.assert_array_equal(grid, np.arange(380.0, 781.0, 1.0))
    truth = truth_rgb(grid)
    for c in range(3):
        peak = truth[:, c].max()
        rms = math.sqrt(np.mean((fit.spectra.values[:, c] - truth[:, c]) ** 2)) / peak
        assert rms < 0.02
        assert fit.rms_error[c] < 0.02 and fit.max_error[c] < 0.05
        assert fit.max_error[c] >= fit.rms_error[c]
    assert fit.spectra.labels == RGB
    assert np.all(fit.spectra.values >= 0)


def test_fit_is_non_negative_and_deterministic_on_hard_data():
    # A box spectrum with sharp edges and zeros: least squares without the
    # constraint would ring below zero.
    wl = np.arange(400.0, 701.0, 5.0)
    box = ((wl >= 500) & (wl <= 560)).astype(float)
    spike = np.zeros_like(wl)
    spike[wl == 610] = 1.0
    s = D.Spectra(wl, np.stack([spike, box, 0.5 * box], 1), RGB, "hard")
    a, b = D.fit_spectra(s), D.fit_spectra(s)
    assert np.all(a.spectra.values >= 0)
    np.testing.assert_array_equal(a.spectra.values, b.spectra.values)
    assert a.rms_error == b.rms_error


def test_fit_of_noisy_data_is_smooth():
    wl = np.arange(380.0, 781.0, 1.0)
    truth = truth_rgb(wl)
    rng = np.random.default_rng(1234)
    noisy = np.clip(truth + rng.normal(0.0, 0.03, truth.shape), 0.0, None)
    fit = D.fit_spectra(D.Spectra(wl, noisy, RGB, "noisy"))
    v = fit.spectra.values
    d2_fit = np.sqrt(np.mean(np.diff(v, 2, axis=0) ** 2, axis=0))
    d2_noise = np.sqrt(np.mean(np.diff(noisy, 2, axis=0) ** 2, axis=0))
    # The truth's own second difference is ~1e-3; white noise of 0.03 gives ~0.07.
    assert np.all(d2_fit < 0.15 * d2_noise)
    assert np.all(np.abs(np.diff(v, 2, axis=0)).max(axis=0) < 0.02)
    # ... and it still follows the signal, better than the raw noise does.
    rms_fit = np.sqrt(np.mean((v - truth) ** 2, axis=0))
    rms_raw = np.sqrt(np.mean((noisy - truth) ** 2, axis=0))
    assert np.all(rms_fit < 0.7 * rms_raw)
    assert np.all(v >= 0)


def test_fit_of_colour_science_table_reports_its_errors():
    spd = D.get_display("desktop").primaries
    fit = D.fit_spectra(spd)
    # Errors reported are consistent with a direct comparison at the data's wavelengths.
    back = fit.spectra.resample(spd.wavelength_nm).values
    for c in range(3):
        peak = spd.values[:, c].max()
        assert np.max(np.abs(back[:, c] - spd.values[:, c])) / peak == pytest.approx(fit.max_error[c], abs=1e-9)
    assert np.all(fit.spectra.values >= 0)


# --------------------------------------------------------------------------- transfer functions

TOL = {np.float32: 2e-6, np.float64: 1e-12}


def srgb_reference(v: float) -> float:
    """IEC 61966-2-1 decoding, scalar, written from the standard."""
    return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_srgb_round_trip_and_dtype(dtype):
    v = np.linspace(0.0, 1.0, 1001, dtype=dtype)
    lin = D.srgb_to_linear(v)
    back = D.linear_to_srgb(lin)
    assert lin.dtype == dtype and back.dtype == dtype
    np.testing.assert_allclose(back, v, atol=TOL[dtype] * 10)
    lin2 = np.linspace(0.0, 1.0, 1001, dtype=dtype)
    np.testing.assert_allclose(D.srgb_to_linear(D.linear_to_srgb(lin2)), lin2, atol=TOL[dtype] * 10)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_srgb_known_points(dtype):
    v = np.array([0.0, 1.0, 0.5, 0.04045, 0.2], dtype=dtype)
    lin = D.srgb_to_linear(v)
    expected = [0.0, 1.0, 0.2140411, 0.04045 / 12.92, srgb_reference(0.2)]
    np.testing.assert_allclose(lin, expected, rtol=1e-5 if dtype == np.float32 else 1e-7, atol=1e-7)
    assert lin[0] == 0.0 and lin[1] == pytest.approx(1.0, abs=TOL[dtype])
    # Encoding side: the linear-segment threshold 0.0031308 maps to 0.04045.
    assert float(D.linear_to_srgb(np.array(0.0031308))) == pytest.approx(0.04045, abs=1e-6)


def test_srgb_monotonic_and_continuous():
    v = np.linspace(0.0, 1.0, 100001)
    lin = D.srgb_to_linear(v)
    assert np.all(np.diff(lin) > 0)
    assert np.all(np.diff(D.linear_to_srgb(v)) > 0)
    # The two pieces meet at the breakpoint (no jump larger than one step's worth).
    a, b = D.srgb_to_linear(np.array([0.04045, 0.04045 + 1e-9]))
    assert abs(b - a) < 1e-8


def test_transfer_clips_and_keeps_nan():
    v = np.array([-0.5, 2.0, np.nan], dtype=np.float32)
    for fn in (D.srgb_to_linear, D.linear_to_srgb):
        out = fn(v)
        assert out.dtype == np.float32
        assert out[0] == 0.0 and out[1] == pytest.approx(1.0, abs=1e-6) and np.isnan(out[2])
    for name in D.TRANSFERS:
        out = D.decode(name, v)
        assert out[0] == 0.0 and out[1] == pytest.approx(1.0, abs=1e-6) and np.isnan(out[2])


def test_transfer_rejects_integer_arrays():
    with pytest.raises(ValidationError):
        D.srgb_to_linear(np.array([0, 128, 255], dtype=np.uint8))


def test_decode_encode_by_name_and_profile():
    v = np.array([0.0, 0.25, 0.5, 1.0])
    np.testing.assert_allclose(D.decode("gamma2.2", v), v**2.2)
    np.testing.assert_allclose(D.encode("gamma2.2", v**2.2), v)
    np.testing.assert_array_equal(D.decode("linear", v), v)
    np.testing.assert_array_equal(D.encode("linear", v), v)
    np.testing.assert_allclose(D.decode("srgb", v), [srgb_reference(x) for x in v])
    desktop, crt = D.get_display("desktop"), D.get_display("crt")
    np.testing.assert_allclose(D.decode(desktop, v), [srgb_reference(x) for x in v])
    np.testing.assert_allclose(D.decode(crt, v), v ** 2.2)
    assert D.decode("gamma2.2", v.astype(np.float32)).dtype == np.float32
    with pytest.raises(ValidationError):
        D.decode("pq", v)


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=0.0, max_value=1.0, allow_nan=False))
def test_srgb_round_trip_property(x):
    # The standard's two breakpoints (0.04045 and 0.0031308) disagree by ~5e-9 in
    # linear light, so right at the breakpoint the round trip is off by ~3e-8.
    assert float(D.linear_to_srgb(D.srgb_to_linear(np.float64(x)))) == pytest.approx(x, abs=5e-8)
    assert float(D.srgb_to_linear(np.float64(x))) == pytest.approx(srgb_reference(x), rel=1e-12, abs=1e-15)


# --------------------------------------------------------------------------- DisplayProfile


def test_display_profile_validation():
    spd = D.get_display("desktop").primaries
    ok = dict(name="x", title="X", kind="monitor", primaries=spd, pixels_per_degree=40.0, distance_m=0.5)
    D.DisplayProfile(**ok)
    assert D.DisplayProfile(**{**ok, "kind": "headset", "distance_m": math.inf}).vergence_D == 0.0
    for change, field in [({"pixels_per_degree": 0.5}, "pixels_per_degree"),
                          ({"pixels_per_degree": 501}, "pixels_per_degree"),
                          ({"pixels_per_degree": math.nan}, "pixels_per_degree"),
                          ({"distance_m": 0.0}, "distance_m"),
                          ({"distance_m": -1.0}, "distance_m"),
                          ({"distance_m": math.nan}, "distance_m"),
                          ({"transfer": "pq"}, "transfer"),
                          ({"kind": "tv"}, "kind"),
                          ({"name": ""}, "name"),
                          ({"resolution_px": (0, 10)}, "resolution_px"),
                          ({"primaries": D.Spectra(spd.wavelength_nm, spd.values, ("r", "g", "b"), "")},
                           "primaries.labels")]:
        with pytest.raises(ValidationError) as info:
            D.DisplayProfile(**{**ok, **change})
        assert info.value.field == field


# --------------------------------------------------------------------------- profile JSON


def write_json(path: Path, doc: dict) -> Path:
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def test_load_profile_with_csv_spectra(tmp_path):
    wl = np.arange(400.0, 701.0, 10.0)
    (tmp_path / "spectra").mkdir()
    write_csv(tmp_path / "spectra" / "mine.csv", wl, truth_rgb(wl))
    path = write_json(tmp_path / "mine.json", {
        "schema": "vrcorrect.display/1", "name": "mine", "title": "My monitor", "kind": "monitor",
        "spectra_csv": "spectra/mine.csv", "pixel_pitch_mm": 0.25, "distance_m": 0.5, "transfer": "gamma2.2",
        "resolution_px": [1920, 1080],
    })
    p = D.load_display_profile(path)
    assert p.name == "mine" and p.kind == "monitor" and p.transfer == "gamma2.2"
    assert p.pixels_per_degree == pytest.approx(34.9066, abs=1e-3)
    assert p.resolution_px == (1920, 1080)
    np.testing.assert_array_equal(p.primaries.wavelength_nm, wl)
    np.testing.assert_allclose(p.primaries.values, truth_rgb(wl), rtol=1e-8)
    # get_display accepts the same path, as str or Path.
    assert D.get_display(str(path)).pixels_per_degree == p.pixels_per_degree
    assert D.get_display(path).name == "mine"


def test_load_headset_profile_from_fov_and_preset_primaries(tmp_path):
    path = write_json(tmp_path / "hmd.json", {
        "schema": "vrcorrect.display/1", "name": "hmd", "kind": "headset", "preset_primaries": "quest2",
        "resolution_px": [2000, 2000], "fov_deg": 100, "distance_m": "inf",
    })
    p = D.load_display_profile(path)
    assert p.pixels_per_degree == 20.0 and math.isinf(p.distance_m) and p.title == "hmd"
    assert p.primaries is D.get_display("quest2").primaries


def test_load_profile_photometry_given_and_defaults(tmp_path):
    """Stated photometry is kept; what is not stated is the kind's default, and the sources say which."""
    base = {"schema": "vrcorrect.display/1", "name": "m", "preset_primaries": "desktop", "pixels_per_degree": 40,
            "distance_m": 0.7}
    p = D.load_display_profile(write_json(tmp_path / "a.json", {**base, "kind": "monitor",
                                                                "peak_luminance_cd_m2": 350, "ambient_lux": 500}))
    assert (p.photometry.peak_luminance_cd_m2, p.photometry.ambient_lux) == (350.0, 500.0)
    assert p.photometry.contrast == D.DEFAULT_PHOTOMETRY["monitor"][1]
    assert "peak_luminance_cd_m2, ambient_lux" in p.photometry.sources
    h = D.load_display_profile(write_json(tmp_path / "b.json", {**base, "kind": "headset"}))
    assert h.photometry.ambient_lux == 0.0 and "estimate" in h.photometry.sources
    assert h.photometry.black_cd_m2 == pytest.approx(h.photometry.peak_luminance_cd_m2 / h.photometry.contrast)


@pytest.mark.parametrize("name", D.preset_names())
def test_preset_photometry_is_sourced_and_plausible(name):
    """Headsets are dim and dark inside; monitors sit in room light; every figure says where it is from."""
    ph = D.get_display(name).photometry
    assert ph.sources and ("estimate" in ph.sources or "IEC" in ph.sources)
    if D.get_display(name).kind == "headset":
        assert ph.ambient_lux == 0.0 and 50 <= ph.peak_luminance_cd_m2 <= 300
    else:
        assert ph.ambient_lux > 0 and 50 <= ph.peak_luminance_cd_m2 <= 500


def test_photometry_validation():
    with pytest.raises(ValidationError) as info:
        D.Photometry(peak_luminance_cd_m2=100, contrast=1000, ambient_lux=float("nan"))
    assert info.value.field == "photometry.ambient_lux"
    d = D.get_display("desktop")
    with pytest.raises(ValidationError) as info:
        D.DisplayProfile(d.name, d.title, d.kind, d.primaries, d.pixels_per_degree, d.distance_m,
                         photometry=(200, 1000, 250))
    assert info.value.field == "photometry"


def test_load_profile_reports_every_problem(tmp_path):
    path = write_json(tmp_path / "bad.json", {
        "schema": "vrcorrect.display/1", "name": "bad", "kind": "tv", "preset_primaries": "desktop",
        "pixels_per_degree": 30, "distance_m": 0.6, "transfer": "pq", "colour": "blue",
    })
    with pytest.raises(ValidationErrors) as info:
        D.load_display_profile(path)
    err = info.value
    assert len(err.problems) == 3
    assert {p.field for p in err.problems} == {"kind", "transfer", "colour"}
    assert "3 problems" in str(err) and str(path) in str(err)


def test_load_profile_more_problems(tmp_path):
    wl = np.arange(400.0, 701.0, 10.0)
    v = truth_rgb(wl)
    v[3, 1] = -1.0
    write_csv(tmp_path / "neg.csv", wl, v)
    path = write_json(tmp_path / "bad2.json", {
        "schema": "vrcorrect.display/2", "name": "", "kind": "headset", "spectra_csv": "neg.csv",
        "pixel_pitch_mm": 0.1, "distance_m": -1,
    })
    with pytest.raises(ValidationErrors) as info:
        D.load_display_profile(path)
    fields = [p.field for p in info.value.problems]
    assert set(fields) == {"schema", "name", "spectra_csv", "distance_m", "pixel_pitch_mm"}
    csv_problem = next(p for p in info.value.problems if p.field == "spectra_csv")
    assert "line 5" in csv_problem.allowed  # header is line 1, the 4th data row is line 5


@pytest.mark.parametrize("doc, field", [
    ({"pixels_per_degree": 30, "pixel_pitch_mm": 0.25}, "pixels_per_degree"),
    ({}, "pixels_per_degree"),
    ({"pixels_per_degree": 30, "preset_primaries": "desktop", "spectra_csv": "x.csv"}, "spectra_csv"),
    ({"pixels_per_degree": 0}, "pixels_per_degree"),
    ({"fov_deg": 90, "resolution_px": [1000, 1000]}, "fov_deg"),  # fov for a monitor
    ({"pixels_per_degree": 30, "preset_primaries": "nosuch"}, "preset_primaries"),
    ({"pixels_per_degree": 30, "peak_luminance_cd_m2": 0}, "peak_luminance_cd_m2"),
    ({"pixels_per_degree": 30, "contrast": 1}, "contrast"),
    ({"pixels_per_degree": 30, "ambient_lux": -5}, "ambient_lux"),
    ({"pixels_per_degree": 30, "reflectivity": "matte"}, "reflectivity"),
])
def test_load_profile_single_problems(tmp_path, doc, field):
    base = {"schema": "vrcorrect.display/1", "name": "m", "kind": "monitor", "distance_m": 0.5}
    if "preset_primaries" not in doc and "spectra_csv" not in doc:
        base["preset_primaries"] = "desktop"
    path = write_json(tmp_path / "p.json", {**base, **doc})
    with pytest.raises(ValidationErrors) as info:
        D.load_display_profile(path)
    assert [p.field for p in info.value.problems] == [field]


def test_load_profile_unreadable(tmp_path):
    with pytest.raises(InputError):
        D.load_display_profile(tmp_path / "missing.json")
    broken = tmp_path / "broken.json"
    broken.write_text('{\n  "schema": "vrcorrect.display/1",\n  "name": \n}', encoding="utf-8")
    with pytest.raises(InputError, match="line 4"):
        D.load_display_profile(broken)
    arr = write_json(tmp_path / "list.json", [1, 2])  # type: ignore[arg-type]
    with pytest.raises(InputError, match="object"):
        D.load_display_profile(arr)


def test_load_profile_with_colour_and_gaussian_primaries(tmp_path):
    base = {"schema": "vrcorrect.display/1", "name": "m", "kind": "headset", "pixels_per_degree": 20,
            "distance_m": 1.5}
    p = D.load_display_profile(write_json(tmp_path / "c.json", {**base, "colour_primaries": "Apple Studio Display",
                                                                "photometry_sources": "measured"}))
    assert p.primaries is D.get_display("desktop").primaries
    assert p.photometry.sources == "measured"
    bands = {"red": [[610, 20, 1], [590, 40, 0.2]], "green": [[540, 30, 0.8]], "blue": [[450, 20, 1.5]]}
    g = D.load_display_profile(write_json(tmp_path / "g.json", {**base, "gaussian_primaries": bands}))
    wl = g.primaries.wavelength_nm
    np.testing.assert_allclose(g.primaries.channel("red"), gauss(wl, 610, 20) + 0.2 * gauss(wl, 590, 40))
    np.testing.assert_allclose(g.primaries.channel("blue"), 1.5 * gauss(wl, 450, 20))
    assert g.primaries.source == "parametric: sum of Gaussians"


@pytest.mark.parametrize("doc, fields", [
    ({"colour_primaries": "Sony BVM"}, ["colour_primaries"]),
    ({"colour_primaries": "Apple Studio Display", "preset_primaries": "desktop"}, ["spectra_csv"]),
    ({"gaussian_primaries": [620, 35, 1]}, ["gaussian_primaries"]),
    ({"gaussian_primaries": {"red": [[620, 35, 1]], "green": [], "blue": [[460, 0, 1], [900, 10, -1]],
                             "colour": 1, "source": 3}},
     ["gaussian_primaries.green", "gaussian_primaries.blue[0]", "gaussian_primaries.blue[1]",
      "gaussian_primaries.source", "gaussian_primaries.colour"]),
    ({"gaussian_primaries": {"red": [[620, 35, 0]], "green": [[530, 35, 1]], "blue": [[460, 25, 1]]}},
     ["primaries.values"]),
    ({"preset_primaries": "desktop", "photometry_sources": 5}, ["photometry_sources"]),
])
def test_load_profile_primaries_and_photometry_sources_problems(tmp_path, doc, fields):
    base = {"schema": "vrcorrect.display/1", "name": "m", "kind": "monitor", "distance_m": 0.5,
            "pixels_per_degree": 30}
    with pytest.raises(ValidationErrors) as info:
        D.load_display_profile(write_json(tmp_path / "p.json", {**base, **doc}))
    assert [p.field for p in info.value.problems] == fields
