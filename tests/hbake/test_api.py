"""The public API of hbake (docs/reference/hbake-api.md): what __all__ lists exists, and the
page's example runs as written on a real mesh (a bake, a read, a validation, a lookup)."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import trimesh

import hbake

REPO = Path(__file__).resolve().parents[2]
PAGE = REPO / "docs" / "reference" / "hbake-api.md"


def test_every_name_of_all_exists_and_is_documented():
    text = PAGE.read_text("utf-8")
    for name in hbake.__all__:
        assert hasattr(hbake, name), name
        if name != "__version__":
            assert f"hbake.{name}" in text or f"`{name}`" in text, f"{name} is not on {PAGE.name}"


def test_the_pages_example_runs(tmp_path, monkeypatch):
    code = re.search(r"## Example\n\n```python\n(.*?)```", PAGE.read_text("utf-8"), re.S).group(1)
    # A bumpy sphere of 5 cm: not flat, closed, small enough to bake in seconds.
    s = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    v = s.vertices * (1 + 0.05 * np.sin(40 * s.vertices[:, 0]))[:, None]
    trimesh.Trimesh(v, s.faces, process=False).export(tmp_path / "part.stl")
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(code, str(PAGE), "exec"), scope)
    bundle, position = scope["bundle"], scope["position"]
    assert len(bundle.coarse_faces) <= 300
    # The corner's atlas position lies near the coarse corner (within the bake's displacement).
    corner = bundle.coarse_vertices[bundle.coarse_faces[0, 0]]
    assert np.linalg.norm(position - corner) < 0.01
