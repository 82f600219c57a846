"""Clips (a folder of frames, an animated GIF, a video file) through ``render``, ``correct`` and
``simulate``: real decoding (Pillow, imageio-ffmpeg's ffmpeg), the real GL path (Mesa llvmpipe),
the real solvers; tiny clips (8 frames of 48x40) so the file stays quick.

The plumbing (plumbing/clips.py) first: natural order, timing and resampling, the checks, the
all-or-nothing folder; then the commands: frame counts and names, each output frame against the
still-image command on that frame, the cut, resampling, one-line errors, nothing partial."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vrcorrect.apps import cli
from vrcorrect.plumbing import clips as C
from vrcorrect.plumbing.errors import InputError, ValidationError
from vrcorrect.plumbing.images import bundled_images

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_RX = ROOT / "vrcorrect" / "data" / "sample_rx.json"
W, H, N, CUT = 48, 40, 8, 4                      # 8 frames of 48x40; frames 4-7 are another picture


@pytest.fixture(scope="module")
def frames() -> list[np.ndarray]:
    """Frames 0-3 pan across the astronaut 2 px a frame, frames 4-7 across the coffee: a cut at 4."""
    photos = dict(bundled_images(96))
    out = []
    for i in range(N):
        photo = photos["astronaut"] if i < CUT else photos["coffee"]
        crop = photo[20:20 + H, 10 + 2 * i:10 + 2 * i + W]
        out.append(np.round(crop * 255).astype(np.uint8))
    return out


def _write_folder(folder: Path, frames: list[np.ndarray], names=None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        Image.fromarray(frame).save(folder / (names[i] if names else f"shot{i + 1}.png"))
    return folder


def _write_gif(path: Path, frames: list[np.ndarray], duration_ms: int = 40) -> Path:
    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=duration_ms, loop=0)
    return path


def _write_video(path: Path, frames: list[np.ndarray], fps: float = 24) -> Path:
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(str(path), (frames[0].shape[1], frames[0].shape[0]), fps=fps, quality=9,
                                         macro_block_size=8, ffmpeg_log_level="error")
    writer.send(None)
    for frame in frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()
    return path


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, frames) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("clips")
    return {"folder": _write_folder(d / "shots", frames), "gif": _write_gif(d / "clip.gif", frames),
            "video": _write_video(d / "clip.mp4", frames), "dir": d}


def _png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path)).astype(np.int16)


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _one_line_error(code: int, capsys, *words: str) -> str:
    err = capsys.readouterr().err
    # progress lines ("N/M frames, ...") may come first on a run that got that far; the error is one line
    lines = [line for line in err.splitlines() if line.strip() and not re.match(r"^\S.*: \d+/\d+ frames", line)]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("vrcorrect: error:"), err
    assert "Traceback" not in err
    for word in words:
        assert word.lower() in lines[0].lower(), (word, lines[0])
    return lines[0]


# --------------------------------------------------------------------------
# plumbing/clips.py
# --------------------------------------------------------------------------


def test_folder_frames_are_in_natural_order(tmp_path):
    names = ["frame10.png", "frame2.png", "frame1.png", "Frame3.png", "frame0100.png", "notes.txt", "._frame1.png"]
    for i, name in enumerate(names):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in C.clip_folder_files(tmp_path)] == \
        ["frame1.png", "frame2.png", "Frame3.png", "frame10.png", "frame0100.png"]


def test_each_kind_is_told_apart_and_decoded(inputs, frames, tmp_path):
    assert C.clip_kind(inputs["folder"]) == "folder" and C.clip_kind(inputs["gif"]) == "animation"
    assert C.clip_kind(inputs["video"]) == "video"
    still = _write_gif(tmp_path / "one.gif", frames[:1])
    assert C.clip_kind(still) is None and C.clip_kind(inputs["folder"] / "shot1.png") is None
    assert C.clip_kind(tmp_path / "missing.mp4") is None

    folder = C.open_clip(inputs["folder"])
    assert (folder.count, folder.size, folder.durations_s) == (N, (W, H), None)
    assert [p.name for p in folder.files][:3] == ["shot1.png", "shot2.png", "shot3.png"]
    decoded = list(folder.frames())
    assert all(np.array_equal(np.round(a * 255).astype(np.uint8), b) for a, b in zip(decoded, frames))
    assert all(np.array_equal(a, b) for a, b in zip(C.read_clip(inputs["folder"]).frames_u8(), frames))

    gif = C.open_clip(inputs["gif"])
    assert (gif.count, gif.size) == (N, (W, H)) and gif.durations_s == pytest.approx([0.04] * N)
    assert gif.frames_per_s == pytest.approx(25.0)
    # GIF quantises to 256 colours: close to the frames, not equal
    assert all(np.abs(a * 255 - b).mean() < 6 for a, b in zip(gif.frames(), frames))

    video = C.open_clip(inputs["video"])
    assert (video.count, video.size, video.frames_per_s) == (N, (W, H), pytest.approx(24.0))
    got = list(video.frames())
    assert len(got) == N and all(np.abs(a * 255 - b).mean() < 8 for a, b in zip(got, frames))   # lossy codec


def test_resampling_repeats_or_drops_by_presentation_time():
    up = C.resample_indices([1 / 24] * 30, 90)            # 1.25 s at 90 fps: 112.5 -> 113 frames
    assert len(up) == 113 and up[:9] == [0, 0, 0, 0, 1, 1, 1, 1, 2] and up[-1] == 29
    assert sorted(set(np.bincount(up))) == [3, 4]         # each 24 fps frame shown 3 or 4 times at 90
    down = C.resample_indices([1 / 90] * 90, 24)          # 1 s at 24 fps: every 3.75th frame
    assert len(down) == 24 and down[:5] == [0, 3, 7, 11, 15]
    assert C.resample_indices([0.1, 0.2, 0.1], 10) == [0, 1, 1, 2]        # an animation's own durations
    assert C.resample_indices([1 / 30] * 8, 30) == list(range(8))         # same rate: one each
    with pytest.raises(ValidationError, match="frames_per_s"):
        C.resample_indices([0.1], 0)
    with pytest.raises(ValidationError, match="durations_s"):
        C.resample_indices([0.1, -1.0], 30)


def test_frame_names_are_padded_to_the_length_and_at_least_five_digits():
    assert C.frame_name(0, 8) == "frame_00000.png" and C.frame_name(7, 8) == "frame_00007.png"
    assert C.frame_name(99999, 100000) == "frame_99999.png"
    assert C.frame_name(5, 100001) == "frame_000005.png"


def test_bad_clips_are_refused_naming_the_file(tmp_path, frames):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no images"):
        C.open_clip(empty)
    text_only = tmp_path / "text_only"
    text_only.mkdir()
    (text_only / "readme.txt").write_text("frames go here")
    with pytest.raises(InputError, match="no images"):
        C.open_clip(text_only)
    mixed = _write_folder(tmp_path / "mixed", frames[:3], ["f1.png", "f2.png", "f10.png"])
    Image.fromarray(frames[0][:-2]).save(mixed / "f2.png")   # f2 comes before f10: named first
    Image.fromarray(frames[0][:, :-4]).save(mixed / "f10.png")
    with pytest.raises(InputError, match=r"f2\.png: 48x38 pixels.*f1\.png is 48x40"):
        C.open_clip(mixed)
    broken = _write_folder(tmp_path / "broken", frames[:2])
    (broken / "shot3.png").write_text("not an image")
    with pytest.raises(InputError, match="shot3.png"):
        C.open_clip(broken)
    garbage = tmp_path / "garbage.mp4"
    garbage.write_bytes(os.urandom(2000))
    with pytest.raises(InputError, match="garbage.mp4: ffmpeg cannot read"):
        C.open_clip(garbage)
    long = _write_folder(tmp_path / "long", frames[:4])
    with pytest.raises(InputError, match="4 frames; a clip may have at most 3"):
        C.open_clip(long, max_frames=3)
    with pytest.raises(InputError, match="no such file"):
        C.open_clip(tmp_path / "nothing")


def test_a_frame_folder_appears_whole_or_not_at_all(tmp_path, frames):
    out = tmp_path / "out"
    rgb = frames[0] / 255.0
    with pytest.raises(RuntimeError, match="mid-clip"):
        with C.FrameFolder(out, 3) as folder:
            folder.write(0, rgb)
            folder.write(1, rgb)
            raise RuntimeError("mid-clip")
    assert _names(tmp_path) == []                                        # no folder, no temporary folder
    report = tmp_path / "report.json"
    with C.FrameFolder(out, 3) as folder:
        for i in range(3):
            folder.write(i, rgb)
        assert not out.exists()                                          # nothing visible before commit
        folder.commit([(report, lambda tmp: tmp.write_text("{}"))])
    assert _names(out) == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]
    assert report.read_text() == "{}" and _names(tmp_path) == ["out", "report.json"]
    assert np.array_equal(_png(out / "frame_00001.png"), frames[0])


def test_an_existing_folder_is_replaced_only_with_force_and_only_if_it_holds_frames(tmp_path, frames):
    out = tmp_path / "out"
    out.mkdir()
    C.FrameFolder(out, 2)                                                # an empty folder is fine
    (out / "frame_00000.png").write_bytes(b"old")
    with pytest.raises(InputError, match="not empty; pass --force"):
        C.FrameFolder(out, 2)
    with C.FrameFolder(out, 1, force=True) as folder:                    # replaces the old frames
        folder.write(0, frames[0] / 255.0)
        folder.commit()
    assert _names(out) == ["frame_00000.png"] and np.array_equal(_png(out / "frame_00000.png"), frames[0])
    (out / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="notes.txt"):
        C.FrameFolder(out, 1, force=True)                                # the user's file is never deleted
    assert (out / "notes.txt").read_text() == "mine"
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        C.FrameFolder(tmp_path / "file", 1, force=True)
    with pytest.raises(InputError, match="does not exist"):
        C.FrameFolder(tmp_path / "no" / "out", 1)


# --------------------------------------------------------------------------
# simulate and correct (CPU)
# --------------------------------------------------------------------------

FRAME_NAMES = [f"frame_{i:05d}.png" for i in range(N)]


def test_simulate_writes_what_the_eye_sees_of_every_frame_of_each_kind(inputs, tmp_path, capsys):
    outs = {}
    for kind in ("folder", "gif", "video"):
        outs[kind] = tmp_path / f"seen_{kind}"
        assert cli.main(["simulate", str(inputs[kind]), "-o", str(outs[kind])]) == 0
        assert _names(outs[kind]) == FRAME_NAMES
    assert "8 frames" in capsys.readouterr().out
    # each frame of the folder clip is what simulate makes of that frame as a still image
    still = tmp_path / "still.png"
    assert cli.main(["simulate", str(inputs["folder"] / "shot6.png"), "-o", str(still)]) == 0
    assert np.array_equal(_png(outs["folder"] / "frame_00005.png"), _png(still))
    assert _names(tmp_path) == sorted(["seen_folder", "seen_gif", "seen_video", "still.png"])   # no leftovers


def test_correct_solves_every_frame_and_reports_each_with_a_video_score(inputs, tmp_path, capsys):
    out, report = tmp_path / "shown", tmp_path / "report.json"
    assert cli.main(["correct", str(inputs["folder"]), "-o", str(out), "--report", str(report)]) == 0
    assert _names(out) == FRAME_NAMES
    data = json.loads(report.read_text())
    assert [f["file"] for f in data["frames"]] == FRAME_NAMES
    assert [f["source_frame"] for f in data["frames"]] == list(range(N))
    for f in data["frames"]:
        assert 0 < f["objective"] < f["objective_uncorrected"], f        # fast beats no correction
    assert data["summary"]["objective_median"] == pytest.approx(np.median([f["objective"] for f in data["frames"]]))
    assert 0 < data["summary"]["objective_fraction_median"] < 1
    assert data["clip"]["frames"] == N and data["clip"]["kind"] == "folder"
    assert data["metrics"]["video_jod"] > data["metrics"]["video_jod_uncorrected"]
    # the ceiling: each frame is exactly the still-image correction of that frame
    still = tmp_path / "still.png"
    assert cli.main(["correct", str(inputs["folder"] / "shot3.png"), "-o", str(still)]) == 0
    assert np.array_equal(_png(out / "frame_00002.png"), _png(still))
    for kind in ("gif", "video"):
        assert cli.main(["correct", str(inputs[kind]), "-o", str(tmp_path / kind), "--method", "wiener"]) == 0
        assert _names(tmp_path / kind) == FRAME_NAMES
    # --fps on correct resamples: 8 frames of 40 ms at 50 fps are 16, each source frame twice
    assert cli.main(["correct", str(inputs["gif"]), "-o", str(tmp_path / "gif50"), "--method", "wiener",
                     "--fps", "50"]) == 0
    assert len(_names(tmp_path / "gif50")) == 16
    assert np.array_equal(_png(tmp_path / "gif50" / "frame_00006.png"), _png(tmp_path / "gif" / "frame_00003.png"))
    assert "-> 16 frames at 50 fps" in capsys.readouterr().out


def test_a_failure_mid_clip_leaves_nothing(tmp_path, frames, capsys):
    """The 6th frame's header is fine (the clip passes its checks) but its pixels are cut short:
    decoding fails after five frames were written; no folder, no report, no temporary folder."""
    clip = _write_folder(tmp_path / "clip", frames)
    data = (clip / "shot6.png").read_bytes()
    (clip / "shot6.png").write_bytes(data[: len(data) // 2])
    for command in (["correct", "--report", str(tmp_path / "r.json")], ["simulate"]):
        code = cli.main([command[0], str(clip), "-o", str(tmp_path / "out"), *command[1:]])
        _one_line_error(code, capsys, "shot6.png")
        assert _names(tmp_path) == ["clip"]


def test_sigterm_while_correcting_a_clip_leaves_nothing(tmp_path, frames):
    """SIGTERM once frames are being written (seen in the temporary folder): exit 143, one line, and
    nothing beside the input: no folder, no temporary folder, no report."""
    clip = _write_folder(tmp_path / "clip", [frames[i % N] for i in range(40)],
                         [f"f{i}.png" for i in range(40)])
    command = [sys.executable, "-m", "vrcorrect.apps.cli", "correct", str(clip), "-o", str(tmp_path / "out"),
               "--report", str(tmp_path / "r.json"), "--tolerance", "0", "--iterations", "300"]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            partial = [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]
            if partial and len(list(partial[0].iterdir())) >= 2:
                break
            time.sleep(0.02)
        assert proc.poll() is None, "the run ended before two frames were written"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.rstrip().splitlines()[-1] == "vrcorrect: terminated (SIGTERM)"
    assert _names(tmp_path) == ["clip"]


# --------------------------------------------------------------------------
# render (the real-time path on Mesa llvmpipe)
# --------------------------------------------------------------------------


PUPIL_MM = 3.0
"""The cut test's fixed pupil (the pupil from the light would follow the clip's history)."""


def _fresh_corrector_output(ctx, frame: np.ndarray) -> np.ndarray:
    """What a Corrector made now (a cold start) shows for ``frame``: the default render's options (the
    robust design), the pupil fixed."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    corrector = Corrector(ctx, SAMPLE_RX, "quest2", "right", pupil=PUPIL_MM, robust=True)
    src = G.upload_texture(ctx, frame)
    tex, fbo = G.render_target(ctx, width=W, height=H)
    try:
        corrector.apply(src, fbo)
        return G.read_framebuffer(fbo).astype(np.int16)
    finally:
        corrector.release()
        G.release(fbo, tex, src)


