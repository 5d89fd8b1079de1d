"""The bundle format (docs/bundle-format.md): writer, reader, validator, lookup, golden bundles.

Hand-built bundles (a cube whose atlas is filled analytically) test the
writer and the validator without the pipeline; the golden bundles in
tests/golden/ (made by tests/golden/make_golden.py with hbake.bake) test the
format end to end and carry the expected values that the C++ runtime's tests
compare against too. tests/corrupt.py makes one corrupted variant per rule.
"""
from __future__ import annotations

import filecmp
import hashlib
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import corrupt
from hbake import bundle as hb
from hbake.bundle import format as hb_format, uv_coverage, write as hb_write
from hbake.bundle import (
    atlas_lookup, read_bundle, texel_coords, validate_bundle, write_bundle,
)
from bundledata import _fill_atlas, _manifest_fields, cube_data  # noqa: F401
from hbake.errors import (
    VALIDATE_EXIT, BakeFailedError, BundleError, OutputExistsError, OutputUnwritableError,
)

REPO = Path(__file__).resolve().parents[3]
GOLDEN = REPO / "tests" / "golden"
#: The bundle kept in format 1.2 (pieces.ply's map as one list per piece).
FORMAT_1_2 = GOLDEN / "format-1.2" / "ridged_box_pp.hbundle"
SPEC = REPO / "docs" / "bundle-format.md"


# --------------------------------------------------------------------------- a hand-built bundle





@pytest.fixture()
def cube(tmp_path) -> Path:
    out = tmp_path / "cube.hbundle"
    write_bundle(out, cube_data())
    return out


def _classes(path) -> list[str]:
    return [p.cls for p in validate_bundle(path)]


def _first(path) -> hb.Problem:
    problems = validate_bundle(path)
    assert problems, f"{path} unexpectedly valid"
    return problems[0]


def _rewrite_manifest(path: Path, edit) -> None:
    m = json.loads((path / "manifest.json").read_text())
    edit(m)
    (path / "manifest.json").write_bytes(hb.manifest_bytes(m))


# --------------------------------------------------------------------------- writer and reader

def test_round_trip(tmp_path):
    data = cube_data()
    out = tmp_path / "rt.hbundle"
    manifest = write_bundle(out, data)
    b = read_bundle(out)
    # positions are stored as float32: equal to the float32 rounding of the input
    np.testing.assert_array_equal(b.coarse_vertices, data.coarse_vertices.astype(np.float32))
    np.testing.assert_array_equal(b.coarse_faces, data.coarse_faces)
    np.testing.assert_array_equal(b.coarse_uvs, data.coarse_uvs)
    np.testing.assert_array_equal(b.atlas, data.atlas)
    assert len(b.piece_vertices) == 2
    for k in range(2):
        np.testing.assert_array_equal(b.piece_vertices[k], data.piece_vertices[k].astype(np.float32))
        np.testing.assert_array_equal(b.piece_faces[k], data.piece_faces[k])
        np.testing.assert_array_equal(b.piece_coarse_faces[k], data.piece_coarse_faces[k])
    assert b.manifest == manifest
    assert b.path == out
    for key, value in data.manifest.items():
        assert b.manifest[key] == value
    assert b.manifest["format"] == "hbundle" and b.manifest["format_version"] == hb.FORMAT_VERSION
    # the returned manifest describes the files on disk
    for key in ("coarse_mesh", "atlas", "pieces"):
        entry = manifest["files"][key]
        blob = (out / entry["path"]).read_bytes()
        assert entry["bytes"] == len(blob)
        assert entry["sha256"] == hashlib.sha256(blob).hexdigest()
    assert manifest["files"]["atlas"]["width"] == 48 and manifest["files"]["atlas"]["height"] == 32


def test_manifest_encoding(cube):
    raw = (cube / "manifest.json").read_bytes()
    m = json.loads(raw)
    assert raw == (json.dumps(m, sort_keys=True, indent=2, ensure_ascii=False) + "\n").encode()
    assert raw.endswith(b"}\n") and b"\r" not in raw
    # no absolute paths, host names or time stamps
    assert str(cube.parent).encode() not in raw


def test_write_is_byte_deterministic(tmp_path):
    a, b = tmp_path / "a.hbundle", tmp_path / "b.hbundle"
    write_bundle(a, cube_data())
    write_bundle(b, cube_data())
    names = sorted(os.listdir(a))
    assert names == ["atlas.exr", "coarse.ply", "manifest.json", "pieces.ply"]
    match, mismatch, errors = filecmp.cmpfiles(a, b, names, shallow=False)
    assert mismatch == [] and errors == []


def _spec_header(title: str) -> str:
    """The fixed PLY header as docs/bundle-format.md prints it under ``title``."""
    text = SPEC.read_text()
    sec = text[text.index(title):]
    block = re.search(r"```\n(ply\n.*?end_header\n)```", sec, re.S)
    return block.group(1)


