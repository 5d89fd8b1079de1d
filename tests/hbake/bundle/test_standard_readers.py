"""Every file of a bundle opens in the standard tools (docs/bundle-format.md, "Layout").

`coarse.ply` and `pieces.ply` in MeshLab (pymeshlab) and trimesh, `atlas.exr` in
OpenImageIO (`oiiotool --info` and its Python module); each reads what hbake's own reader
reads. Checked on the golden bundles (tests/golden/*.hbundle) and on bundles baked here
by both routes (the ridged block of tests/golden/make_golden.py).

Before format 1.3, pieces.ply kept the piece -> coarse-triangle map as one variable-length
list per piece (`property list uint uint coarse_faces`): pymeshlab aborted the whole
process on it ("buffer overflow detected") or stopped with "Unexpected EOF", and trimesh
said "PLY is unexpected length". pymeshlab therefore runs in a child process here, so an
abort fails one test instead of killing pytest.
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hbake.bundle import read_bundle

HERE = Path(__file__).resolve().parents[2]
GOLDEN = HERE / "golden"
sys.path.insert(0, str(GOLDEN))
_dont_write = sys.dont_write_bytecode
sys.dont_write_bytecode = True  # keep tests/golden free of __pycache__
try:
    import make_golden  # noqa: E402
finally:
    sys.dont_write_bytecode = _dont_write

GOLDEN_BUNDLES = sorted(GOLDEN.glob("*.hbundle"))

# The child process: load one PLY with pymeshlab and print what MeshLab sees.
_PYMESHLAB = """
import json, sys
import pymeshlab
ms = pymeshlab.MeshSet()
ms.load_new_mesh(sys.argv[1])
m = ms.current_mesh()
print(json.dumps({"vertices": m.vertex_number(), "faces": m.face_number(),
                  "wedge_uv": bool(m.has_wedge_tex_coord()),
                  "vertex_matrix": m.vertex_matrix().tolist(), "face_matrix": m.face_matrix().tolist()}))
"""


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> dict[str, Path]:
    """The ridged block baked now by the cage route (as the golden one) and by --method pp."""
    from hbake import bake
    from hbake.settings import BakeSettings

    out = tmp_path_factory.mktemp("fresh")
    cage = make_golden.bake_one("ridged_box", out)
    build, overrides = make_golden.GOLDEN["ridged_box"]
    src = out / "ridged_box.ply"
    build().export(src)
    pp = out / "ridged_box_pp.hbundle"
    bake(src, pp, BakeSettings().with_overrides({"load.units": "m", **overrides, "method": "pp"}, source="test"))
    return {"cage": cage, "pp": pp}


def _bundles(fresh) -> list[Path]:
    return GOLDEN_BUNDLES + [fresh["cage"], fresh["pp"]]


def _ids():
    return [b.name for b in GOLDEN_BUNDLES] + ["fresh-cage", "fresh-pp"]


def _pick(fresh, k: int) -> Path:
    return _bundles(fresh)[k]


CASES = range(len(GOLDEN_BUNDLES) + 2)


def _pymeshlab(path: Path) -> dict:
    r = subprocess.run([sys.executable, "-c", _PYMESHLAB, str(path)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, (f"pymeshlab could not open {path} (exit {r.returncode}): "
                               f"{(r.stderr or r.stdout).strip()[-600:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("k", CASES, ids=_ids())
def test_ply_files_open_in_meshlab(fresh, k):
    path = _pick(fresh, k)
    b = read_bundle(path)
    coarse = _pymeshlab(path / "coarse.ply")
    assert (coarse["vertices"], coarse["faces"]) == (len(b.coarse_vertices), len(b.coarse_faces))
    assert coarse["wedge_uv"]
    np.testing.assert_array_equal(coarse["face_matrix"], b.coarse_faces)
    pieces = _pymeshlab(path / "pieces.ply")
    pv = np.concatenate(b.piece_vertices)
    offsets = np.cumsum([0] + [len(p) for p in b.piece_vertices[:-1]])
    pf = np.concatenate([f + o for f, o in zip(b.piece_faces, offsets)])
    assert (pieces["vertices"], pieces["faces"]) == (len(pv), len(pf))
    np.testing.assert_array_equal(pieces["face_matrix"], pf)
    np.testing.assert_allclose(pieces["vertex_matrix"], pv, rtol=0, atol=0)


@pytest.mark.parametrize("k", CASES, ids=_ids())
def test_ply_files_open_in_trimesh(fresh, k):
    import trimesh

    path = _pick(fresh, k)
    b = read_bundle(path)
    coarse = trimesh.load(path / "coarse.ply", process=False)
    np.testing.assert_array_equal(coarse.faces.shape, b.coarse_faces.shape)
    pieces = trimesh.load(path / "pieces.ply", process=False)
    assert len(pieces.vertices) == sum(len(p) for p in b.piece_vertices)
    assert len(pieces.faces) == sum(len(p) for p in b.piece_faces)
    # the piece -> coarse-triangle map is there too, in fixed-size elements
    raw = pieces.metadata["_ply_raw"]
    counts = raw["piece"]["data"]["coarse_face_count"]
    rows = raw["piece_coarse_face"]["data"]["coarse_face"]
    assert len(counts) == len(b.piece_coarse_faces)
    maps = np.split(rows, np.cumsum(counts)[:-1])
    for got, want in zip(maps, b.piece_coarse_faces):
        np.testing.assert_array_equal(got, want)
    for p in range(len(counts)):
        part = pieces.submesh([np.flatnonzero(raw["face"]["data"]["piece"] == p)], append=True)
        assert part.is_watertight and part.volume > 0


def _oiiotool() -> str:
    cand = Path(sys.executable).parent / "oiiotool"
    found = str(cand) if cand.is_file() else shutil.which("oiiotool")
    assert found, "oiiotool is not installed (pyproject.toml's test extra installs OpenImageIO: make setup)"
    return found


@pytest.mark.parametrize("k", CASES, ids=_ids())
def test_atlas_opens_in_openimageio(fresh, k):
    import OpenImageIO as oiio

    path = _pick(fresh, k)
    b = read_bundle(path)
    h, w = b.atlas.shape[:2]
    exr = path / "atlas.exr"
    r = subprocess.run([_oiiotool(), "--info", "-v", str(exr)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert re.search(rf"\b{w} x +{h}, 4 channel, float openexr", r.stdout), r.stdout
    inp = oiio.ImageInput.open(str(exr))
    assert inp, oiio.geterror()
    try:
        spec = inp.spec()
        assert (spec.width, spec.height, spec.nchannels) == (w, h, 4)
        assert spec.format == oiio.FLOAT
        names = list(spec.channelnames)
        pixels = inp.read_image(0, 0, 0, 4, oiio.FLOAT)
    finally:
        inp.close()
    assert sorted(names) == ["A", "B", "G", "R"]
    pixels = np.asarray(pixels).reshape(h, w, 4)
    rgba = np.stack([pixels[:, :, names.index(c)] for c in "RGBA"], axis=2)
    np.testing.assert_array_equal(rgba, b.atlas)