def test_render_resets_on_a_cut_as_a_fresh_corrector_starts(gl, inputs, frames, tmp_path, capsys):
    """A folder clip played one frame each: the cut at frame 4 is detected and reported, and that
    frame is what a fresh Corrector makes of it (a cold start) within 2/255; without reprojection
    no cut is detected and the warm start from the other picture shows."""
    out = tmp_path / "shown"
    assert cli.main(["render", str(inputs["folder"]), "-o", str(out), "--pupil", str(PUPIL_MM)]) == 0
    printed = capsys.readouterr().out
    assert _names(out) == FRAME_NAMES
    assert f"1 cut(s) detected: at frame {CUT}" in printed, printed
    assert "folder of 8 frames with no frame rate, taken as 90 fps -> 8 frames at 90 fps" in printed
    assert "ms per frame" in printed and "software renderer" in printed and "median objective" in printed
    fresh = _fresh_corrector_output(gl, frames[CUT])
    assert np.abs(_png(out / FRAME_NAMES[CUT]) - fresh).max() <= 2
    assert np.abs(_png(out / FRAME_NAMES[CUT + 1]) - _fresh_corrector_output(gl, frames[CUT + 1])).max() > 2

    plain = tmp_path / "plain"
    assert cli.main(["render", str(inputs["folder"]), "-o", str(plain), "--no-reprojection", "--pupil",
                     str(PUPIL_MM)]) == 0
    printed = capsys.readouterr().out
    assert "--no-reprojection: no motion, no cut detection" in printed and "cut(s) detected" not in printed
    assert np.abs(_png(plain / FRAME_NAMES[CUT]) - fresh).max() > 2
    assert np.array_equal(_png(plain / FRAME_NAMES[0]), _png(out / FRAME_NAMES[0]))   # the same first frame


