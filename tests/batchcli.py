"""Helpers of the tests that drive the `hbake` command on small meshes: a quick settings
file (LOW), a bumpy sphere (blob), the command itself (run) and its one-line errors."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh


def hbake() -> list[str]:
    script = Path(sys.executable).with_name("hbake")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hbake.cli"]


def env() -> dict:
    e = dict(os.environ, NO_COLOR="1", COLUMNS="200")
    e.pop("FORCE_COLOR", None)
    return e


#: Low settings for every test bake (a batch config's [defaults]).
LOW = """[defaults]
simplify.target_faces = 60
parameterize.atlas_width = 32
parameterize.atlas_height = 32
quality.samples = 1000
"""


def blob(path: Path, k: float = 40.0, subdivisions: int = 3) -> Path:
    """A closed, bumpy, flattened icosphere of 2 cm (1,280 triangles at 3 subdivisions)."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.02)
    v = m.vertices.copy()
    v[:, 2] *= 0.7
    v += 0.0005 * np.sin(k * v[:, [0]] / 0.02) * m.vertex_normals
    trimesh.Trimesh(v, m.faces, process=False).export(path)
    return path


def run(args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(hbake() + [str(a) for a in args], capture_output=True, text=True,
                          env=env(), timeout=kw.pop("timeout", 600), **kw)


def one_error_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert lines[0].startswith("hbake: error: ") and "Traceback" not in stderr
    return lines[0]