def test_ply_headers_are_the_spec_headers(cube):
    b = read_bundle(cube)
    coarse = (cube / "coarse.ply").read_bytes()
    want = _spec_header("## `coarse.ply`").replace(" N\n", f" {len(b.coarse_vertices)}\n") \
        .replace(" M\n", f" {len(b.coarse_faces)}\n")
    assert coarse.startswith(want.encode())
    nv = sum(len(p) for p in b.piece_vertices)
    nf = sum(len(p) for p in b.piece_faces)
    nk = sum(len(m) for m in b.piece_coarse_faces)
    want = _spec_header("## `pieces.ply`").replace(" N\n", f" {nv}\n").replace(" M\n", f" {nf}\n") \
        .replace(" P\n", f" {len(b.piece_vertices)}\n").replace(" K\n", f" {nk}\n")
    pieces = (cube / "pieces.ply").read_bytes()
    assert pieces.startswith(want.encode())
    # body sizes by the spec's record layout
    assert len(coarse) == coarse.index(b"end_header\n") + 11 \
        + 12 * len(b.coarse_vertices) + (1 + 12 + 1 + 24) * len(b.coarse_faces)
    assert len(pieces) == pieces.index(b"end_header\n") + 11 + 16 * nv + (1 + 12 + 4) * nf \
        + 4 * len(b.piece_vertices) + 4 * nk
    # the map: per piece its count, then the rows piece by piece
    body = np.frombuffer(pieces, "<u4", offset=len(pieces) - 4 * (len(b.piece_vertices) + nk))
    np.testing.assert_array_equal(body[:len(b.piece_vertices)], [len(m) for m in b.piece_coarse_faces])
    np.testing.assert_array_equal(body[len(b.piece_vertices):], np.concatenate(b.piece_coarse_faces))


def test_coarse_ply_opens_in_meshlab_with_wedge_uvs(cube):
    """MeshLab (pymeshlab) reads the welded mesh and the per-corner UVs."""
    import pymeshlab

    b = read_bundle(cube)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(cube / "coarse.ply"))
    m = ms.current_mesh()
    assert m.vertex_number() == len(b.coarse_vertices)
    assert m.face_number() == len(b.coarse_faces)
    assert m.has_wedge_tex_coord()
    np.testing.assert_array_equal(m.face_matrix(), b.coarse_faces)
    np.testing.assert_allclose(m.vertex_matrix(), b.coarse_vertices, rtol=0, atol=0)
    wedge = np.asarray(m.wedge_tex_coord_matrix()).reshape(-1, 3, 2)
    np.testing.assert_array_equal(wedge.astype(np.float32), b.coarse_uvs)


def test_pieces_ply_opens_in_trimesh(cube):
    import trimesh

    b = read_bundle(cube)
    mesh = trimesh.load(cube / "pieces.ply", process=False)
    assert len(mesh.faces) == sum(len(p) for p in b.piece_faces)
    for part in mesh.split(only_watertight=False):
        assert part.is_watertight and part.volume > 0


def test_exr_header(cube):
    import OpenEXR

    f = OpenEXR.File(str(cube / "atlas.exr"), separate_channels=True)
    assert len(f.parts) == 1
    p = f.parts[0]
    hdr = p.header
    assert p.compression() == OpenEXR.ZIP_COMPRESSION
    assert p.type() == OpenEXR.scanlineimage
    assert [c.name for c in hdr["channels"]] == ["A", "B", "G", "R"]
    for c in "RGBA":
        assert p.channels[c].type() == OpenEXR.FLOAT
    (x0, y0), (x1, y1) = hdr["dataWindow"]
    assert (x0, y0, x1, y1) == (0, 0, 47, 31)
    (x0, y0), (x1, y1) = hdr["displayWindow"]
    assert (x0, y0, x1, y1) == (0, 0, 47, 31)
    # no time stamp or other varying attribute
    assert set(hdr) <= {"channels", "compression", "dataWindow", "displayWindow", "lineOrder",
                        "pixelAspectRatio", "screenWindowCenter", "screenWindowWidth", "type"}


def test_piz_compression(tmp_path):
    out = tmp_path / "piz.hbundle"
    m = write_bundle(out, cube_data(), compression="piz")
    assert m["files"]["atlas"]["compression"] == "piz"
    assert validate_bundle(out) == []
    np.testing.assert_array_equal(read_bundle(out).atlas, cube_data().atlas)
    with pytest.raises(ValueError):
        write_bundle(tmp_path / "zstd.hbundle", cube_data(), compression="zstd")
    assert not (tmp_path / "zstd.hbundle").exists()


def _leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


def test_write_refuses_existing_and_force_replaces(tmp_path, cube):
    with pytest.raises(OutputExistsError) as e:
        write_bundle(cube, cube_data())
    assert e.value.exit_code == 5
    before = (cube / "atlas.exr").read_bytes()
    write_bundle(cube, cube_data(w=60, h=30), force=True)
    assert (cube / "atlas.exr").read_bytes() != before
    assert read_bundle(cube).atlas.shape == (30, 60, 4)
    assert _leftovers(cube.parent) == []
    # --force never deletes a directory that is not a bundle
    other = tmp_path / "precious"
    other.mkdir()
    (other / "thesis.tex").write_text("x")
    with pytest.raises(OutputExistsError):
        write_bundle(other, cube_data(), force=True)
    assert (other / "thesis.tex").read_text() == "x"


def test_write_unwritable(tmp_path):
    with pytest.raises(OutputUnwritableError) as e:
        write_bundle(tmp_path / "missing" / "x.hbundle", cube_data())
    assert e.value.exit_code == 6
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(OutputUnwritableError):
        write_bundle(blocker / "x.hbundle", cube_data())