def test_render_plays_a_clip_at_the_headset_rate(inputs, tmp_path, capsys):
    """--fps resamples by presentation time: a 24 fps video at 60 fps, a GIF of 40 ms frames at 50 fps,
    a folder at --clip-fps 45 played at 90 (each frame twice: a repeated frame seen uncorrected is
    the same picture)."""
    cases = [
        (["render", str(inputs["video"]), "--fps", "60", "--view", "seen-corrected"], 20,
         "video of 8 frames at 24 fps -> 20 frames at 60 fps"),
        (["render", str(inputs["gif"]), "--fps", "50"], 16, "animation of 8 frames at 25 fps -> 16 frames at 50 fps"),
        (["render", str(inputs["folder"]), "--clip-fps", "45", "--view", "seen-uncorrected"], 16,
         "at 45 fps (--clip-fps) -> 16 frames at 90 fps"),
    ]
    for i, (argv, count, words) in enumerate(cases):
        out = tmp_path / f"out{i}"
        assert cli.main([*argv, "-o", str(out)]) == 0
        printed = capsys.readouterr().out
        assert words in printed, printed
        assert _names(out) == [C.frame_name(k, count) for k in range(count)]
    seen = [_png(tmp_path / "out2" / C.frame_name(k, 16)) for k in range(16)]
    assert all(np.array_equal(seen[2 * k], seen[2 * k + 1]) for k in range(8))
    assert not np.array_equal(seen[0], seen[2])


