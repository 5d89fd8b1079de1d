"""Progress when stderr is not a terminal: one plain line per completed stage.

On a terminal ``hbake bake`` draws a bar per stage; under make, CI or a batch log (stderr
not a TTY) it prints ``hbake: stage NAME SECONDS s`` per completed stage instead, and
nothing with ``--quiet``. A stage that fails prints no line, so an error stays the only
line; ``--json`` keeps stdout pure JSON; ``hbake batch`` keeps its one line per model (its
bakes run quietly) so parallel bakes never interleave stage lines.
"""
from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from hbake.progress import Progress

REPO = Path(__file__).resolve().parents[3]
STAGE_LINE = re.compile(r"^hbake: stage (?P<name>[a-z ]+?) (?P<s>\d+\.\d\d) s( \(.*\))?$")


class _Tty(io.StringIO):
    def isatty(self):
        return True


def _stages(progress, names):
    for name in names:
        with progress.stage(name):
            pass


def test_a_pipe_gets_one_line_per_completed_stage():
    out = io.StringIO()
    p = Progress(stream=out)
    assert not p.enabled and p.lines
    _stages(p, ["load", "simplify", "decompose"])
    lines = out.getvalue().splitlines()
    assert [STAGE_LINE.match(ln).group("name") for ln in lines] == ["load", "simplify", "decompose"], lines
    assert "background" in lines[2]


def test_quiet_prints_nothing_and_a_terminal_gets_no_plain_lines():
    out = io.StringIO()
    _stages(Progress(stream=out, quiet=True), ["load", "write"])
    assert out.getvalue() == ""
    tty = _Tty()
    p = Progress(stream=tty)
    assert p.enabled and not p.lines
    _stages(p, ["load"])
    p.close()
    assert "hbake: stage" not in tty.getvalue()


def test_a_failed_stage_prints_no_line():
    out = io.StringIO()
    p = Progress(stream=out)
    with pytest.raises(RuntimeError):
        with p.stage("load"):
            raise RuntimeError("bad input")
    assert out.getvalue() == "" and "load" in p.timings


def _hbake(args, cwd):
    env = dict(os.environ, NO_COLOR="1", COLUMNS="200")
    env.pop("HBAKE_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "hbake.cli", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=300, env=env)


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    import trimesh

    d = tmp_path_factory.mktemp("progress")
    trimesh.creation.icosphere(subdivisions=2, radius=0.02).export(d / "ball.ply")
    return d / "ball.ply"


SMALL = ["--units", "m", "--target-faces", "100", "--atlas-size", "64", "--samples", "2000"]


def test_bake_into_a_pipe_prints_the_stages(ball, tmp_path):
    r = _hbake(["bake", str(ball), "-o", str(tmp_path / "b.hbundle"), *SMALL, "--json"], tmp_path)
    assert r.returncode == 0, r.stderr
    json.loads(r.stdout)                       # stdout stays one JSON document
    names = [m.group("name") for m in map(STAGE_LINE.match, r.stderr.splitlines()) if m]
    assert names == ["load", "simplify", "parameterize", "bake", "decompose", "mass", "quality",
                     "write"], r.stderr
    q = _hbake(["bake", str(ball), "-o", str(tmp_path / "q.hbundle"), *SMALL, "-q"], tmp_path)
    assert q.returncode == 0 and q.stderr == "" and q.stdout == "", q.stderr


def test_an_input_error_is_still_one_line(tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    r = _hbake(["bake", str(bad), "-o", str(tmp_path / "bad.hbundle"), "--units", "m"], tmp_path)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 4 and len(lines) == 1 and lines[0].startswith("hbake: error: "), r.stderr


def test_batch_prints_models_not_stages(ball, tmp_path):
    r = _hbake(["batch", str(ball), "-o", str(tmp_path / "out"), "-c", str(_batch_cfg(tmp_path))],
               tmp_path)
    assert r.returncode == 0, r.stderr
    assert "hbake: stage" not in r.stderr and "ball.ply" in r.stderr, r.stderr


def _batch_cfg(d: Path) -> Path:
    cfg = d / "batch.toml"
    cfg.write_text("[defaults]\nload.units = \"m\"\nsimplify.target_faces = 100\n"
                   "parameterize.atlas_width = 64\nparameterize.atlas_height = 64\n"
                   "quality.samples = 2000\n")
    return cfg


def test_make_demo_builds_no_cpp_tests_and_the_licence_is_an_spdx_string():
    """`make demo` builds the runtime, the example plugin and the Python module only (the
    C++ test suite is `make test`'s), and pyproject's licence is an SPDX string with no
    licence classifier (PEP 639, which the build backend reads without warnings)."""
    import tomllib

    mk = (REPO / "Makefile").read_text()
    assert re.search(r"^demo: setup$", mk, re.M)
    runtime = re.search(r"^runtime:.*?(?=^\S)", mk, re.M | re.S).group(0)
    targets = re.search(r"--target ([^\n]+)", runtime).group(1).split()
    assert targets == ["hrt", "hrt_example_device", "hrt_python", "hrt_python_stub"], targets
    proj = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert isinstance(proj["project"]["license"], str)
    assert not any(c.startswith("License ::") for c in proj["project"].get("classifiers", []))
