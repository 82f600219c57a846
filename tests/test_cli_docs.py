"""docs/cli.md, the command-line reference generated from the parser (issue 26): it is current (a
changed flag fails here until the file is regenerated), it has a section for every command and
subcommand the parser knows, and the generator is deterministic and writes it by the project's
rules (atomic, a clear error and no traceback for a bad path, no overwriting a user's file)."""

from __future__ import annotations

import argparse
import difflib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from vrcorrect.apps import cli_docs
from vrcorrect.apps.cli import build_parser

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "cli.md"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The parser's subcommands straight from argparse (not through the generator)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def test_docs_cli_md_is_current():
    expected = cli_docs.render_cli_markdown()
    current = DOC.read_text(encoding="utf-8") if DOC.exists() else ""
    if current != expected:
        diff = "".join(list(difflib.unified_diff(current.splitlines(True), expected.splitlines(True),
                                                 "docs/cli.md", "generated", n=1))[:60])
        pytest.fail(f"docs/cli.md is not current; regenerate it with: {cli_docs.REGENERATE}\n{diff}")


def test_every_command_and_subcommand_has_a_heading_and_a_contents_link():
    text = DOC.read_text(encoding="utf-8")
    headings = set(re.findall(r"^#{2,6} `(vrcorrect[^`]*)`$", text, re.M))
    top = _subparsers(build_parser())
    assert len(top) >= 10, sorted(top)
    expected = set()
    for name, parser in top.items():
        expected.add(f"vrcorrect {name}")
        expected.update(f"vrcorrect {name} {sub}" for sub in _subparsers(parser))
    assert {"vrcorrect rx validate", "vrcorrect layer install", "vrcorrect bench"} <= expected
    missing = sorted(expected - headings)
    assert not missing, f"commands without a section in docs/cli.md: {missing}; run: {cli_docs.REGENERATE}"
    for name in expected:
        assert f"(#{name.replace(' ', '-')})" in text, f"no contents link to {name}"


def test_the_reference_ignores_the_terminal_and_names_nothing_of_this_machine(monkeypatch):
    monkeypatch.setenv("COLUMNS", "40")
    narrow = cli_docs.render_cli_markdown()
    monkeypatch.setenv("COLUMNS", "250")
    assert cli_docs.render_cli_markdown() == narrow
    assert str(REPO) not in narrow and str(Path.home()) not in narrow
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", narrow)
    assert narrow.startswith(f"{cli_docs.TITLE}\n\n{cli_docs.GENERATED}")
    assert cli_docs.REGENERATE in narrow.split("## Contents")[0]


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    rc = cli_docs.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_writes_then_rewrites_its_own_file_but_no_other_without_force(tmp_path, capsys):
    out = tmp_path / "cli.md"
    assert _run(capsys, out)[0] == 0
    assert out.read_text(encoding="utf-8") == DOC.read_text(encoding="utf-8")
    out.write_text(out.read_text(encoding="utf-8") + "stale\n", encoding="utf-8")
    rc, _, err = _run(capsys, "--check", out)
    assert rc == 1 and cli_docs.REGENERATE in err
    assert _run(capsys, out)[0] == 0                                 # an earlier output: no --force
    assert _run(capsys, "--check", out)[0] == 0
    mine = tmp_path / "notes.md"
    mine.write_text("my notes\n", encoding="utf-8")
    rc, _, err = _run(capsys, mine)
    assert rc == 2 and "--force" in err and mine.read_text(encoding="utf-8") == "my notes\n"
    assert _run(capsys, "--force", mine)[0] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cli.md", "notes.md"]   # no temporary left


@pytest.mark.parametrize("where", ["missing/cli.md", "."])
def test_a_bad_path_is_one_clear_line(tmp_path, capsys, where):
    rc, out, err = _run(capsys, tmp_path / where)
    assert rc == 2 and out == ""
    assert err.startswith("vrcorrect: error: ") and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_the_regenerate_command_runs_from_the_repository(tmp_path):
    """The documented command itself (the module's ``__main__``), in check mode, and a bad path."""
    ok = subprocess.run([sys.executable, "-m", "vrcorrect.apps.cli_docs", "--check", "docs/cli.md"], cwd=REPO,
                        capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    bad = subprocess.run([sys.executable, "-m", "vrcorrect.apps.cli_docs", str(tmp_path / "no" / "cli.md")],
                         cwd=REPO, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.startswith("vrcorrect: error: ")
