"""hbake.fileio's atomic writer: an output appears whole or not at all, and an existing
file is replaced only by a complete one (the reports, `hbake texture`'s meshes and the
plots are written through it)."""
from __future__ import annotations

import errno

import pytest

from hbake.errors import OutputUnwritableError
from hbake.fileio import write_atomic, write_json_atomic


def _siblings(path):
    return sorted(p.name for p in path.parent.iterdir())


def test_a_complete_write_lands_and_leaves_no_temporary(tmp_path):
    out = tmp_path / "mesh.ply"
    assert write_atomic(out, lambda tmp: tmp.write_bytes(b"ply\n")) == out
    assert out.read_bytes() == b"ply\n"
    assert _siblings(out) == ["mesh.ply"]


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    out = tmp_path / "report.json"
    out.write_text("old\n")

    def half_then_fail(tmp):
        tmp.write_text("half of a new fi")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OutputUnwritableError) as exc:
        write_atomic(out, half_then_fail, "--report")
    assert str(exc.value) == f"--report {out}: No space left on device"
    assert exc.value.exit_code == 6
    assert out.read_text() == "old\n"
    assert _siblings(out) == ["report.json"]


def test_an_interrupt_mid_write_leaves_nothing_new(tmp_path):
    out = tmp_path / "plot.png"

    def interrupted(tmp):
        tmp.write_bytes(b"\x89PNG half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_atomic(out, interrupted, suffix=".tmp.png")
    assert _siblings(out) == []


def test_the_temporary_ends_in_the_suffix_a_format_sniffing_writer_needs(tmp_path):
    seen = []
    write_atomic(tmp_path / "fig.png", lambda tmp: (seen.append(tmp.name), tmp.write_bytes(b"x")),
                 suffix=".tmp.png")
    assert seen[0].startswith(".fig.png.") and seen[0].endswith(".tmp.png")


def test_json_is_sorted_and_indented(tmp_path):
    out = tmp_path / "r.json"
    write_json_atomic(out, {"b": 1, "a": [1, 2]}, "report")
    assert out.read_text() == '{\n  "a": [\n    1,\n    2\n  ],\n  "b": 1\n}\n'