@pytest.mark.parametrize("exc", [KeyboardInterrupt, RuntimeError])
def test_write_is_atomic(tmp_path, monkeypatch, exc, cube):
    """An exception (Ctrl-C included) while writing leaves nothing new behind and
    an existing bundle untouched, even with force."""
    before = {p.name: p.read_bytes() for p in cube.iterdir()}

    def boom(*a, **k):
        raise exc("stop")

    monkeypatch.setattr(hb_write, "write_pieces_ply", boom)
    with pytest.raises(exc):
        write_bundle(tmp_path / "new.hbundle", cube_data())
    with pytest.raises(exc):
        write_bundle(cube, cube_data(w=60), force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cube.hbundle"]
    assert {p.name: p.read_bytes() for p in cube.iterdir()} == before


def test_write_refuses_invalid_data(tmp_path):
    """write_bundle validates before publishing: a NaN texel under a UV triangle is
    a bake failure, and nothing is left behind."""
    data = cube_data()
    data.atlas[16, 8, 0] = np.nan
    with pytest.raises(BakeFailedError, match="atlas"):
        write_bundle(tmp_path / "bad.hbundle", data)
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- atlas lookup

def test_atlas_lookup_texel_centres_and_orientation():
    """Texel centres return the texel exactly; row 0 is the top (v = 1), column 0 the
    left (u = 0); width and height are not swapped on a non-square atlas."""
    h, w = 5, 7
    atlas = np.arange(h * w * 4, dtype=np.float32).reshape(h, w, 4)
    jj, ii = np.mgrid[0:h, 0:w]
    uv = np.stack([(ii.ravel() + 0.5) / w, 1 - (jj.ravel() + 0.5) / h], axis=1)
    # (i + 0.5) / w * w - 0.5 is i up to one rounding of the UV: 1e-15 of a texel
    np.testing.assert_allclose(atlas_lookup(atlas, uv), atlas.reshape(-1, 4), rtol=0, atol=1e-12)
    # top-left texel at small u, large v
    np.testing.assert_array_equal(atlas_lookup(atlas, np.array([0.01, 0.99])), atlas[0, 0])
    np.testing.assert_array_equal(atlas_lookup(atlas, np.array([0.99, 0.01])), atlas[h - 1, w - 1])
    np.testing.assert_allclose(texel_coords(np.array([[0.0, 1.0], [1.0, 0.0]]), w, h),
                               [[-0.5, -0.5], [w - 0.5, h - 0.5]])


def test_atlas_lookup_reproduces_affine_fields():
    """Bilinear interpolation is exact for a field affine in (u, v) away from the
    clamped border: analytic check with a non-square atlas."""
    h, w = 16, 24
    jj, ii = np.mgrid[0:h, 0:w]
    u = (ii + 0.5) / w
    v = 1 - (jj + 0.5) / h
    field = np.stack([3 * u - 2 * v + 1, 0.5 * u, -v, u + v], axis=-1).astype(np.float64)
    rng = np.random.default_rng(1)
    q = rng.uniform([0.5 / w, 0.5 / h], [1 - 0.5 / w, 1 - 0.5 / h], size=(500, 2))
    want = np.stack([3 * q[:, 0] - 2 * q[:, 1] + 1, 0.5 * q[:, 0], -q[:, 1], q[:, 0] + q[:, 1]], axis=1)
    np.testing.assert_allclose(atlas_lookup(field, q), want, atol=1e-12)


def test_atlas_lookup_matches_scipy():
    """Against an independent implementation: scipy's order-1 map_coordinates with
    edge clamping ('nearest'), including UVs outside the texel-centre range."""
    from scipy.ndimage import map_coordinates

    rng = np.random.default_rng(2)
    h, w = 11, 17
    atlas = rng.normal(size=(h, w, 4))
    q = rng.uniform(-0.05, 1.05, size=(400, 2))
    x = q[:, 0] * w - 0.5
    y = (1 - q[:, 1]) * h - 0.5
    want = np.stack([map_coordinates(atlas[:, :, c], [y, x], order=1, mode="nearest")
                     for c in range(4)], axis=1)
    np.testing.assert_allclose(atlas_lookup(atlas, q), want, atol=1e-12)


def test_footprint_is_exactly_the_texels_bilinear_reads():
    """_footprint_texels against brute force: dense sampling of the triangle, collecting
    the four (clamped) texels each sample reads."""
    rng = np.random.default_rng(3)
    w, h = 20, 13
    for _ in range(30):
        tri = rng.uniform(0, 1, size=(3, 2))
        fi, fj = uv_coverage._footprint_texels(tri, w, h)
        got = set(zip(fi.tolist(), fj.tolist()))
        b = rng.dirichlet([1, 1, 1], size=20000)
        b = np.concatenate([b, np.eye(3), [[0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5]]])
        xy = texel_coords(b @ tri, w, h)
        x0 = np.floor(xy[:, 0]).astype(int)
        y0 = np.floor(xy[:, 1]).astype(int)
        want = set()
        for di in (0, 1):
            for dj in (0, 1):
                want |= set(zip(np.clip(x0 + di, 0, w - 1).tolist(), np.clip(y0 + dj, 0, h - 1).tolist()))
        assert want <= got  # never misses a texel a lookup reads
        # and is tight: anything extra is a texel whose square the triangle only touches
        # within sampling resolution (at most one ring of boundary cells)
        extra = got - want
        assert len(extra) <= 0.25 * len(want) + 4


# --------------------------------------------------------------------------- validation

def test_valid_bundle_has_no_problems(cube):
    assert validate_bundle(cube) == []


def test_minor_version_and_unknown_fields_are_accepted(cube):
    def edit(m):
        m["format_version"] = "1.7"
        m["future_field"] = {"anything": [1, 2]}
        m["atlas"]["future_stat"] = 3
    _rewrite_manifest(cube, edit)
    assert validate_bundle(cube) == []
    assert read_bundle(cube).manifest["format_version"] == "1.7"


@pytest.mark.parametrize("edit, cls, text", [
    (lambda m: m.update(format_version="0.9"), "version", "unsupported major version 0.9"),
    (lambda m: m.update(format="gltf"), "version", "not an hbundle"),
    (lambda m: m.update(format_version="1"), "version", "MAJOR.MINOR"),
    (lambda m: m.pop("quality"), "schema", "'quality' is a required property"),
    (lambda m: m["atlas"].update(gutter=0), "schema", "atlas/gutter"),
    (lambda m: m["units"].update(source_unit="furlong"), "schema", "units/source_unit"),
    (lambda m: m["files"]["atlas"].update(compression="zstd"), "schema", "files/atlas/compression"),
    (lambda m: m["files"]["pieces"].update(path="../pieces.ply"), "schema", "files/pieces/path"),
    (lambda m: m["files"]["atlas"].update(channels=["R", "G", "B"]), "schema", "files/atlas/channels"),
    (lambda m: m["mass"].update(inertia=[[1, 0, 0], [0, 1, 0]]), "schema", "mass/inertia"),
    (lambda m: m["coarse"].update(triangles=13), "mesh", "the manifest says 8 and 13"),
    (lambda m: m["pieces"].update(count=3), "pieces", "the manifest says 3"),
    (lambda m: m["atlas"].update(width=50), "atlas", "files.atlas says 48x32"),
    (lambda m: m["files"]["atlas"].update(width=50), "atlas", "image is 48x32, the manifest says 50x32"),
    (lambda m: m["files"]["atlas"].update(compression="piz"), "atlas", "the manifest says PIZ"),
    (lambda m: m["files"]["coarse_mesh"].update(bytes=1), "hash", "the manifest says 1"),
    (lambda m: m["files"]["pieces"].update(sha256="a" * 64), "hash", "SHA-256"),
    (lambda m: m["files"]["pieces"].update(path="nothere.ply"), "io", "nothere.ply: missing"),
])
def test_manifest_problems(cube, edit, cls, text):
    _rewrite_manifest(cube, edit)
    problems = validate_bundle(cube)
    assert problems and problems[0].cls == cls, problems
    assert any(text in p.message for p in problems if p.cls == cls), problems


def test_manifest_not_json(cube):
    (cube / "manifest.json").write_text("{ not json")
    assert _first(cube).cls == "schema"
    (cube / "manifest.json").write_text("[1, 2]")
    assert _first(cube).cls == "schema"
    (cube / "manifest.json").unlink()
    assert _first(cube) == hb.Problem("io", "manifest.json: missing")


def test_manifest_nan_is_not_json(tmp_path):
    """Python's json would read NaN; JSON and the C++ reader (nlohmann-json) do not."""
    out = tmp_path / "nan.hbundle"
    write_bundle(out, cube_data())
    raw = (out / "manifest.json").read_text()
    raw2 = re.sub(r'"coverage": [0-9.e-]+', '"coverage": NaN', raw)
    assert raw2 != raw
    (out / "manifest.json").write_text(raw2)
    first = _first(out)
    assert first.cls == "schema" and "NaN" in first.message
    data = cube_data()
    data.manifest["atlas"]["coverage"] = float("nan")
    with pytest.raises(ValueError):  # the writer refuses to write it in the first place
        write_bundle(tmp_path / "nan2.hbundle", data)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nan.hbundle"]


def test_missing_bundle(tmp_path):
    assert _first(tmp_path / "nope.hbundle").cls == "io"
    (tmp_path / "f").write_text("")
    assert _first(tmp_path / "f").cls == "io"
    with pytest.raises(BundleError) as e:
        read_bundle(tmp_path / "nope.hbundle")
    assert e.value.cls == "io" and e.value.exit_code == 10


def _rewrite(path: Path, key: str, blob: bytes) -> None:
    """Replace a file and recompute its hash so that only the content check can fail."""
    name = json.loads((path / "manifest.json").read_text())["files"][key]["path"]
    (path / name).write_bytes(blob)
    corrupt._rehash(path, key)


@pytest.mark.parametrize("change, text", [
    (lambda b: b.replace(b"property float x\n", b"property double x\n", 1), "header line"),
    (lambda b: b.replace(b"binary_little_endian", b"binary_big_endian", 1), "header line 2"),
    (lambda b: b.replace(b"comment hbundle coarse mesh 1.0\n", b"", 1), None),  # optional: still valid
    (lambda b: b.replace(b"comment hbundle coarse mesh 1.0\n", b"comment a\ncomment b\n", 1), "header"),
    (lambda b: b + b"\0", "need"),
    (lambda b: b[:-1], "need"),
    (lambda b: b"solid x\n" + b, "not a PLY file"),
])
def test_coarse_ply_header_exactness(cube, change, text):
    blob = (cube / "coarse.ply").read_bytes()
    _rewrite(cube, "coarse_mesh", change(blob))
    if text is None:
        assert validate_bundle(cube) == []
        return
    first = _first(cube)
    assert first.cls == "mesh" and text in first.message, first


def _coarse_records(path: Path):
    blob = bytearray((path / "coarse.ply").read_bytes())
    off = blob.index(b"end_header\n") + 11
    n = int(re.search(rb"element vertex (\d+)", blob).group(1))
    m = int(re.search(rb"element face (\d+)", blob).group(1))
    verts = np.frombuffer(blob, hb_format._XYZ, n, off).copy()
    faces = np.frombuffer(blob, hb_format._COARSE_FACE, m, off + 12 * n).copy()
    return blob, off, verts, faces


def _put_coarse(path, blob, off, verts, faces):
    blob[off:off + verts.nbytes] = verts.tobytes()
    blob[off + verts.nbytes:off + verts.nbytes + faces.nbytes] = faces.tobytes()
    _rewrite(path, "coarse_mesh", bytes(blob))


def test_coarse_nan_vertex(cube):
    blob, off, verts, faces = _coarse_records(cube)
    verts["y"][3] = np.nan
    _put_coarse(cube, blob, off, verts, faces)
    first = _first(cube)
    assert first.cls == "mesh" and "vertex 3" in first.message and "non-finite" in first.message


def test_coarse_zero_area_face_with_distinct_indices(cube):
    """Three distinct but collinear vertices: zero area although no index repeats."""
    blob, off, verts, faces = _coarse_records(cube)
    t = 5
    a, b, c = faces["idx"][t]
    for name in "xyz":
        verts[name][c] = 0.5 * (verts[name][a] + verts[name][b])  # exact in float32 for a cube
    _put_coarse(cube, blob, off, verts, faces)
    assert any(p.cls == "mesh" and "degenerate" in p.message for p in validate_bundle(cube))


def test_coarse_uv_nan_and_bad_record_count(cube):
    blob, off, verts, faces = _coarse_records(cube)
    faces["uv"][2, 3] = np.nan
    _put_coarse(cube, blob, off, verts, faces)
    assert "non-finite UVs" in _first(cube).message
    blob, off, verts, faces = _coarse_records(cube)
    faces["nuv"][0] = 5
    _put_coarse(cube, blob, off, verts, faces)
    assert "texcoords" in _first(cube).message


def _pieces_records(path: Path):
    blob = bytearray((path / "pieces.ply").read_bytes())
    off = blob.index(b"end_header\n") + 11
    n = int(re.search(rb"element vertex (\d+)", blob).group(1))
    m = int(re.search(rb"element face (\d+)", blob).group(1))
    verts = np.frombuffer(blob, hb_format._PIECE_VERTEX, n, off).copy()
    faces = np.frombuffer(blob, hb_format._PIECE_FACE, m, off + verts.nbytes).copy()
    return blob, off, verts, faces


def _put_pieces(path, blob, off, verts, faces):
    blob[off:off + verts.nbytes] = verts.tobytes()
    blob[off + verts.nbytes:off + verts.nbytes + faces.nbytes] = faces.tobytes()
    _rewrite(path, "pieces", bytes(blob))


def test_pieces_inward(cube):
    blob, off, verts, faces = _pieces_records(cube)
    sel = faces["piece"] == 1
    faces["idx"][sel] = faces["idx"][sel][:, ::-1]
    _put_pieces(cube, blob, off, verts, faces)
    first = _first(cube)
    assert first.cls == "pieces" and "wound inward" in first.message and "piece 1" in first.message


def test_pieces_open(cube):
    blob, off, verts, faces = _pieces_records(cube)
    faces["idx"][0] = faces["idx"][0][[0, 2, 1]]  # one face flipped: edges no longer pair up
    _put_pieces(cube, blob, off, verts, faces)
    assert "not a closed" in _first(cube).message


def test_pieces_convexity_tolerance(cube):
    """A vertex pushed outward by less than the spec's tolerance passes; by more, fails.

    The tolerance is 1e-6 * bbox diagonal + 1e-9 m, the bbox being the coarse
    mesh's (a 0.1 m cube: diagonal 0.1732 m, tolerance 1.742e-7 m). Piece 0 is
    the box 0 <= x <= 0.05; a corner k on its x = 0.05 side that one of that
    side's two triangles does not use is pushed along +x: it then lies in front of
    that triangle's plane by exactly the push (float32 spacing at 0.05 is 3.7e-9)."""
    tol = hb.convexity_tolerance(np.sqrt(3) * 0.1)
    assert tol == pytest.approx(1.742e-7, rel=1e-3)
    for push, ok in ((0.5 * tol, True), (3 * tol, False)):
        fresh = cube.parent / f"push{ok}.hbundle"
        shutil.copytree(cube, fresh)
        blob, off, verts, faces = _pieces_records(fresh)
        xs = verts["x"].astype(np.float64)
        side = [f for f in faces["idx"][faces["piece"] == 0] if np.all(np.isclose(xs[f], 0.05))]
        assert len(side) == 2
        k = int(next(c for c in side[1] if c not in side[0]))
        verts["x"][k] = np.float32(0.05 + push)
        _put_pieces(fresh, blob, off, verts, faces)
        problems = validate_bundle(fresh)
        if ok:
            assert problems == []
        else:
            assert problems and problems[0].cls == "pieces" and "not convex" in problems[0].message
            lies = float(re.search(r"lies ([0-9.e+-]+) m in front", problems[0].message).group(1))
            assert lies == pytest.approx(3 * tol, rel=0.05)  # float32 rounding of 0.05 + push


def test_pieces_ids_and_too_small(cube):
    blob, off, verts, faces = _pieces_records(cube)
    faces["piece"][0] = 1  # face of piece 0 labelled as piece 1
    _put_pieces(cube, blob, off, verts, faces)
    assert _first(cube).cls == "pieces"
    data = cube_data()
    data.piece_vertices[0] = data.piece_vertices[0][:3]
    data.piece_faces[0] = np.array([[0, 1, 2]], np.uint32)
    with pytest.raises(BakeFailedError, match="fewer than 4 vertices"):
        write_bundle(cube.parent / "small.hbundle", data)


def _pieces_map_offset(path: Path) -> tuple[bytearray, int]:
    """pieces.ply's bytes and the offset of its piece element (the per-piece counts)."""
    blob, off, verts, faces = _pieces_records(path)
    return blob, off + verts.nbytes + faces.nbytes


def test_pieces_map_table_errors(cube):
    """The 1.3 map elements: length from the header, counts that add up to the rows."""
    good = (cube / "pieces.ply").read_bytes()
    _rewrite(cube, "pieces", good[:-4])
    first = _first(cube)
    assert first.cls == "pieces" and "2 pieces and 20 coarse-face rows need" in first.message \
        and "(file is truncated)" in first.message
    _rewrite(cube, "pieces", good + b"abc")
    assert "(trailing bytes)" in _first(cube).message
    _rewrite(cube, "pieces", good)
    blob, at = _pieces_map_offset(cube)
    blob[at:at + 4] = np.array([11], "<u4").tobytes()
    _rewrite(cube, "pieces", bytes(blob))
    assert _first(cube).message.endswith(
        "the pieces' coarse_face_count add up to 21, the piece_coarse_face element has 20 rows")
    _rewrite(cube, "pieces", good.replace(b"element piece_coarse_face 20\n", b"element piece_coarse_face 4294967295\n"))
    assert "4294967295 coarse-face rows need" in _first(cube).message


def test_pieces_layout_follows_the_version(cube):
    """1.3's layout under a 1.0-1.2 version, and 1.2's under 1.3, are pieces errors that say so."""
    _rewrite_manifest(cube, lambda m: m.update(format_version="1.2"))
    first = _first(cube)
    assert first.cls == "pieces" and "in the layout of format 1.3" in first.message
    legacy = cube.parent / "legacy.hbundle"
    shutil.copytree(FORMAT_1_2, legacy)
    assert validate_bundle(legacy) == []
    _rewrite_manifest(legacy, lambda m: m.update(format_version="1.3"))
    first = _first(legacy)
    assert first.cls == "pieces" and "in the layout of format 1.0-1.2" in first.message
    with pytest.raises(BundleError, match="in the layout of format 1.0-1.2"):
        read_bundle(legacy)
    # leading zeros are the number: 1.03 is 1.3, 1.010 is 1.10
    for v in ("1.03", "1.010"):
        _rewrite_manifest(legacy, lambda m: m.update(format_version=v))
        assert _first(legacy).cls == "pieces"
    _rewrite_manifest(legacy, lambda m: m.update(format_version="01.02"))
    assert validate_bundle(legacy) == []


def _rewrite_exr(path: Path, pixels: dict, header: dict | None = None):
    import OpenEXR

    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    hdr.update(header or {})
    OpenEXR.File(hdr, dict(pixels)).write(str(path / "atlas.exr"))
    corrupt._rehash(path, "atlas")


def _atlas_channels(path):
    a = read_bundle(path).atlas
    return {c: np.ascontiguousarray(a[:, :, k]) for k, c in enumerate("RGBA")}


def test_atlas_half_pixels(cube):
    px = {c: p.astype(np.float16) for c, p in _atlas_channels(cube).items()}
    _rewrite_exr(cube, px)
    first = _first(cube)
    assert first.cls == "atlas" and "pixel type HALF" in first.message


def test_atlas_data_window_not_at_origin(cube):
    px = _atlas_channels(cube)
    h, w = px["R"].shape
    _rewrite_exr(cube, px, {"dataWindow": (np.array([1, 0], np.int32), np.array([w, h - 1], np.int32)),
                            "displayWindow": (np.array([0, 0], np.int32), np.array([w - 1, h - 1], np.int32))})
    first = _first(cube)
    assert first.cls == "atlas" and "data window starts at (1, 0)" in first.message


def test_atlas_extra_channel_and_coverage(cube):
    orig = _atlas_channels(cube)
    px = dict(orig)
    px["Z"] = px["R"].copy()
    _rewrite_exr(cube, px)
    assert "not declared" in _first(cube).message
    px = dict(orig)
    px["A"] = px["A"] * 0.5
    _rewrite_exr(cube, px)
    assert "coverage A other than 0 or 1" in _first(cube).message


def test_atlas_texel_outside_gutter_is_unfilled(tmp_path):
    """A UV triangle that covers no texel centre reads texels with no covered texel
    within the gutter: the validator names it."""
    data = cube_data()
    # Move triangle 0's UVs to a sliver in the middle of the 4-texel gap between the
    # charts of columns 0 and 1 (texels 14..17 are empty; with gutter 1, 15 and 16
    # are farther than the gutter from any covered texel).
    w, h = 48, 32
    x = np.array([15.2, 15.4, 15.3]) + 0.5
    y = np.array([8.0, 8.0, 8.3]) + 0.5
    data.coarse_uvs[0] = np.stack([x / w, 1 - y / h], axis=1).astype(np.float32)
    data.atlas = _fill_atlas(data.coarse_vertices, data.coarse_faces.astype(int), data.coarse_uvs, w, h, 1)
    data.manifest["atlas"]["gutter"] = 1
    with pytest.raises(BakeFailedError, match="neither covered nor within the gutter"):
        write_bundle(tmp_path / "x.hbundle", data)


def test_nonfinite_texel_outside_footprints(cube):
    a = read_bundle(cube).atlas.copy()
    a[0, 47, 0] = np.inf  # top-right corner: no chart there
    _rewrite_exr(cube, {c: np.ascontiguousarray(a[:, :, k]) for k, c in enumerate("RGBA")})
    first = _first(cube)
    assert first.cls == "atlas" and "outside every UV triangle" in first.message


def test_not_an_exr(cube):
    _rewrite(cube, "atlas", b"P6\n1 1\n255\n\0\0\0")
    first = _first(cube)
    assert first.cls == "atlas" and "not an OpenEXR file" in first.message


def test_read_bundle_raises_first_problem(cube):
    _rewrite_manifest(cube, lambda m: m.update(format_version="3.1"))
    with pytest.raises(BundleError) as e:
        read_bundle(cube)
    assert e.value.cls == "version" and e.value.exit_code == 11


def test_read_bundle_without_verify_skips_hashes(cube):
    _rewrite_manifest(cube, lambda m: m["files"]["pieces"].update(sha256="b" * 64))
    with pytest.raises(BundleError):
        read_bundle(cube)
    assert read_bundle(cube, verify=False).manifest["files"]["pieces"]["sha256"] == "b" * 64


# --------------------------------------------------------------------------- corrupted variants

@pytest.mark.parametrize("variant", corrupt.VARIANTS, ids=lambda v: v.name)
def test_corrupt_variants_of_hand_built_bundle(tmp_path, cube, variant):
    out = corrupt.write_variants(cube, tmp_path / "corrupt")[variant.name]
    problems = validate_bundle(out)
    assert problems and problems[0].cls == variant.cls, problems


def _golden_bundles() -> list[Path]:
    return sorted(GOLDEN.glob("*.hbundle"))


def _corrupt_index() -> dict:
    return json.loads((GOLDEN / "corrupt" / corrupt.INDEX_NAME).read_text())


def test_committed_corrupt_variants_are_current(tmp_path):
    """tests/golden/corrupt/ (read by the C++ tests) is what corrupt.py makes now."""
    index = _corrupt_index()
    src = GOLDEN / index["source"]
    fresh = tmp_path / "corrupt"
    corrupt.write_variants(src, fresh)
    assert json.loads((fresh / corrupt.INDEX_NAME).read_text()) == index
    for v in index["variants"]:
        a, b = fresh / v["bundle"], GOLDEN / "corrupt" / v["bundle"]
        names = sorted(os.listdir(a))
        assert sorted(os.listdir(b)) == names
        _, mismatch, errors = filecmp.cmpfiles(a, b, names, shallow=False)
        assert mismatch == [] and errors == [], (v["name"], mismatch)


def _run_cli(cmd, *args):
    from hbake.cli.bundle import inspect, validate
    return CliRunner().invoke({"validate": validate, "inspect": inspect}[cmd], [str(a) for a in args])


@pytest.mark.parametrize("variant", [v["name"] for v in json.loads(
    (GOLDEN / "corrupt" / "index.json").read_text())["variants"]] if (GOLDEN / "corrupt" / "index.json").exists()
    else ["(no committed variants)"])
def test_validate_cli_names_committed_corrupt_variants(variant):
    index = {v["name"]: v for v in _corrupt_index()["variants"]}
    v = index[variant]
    path = GOLDEN / "corrupt" / v["bundle"]
    r = _run_cli("validate", path)
    assert r.exit_code == v["exit_code"] == VALIDATE_EXIT[v["class"]], r.output
    lines = r.output.splitlines()
    assert lines and all(ln.startswith(f"{path}: ") for ln in lines)
    assert lines[0].startswith(f"{path}: {v['class']}: ")
    assert "Traceback" not in r.output


def test_validate_cli_ok_and_missing(cube, tmp_path):
    r = _run_cli("validate", cube)
    assert r.exit_code == 0 and r.output == f"{cube}: OK\n"
    r = _run_cli("validate", tmp_path / "nope.hbundle")
    assert r.exit_code == 10 and r.output.startswith(f"{tmp_path / 'nope.hbundle'}: io: ")


def test_inspect_cli(cube):
    r = _run_cli("inspect", cube)
    assert r.exit_code == 0, r.output
    for word in ("48 x 32", "12 triangles", "2 convex pieces", "valid", "cube.stl"):
        assert word in r.output, word
    r = _run_cli("inspect", cube, "--json")
    out = json.loads(r.output)
    assert r.exit_code == 0 and out["valid"] is True and out["problems"] == []
    assert out["manifest"] == json.loads((cube / "manifest.json").read_text())
    (cube / "pieces.ply").unlink()
    out = json.loads(_run_cli("inspect", cube, "--json").output)
    assert out["valid"] is False and out["problems"][0]["class"] == "io"
    assert "problem" in _run_cli("inspect", cube).output


# --------------------------------------------------------------------------- golden bundles

def test_golden_bundles_exist_and_are_small():
    bundles = _golden_bundles()
    assert 2 <= len(bundles) <= 3
    total = sum(f.stat().st_size for f in GOLDEN.rglob("*") if f.is_file())
    assert total < 500_000, f"tests/golden holds {total} bytes"
    sizes = [(m["atlas"]["width"], m["atlas"]["height"])
             for m in (json.loads((b / "manifest.json").read_text()) for b in bundles)]
    assert any(w != h for w, h in sizes), "one golden atlas must be non-square"


@pytest.mark.parametrize("name", [b.name for b in _golden_bundles()] or ["(none)"])
def test_golden_bundle_validates(name):
    path = GOLDEN / name
    assert validate_bundle(path) == []
    r = _run_cli("validate", path)
    assert r.exit_code == 0


def _golden_and_1_2() -> list[str]:
    return [b.name for b in _golden_bundles()] + [str(FORMAT_1_2.relative_to(GOLDEN))]


@pytest.mark.parametrize("name", _golden_and_1_2())
def test_golden_expected_values_reproduce(name):
    path = GOLDEN / name
    exp = json.loads((GOLDEN / name.replace(".hbundle", ".expected.json")).read_text())
    b = read_bundle(path)
    h, w = b.atlas.shape[:2]
    assert exp["bundle"] == path.name
    assert exp["format_version"] == b.manifest["format_version"] == ("1.2" if path == FORMAT_1_2 else hb.FORMAT_VERSION)
    assert (exp["atlas"]["width"], exp["atlas"]["height"]) == (w, h)
    assert exp["coarse"] == {"vertices": len(b.coarse_vertices), "triangles": len(b.coarse_faces)}
    assert exp["pieces"]["count"] == len(b.piece_coarse_faces)
    assert exp["pieces"]["coarse_faces"] == [m.tolist() for m in b.piece_coarse_faces]
    tol = exp["tolerance"]["position"]
    for t in exp["texels"]:
        np.testing.assert_array_equal(b.atlas[t["j"], t["i"]], np.float32(t["rgba"]))
    uv = np.array([s["uv"] for s in exp["lookups"]])
    got = atlas_lookup(b.atlas, uv)
    np.testing.assert_allclose(got, [s["rgba"] for s in exp["lookups"]], rtol=0, atol=tol)
    # the listed lookups discriminate the convention: a v flip or a missing half-texel
    # shift would move most of them by far more than the tolerance
    wrong_flip = atlas_lookup(b.atlas[::-1], uv)[:, :3]
    shifted = atlas_lookup(b.atlas, uv + [0.5 / w, -0.5 / h])[:, :3]
    wrongs = [wrong_flip, shifted]
    if w != h:  # W and H swapped: the atlas read as if it were H wide and W high
        wrongs.append(atlas_lookup(b.atlas.reshape(w, h, 4), uv)[:, :3])
    for wrong in wrongs:
        moved = np.abs(wrong - got[:, :3]).max(axis=1) > 100 * tol
        assert moved.mean() > 0.5
    v, f, uvs = b.coarse_vertices, b.coarse_faces.astype(int), b.coarse_uvs.astype(np.float64)
    for s in exp["surface_samples"]:
        t, bary = s["triangle"], np.array(s["barycentrics"])
        assert abs(bary.sum() - 1) < 1e-12 and bary.min() >= 0
        np.testing.assert_allclose(s["uv"], bary @ uvs[t], atol=1e-12)
        p = bary @ v[f[t]]
        np.testing.assert_allclose(s["coarse_point"], p, atol=1e-12)
        n = np.cross(v[f[t, 1]] - v[f[t, 0]], v[f[t, 2]] - v[f[t, 0]])
        n /= np.linalg.norm(n)
        np.testing.assert_allclose(s["normal"], n, atol=1e-12)
        pos = atlas_lookup(b.atlas, np.array(s["uv"]))[:3]
        np.testing.assert_allclose(s["position"], pos, atol=tol)
        assert s["height"] == pytest.approx(float(np.dot(pos - p, n)), abs=tol)
        # the baked point is near the coarse surface point: within the recorded bounds
        q = b.manifest["quality"]
        assert -q["displacement_inward"] - tol <= s["height"] <= q["displacement_outward"] + tol


def test_format_1_2_bundle_still_reads_and_is_current(tmp_path):
    """The 1.2 bundle (pieces.ply's map as one list per piece) validates through the
    command, reads, and is what tests/golden/make_golden.py makes now: the ridged block
    baked by --method pp and stored in the 1.2 layout (which matched hbake's 1.2 writer
    byte for byte when the fixture was first made by it)."""
    r = _run_cli("validate", FORMAT_1_2)
    assert r.exit_code == 0 and r.output == f"{FORMAT_1_2}: OK\n", r.output
    assert read_bundle(FORMAT_1_2).manifest["format_version"] == "1.2"
    assert b"\nproperty list uint uint coarse_faces\n" in (FORMAT_1_2 / "pieces.ply").read_bytes()[:1024]
    make_golden = _make_golden()
    fresh = make_golden.bake_legacy(tmp_path)
    names = sorted(os.listdir(FORMAT_1_2))
    assert sorted(os.listdir(fresh)) == names
    _, mismatch, errors = filecmp.cmpfiles(fresh, FORMAT_1_2, names, shallow=False)
    assert mismatch == [] and errors == []


def _make_golden():
    import sys

    sys.path.insert(0, str(GOLDEN))
    dont_write = sys.dont_write_bytecode
    sys.dont_write_bytecode = True  # keep tests/golden free of __pycache__
    try:
        import make_golden
    finally:
        sys.path.remove(str(GOLDEN))
        sys.dont_write_bytecode = dont_write
    return make_golden


# --------------------------------------------------------------------------- determinism of a real bake

def test_bake_twice_gives_byte_identical_bundles(tmp_path):
    """The same input and settings give a byte-identical bundle
    (the pebble input and settings of the golden bundles, baked twice)."""
    make_golden = _make_golden()
    outs = []
    for k in range(2):
        d = tmp_path / f"run{k}"
        d.mkdir()
        outs.append(make_golden.bake_one("pebble", d))
    names = sorted(os.listdir(outs[0]))
    assert names == sorted(os.listdir(outs[1])) == ["atlas.exr", "coarse.ply", "manifest.json", "pieces.ply"]
    _, mismatch, errors = filecmp.cmpfiles(outs[0], outs[1], names, shallow=False)
    assert mismatch == [] and errors == []
    assert validate_bundle(outs[0]) == []
