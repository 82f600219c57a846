"""``vrcorrect bench workgroups``: the default frame under several work-group shapes, timed
interleaved on the context's renderer (llvmpipe here), every shape's output equal to the default's,
the section and JSON it writes, and its errors."""

from __future__ import annotations

import json

from vrcorrect.runtime.eye_model import WorkGroups
from vrcorrect.studies.bench.workgroups import PASSES, SETTINGS, Setting, run_workgroup_bench


def test_every_shape_is_timed_interleaved_and_gives_the_defaults_output(gl, tmp_path):
    """Three settings (the default, 2 values a thread everywhere, two columns a column pass's work
    group), 2 timed frames of each kind: each has a positive median GPU time for changing and cold
    frames, the same 8-bit output as the default, and the section and the JSON say so."""
    two = Setting("2 everywhere", WorkGroups.every(2))
    paired = next(s for s in SETTINGS if s.shape.column_lines == {"full": 2, "coarse": 2} and
                  s.shape.table() == WorkGroups().table())
    out, js = tmp_path / "bench.md", tmp_path / "wg.json"
    report = run_workgroup_bench((72, 64), frames=2, settings=(SETTINGS[0], two, paired), out=out, json_out=js,
                                 warm_up_s=0.0, progress=False)
    rows = report["rows"]
    assert [r["setting"] for r in rows] == ["the default", "2 everywhere", paired.label]
    for r in rows:
        assert len(r["changing_frames_ms"]) == 2 and len(r["cold_frames_ms"]) == 2
        assert r["changing_gpu_ms"] > 0 and r["cold_gpu_ms"] > 0
        assert r["same_output_as_default"] is True
    assert rows[1]["values_per_thread"] == dict.fromkeys(PASSES, 2)
    text = out.read_text()
    assert "<!-- bench:workgroups -->" in text and "| 2 everywhere | 2 / 2 / 2 / 2, 2 (coarse columns 2) |" in text
    assert rows[2]["column_lines"] == {"full": 2, "coarse": 2}
    assert "| 8 / 4 / 8 / 8, 4 (coarse columns 2); 2 columns a work group (coarse 2) |" in text
    assert json.loads(js.read_text())["rows"][0]["values_per_thread"] == WorkGroups().table()


def test_bench_workgroups_refuses_bad_input(tmp_path, capsys):
    """One line naming the field, before any GL work; an existing JSON is not overwritten."""
    from vrcorrect.apps.cli import main

    for args, field in ((["--frames", "0"], "--frames"), (["--size", "0x10"], "--size"),
                        (["--json", str(tmp_path / "a.txt")], "--json")):
        assert main(["bench", "workgroups", "--no-write", *args]) == 2
        err = capsys.readouterr().err
        assert field in err and "Traceback" not in err, err
    existing = tmp_path / "wg.json"
    existing.write_text("mine")
    assert main(["bench", "workgroups", "--no-write", "--json", str(existing)]) == 2
    assert "--force" in capsys.readouterr().err and existing.read_text() == "mine"