# --------------------------------------------------------------------------
# One-line errors; still images as before
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bad(tmp_path_factory, frames) -> Path:
    d = tmp_path_factory.mktemp("bad")
    (d / "empty").mkdir()
    (d / "no_images").mkdir()
    (d / "no_images" / "a.txt").write_text("x")
    mixed = _write_folder(d / "mixed", frames[:3], ["f1.png", "f2.png", "f3.png"])
    Image.fromarray(frames[0][:-2]).save(mixed / "f2.png")
    (d / "broken.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 this is not a video")
    long = d / "long"
    long.mkdir()
    for i in range(C.MAX_CLIP_FRAMES + 1):                      # never opened: the count is refused first
        (long / f"f{i}.png").touch()
    _write_folder(d / "clip", frames[:3])
    _write_gif(d / "slow.gif", frames[:3], duration_ms=60_000)  # 3 minutes
    _write_folder(d / "taken", frames[:1], ["frame_00000.png"])
    Image.fromarray(frames[0]).save(d / "still.png")
    return d


BAD_CLIPS = [
    ("empty folder", ["correct", "{d}/empty", "-o", "{d}/out"], ("empty", "no images")),
    ("folder without images", ["simulate", "{d}/no_images", "-o", "{d}/out"], ("no_images", "no images")),
    ("mixed sizes", ["render", "{d}/mixed", "-o", "{d}/out"], ("f2.png", "48x38", "one size")),
    ("unreadable video", ["correct", "{d}/broken.mp4", "-o", "{d}/out"], ("broken.mp4", "ffmpeg")),
    ("too many frames", ["simulate", "{d}/long", "-o", "{d}/out"], ("10001 frames", "at most 10000")),
    ("too many at --fps", ["render", "{d}/slow.gif", "-o", "{d}/out", "--fps", "90"], ("--fps", "16200")),
    ("--fps 0", ["render", "{d}/clip", "-o", "{d}/out", "--fps", "0"], ("--fps",)),
    ("--clip-fps text", ["correct", "{d}/clip", "-o", "{d}/out", "--clip-fps", "fast"], ("--clip-fps",)),
    ("--fps on a still", ["render", "{d}/still.png", "-o", "{d}/out.png", "--fps", "90"], ("--fps", "clip")),
    ("--frames on a clip", ["render", "{d}/clip", "-o", "{d}/out", "--frames", "3"], ("--frames", "still")),
    ("output named .png", ["simulate", "{d}/clip", "-o", "{d}/out.png"], ("--output", "folder")),
    ("output folder taken", ["correct", "{d}/clip", "-o", "{d}/taken"], ("taken", "--force")),
    ("output parent missing", ["render", "{d}/clip", "-o", "{d}/no/out"], ("does not exist",)),
    ("output is the input", ["simulate", "{d}/taken", "-o", "{d}/taken", "--force"], ("--output", "input")),
    ("--panel on a clip", ["correct", "{d}/clip", "-o", "{d}/out", "--panel", "{d}/p.png"], ("--panel", "clip")),
]


@pytest.mark.parametrize("argv, words", [c[1:] for c in BAD_CLIPS], ids=[c[0] for c in BAD_CLIPS])
def test_a_bad_clip_is_one_line_and_writes_nothing(argv, words, bad, capsys):
    before = _names(bad)
    code = cli.main([a.replace("{d}", str(bad)) for a in argv])
    _one_line_error(code, capsys, *words)
    assert _names(bad) == before


def test_a_one_frame_gif_is_a_still_image(tmp_path, frames, capsys):
    """Not a clip: one output PNG, as before."""
    gif = _write_gif(tmp_path / "one.gif", frames[:1])
    assert cli.main(["correct", str(gif), "-o", str(tmp_path / "out.png"), "--method", "wiener"]) == 0
    assert _png(tmp_path / "out.png").shape == (H, W, 3)
    assert "wrote" in capsys.readouterr().out
