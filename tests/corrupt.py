"""Corrupted variants of a valid bundle, each breaking one rule of docs/bundle-format.md.

Both `hbake validate` (tests/hbake/bundle/test_bundle.py) and the C++ loader (runtime tests,
reading the committed copies in tests/golden/corrupt/) must reject every
variant with the error class listed here. Variants marked ``rehash`` have their
manifest's SHA-256 and byte count recomputed, so that the hash check cannot be
what catches them.

Usage (regenerates the committed variants; tests/golden/make_golden.py calls it):

    .venv/bin/python tests/corrupt.py tests/golden/<name>.hbundle tests/golden/corrupt
"""
from __future__ import annotations

import hashlib
import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from hbake.bundle import manifest_bytes, read_atlas_exr, write_atlas_exr  # noqa: E402
from hbake.bundle.format import _COARSE_FACE, _PIECE_FACE, _PIECE_VERTEX, _XYZ  # noqa: E402

INDEX_NAME = "index.json"


@dataclass(frozen=True)
class Variant:
    name: str
    cls: str            # the error class validate / load_bundle must report (first problem)
    description: str
    apply: Callable[[Path], None]


# --------------------------------------------------------------------------- helpers

def _manifest(b: Path) -> dict:
    return json.loads((b / "manifest.json").read_text("utf-8"))


def _write_manifest(b: Path, m: dict) -> None:
    (b / "manifest.json").write_bytes(manifest_bytes(m))


def _rehash(b: Path, key: str) -> None:
    """Recompute files.<key>.sha256 and .bytes so that the hash check passes."""
    m = _manifest(b)
    entry = m["files"][key]
    blob = (b / entry["path"]).read_bytes()
    entry["sha256"] = hashlib.sha256(blob).hexdigest()
    entry["bytes"] = len(blob)
    _write_manifest(b, m)


def _ply_body_offset(blob: bytes) -> int:
    return blob.index(b"end_header\n") + len(b"end_header\n")


def _ply_count(blob: bytes, element: str) -> int:
    header = blob[:_ply_body_offset(blob)].decode("ascii")
    for line in header.split("\n"):
        if line.startswith(f"element {element} "):
            return int(line.split()[2])
    raise ValueError(f"no element {element}")


def _coarse_faces_view(b: Path):
    path = b / _manifest(b)["files"]["coarse_mesh"]["path"]
    blob = bytearray(path.read_bytes())
    off = _ply_body_offset(blob)
    n, m = _ply_count(blob, "vertex"), _ply_count(blob, "face")
    faces = np.frombuffer(blob, dtype=_COARSE_FACE, count=m, offset=off + n * _XYZ.itemsize)
    return path, blob, faces.copy(), off + n * _XYZ.itemsize, n


# --------------------------------------------------------------------------- the variants

def _flip_atlas_byte(b: Path) -> None:
    path = b / _manifest(b)["files"]["atlas"]["path"]
    blob = bytearray(path.read_bytes())
    k = (3 * len(blob)) // 4  # inside the compressed pixel data, past the header
    blob[k] ^= 0xFF
    path.write_bytes(bytes(blob))


def _major_version(b: Path) -> None:
    m = _manifest(b)
    m["format_version"] = "2.0"
    _write_manifest(b, m)


def _missing_pieces(b: Path) -> None:
    (b / _manifest(b)["files"]["pieces"]["path"]).unlink()


def _index_out_of_range(b: Path) -> None:
    path, blob, faces, off, n = _coarse_faces_view(b)
    faces["idx"][0, 1] = n  # one past the last vertex
    blob[off:off + faces.nbytes] = faces.tobytes()
    path.write_bytes(bytes(blob))
    _rehash(b, "coarse_mesh")


def _uv_outside(b: Path) -> None:
    path, blob, faces, off, n = _coarse_faces_view(b)
    faces["uv"][0, 0] = 1.25  # u of corner 0 of face 0
    blob[off:off + faces.nbytes] = faces.tobytes()
    path.write_bytes(bytes(blob))
    _rehash(b, "coarse_mesh")


def _degenerate_face(b: Path) -> None:
    path, blob, faces, off, n = _coarse_faces_view(b)
    faces["idx"][0, 2] = faces["idx"][0, 0]  # repeated vertex: zero area
    blob[off:off + faces.nbytes] = faces.tobytes()
    path.write_bytes(bytes(blob))
    _rehash(b, "coarse_mesh")


def _pieces_arrays(b: Path):
    path = b / _manifest(b)["files"]["pieces"]["path"]
    blob = bytearray(path.read_bytes())
    off = _ply_body_offset(blob)
    n, m = _ply_count(blob, "vertex"), _ply_count(blob, "face")
    verts = np.frombuffer(blob, dtype=_PIECE_VERTEX, count=n, offset=off).copy()
    faces = np.frombuffer(blob, dtype=_PIECE_FACE, count=m, offset=off + verts.nbytes).copy()
    return path, blob, off, verts, faces


def _nonconvex_piece(b: Path) -> None:
    """Pull the first vertex of the largest piece to the piece's centroid: a dent."""
    path, blob, off, verts, faces = _pieces_arrays(b)
    pid = np.bincount(verts["piece"]).argmax()
    idx = np.flatnonzero(verts["piece"] == pid)
    xyz = np.stack([verts["x"][idx], verts["y"][idx], verts["z"][idx]], axis=1).astype(np.float64)
    centre = xyz.mean(axis=0)
    # the vertex farthest from the centroid makes the deepest dent
    k = idx[np.argmax(np.linalg.norm(xyz - centre, axis=1))]
    new = 0.9 * centre + 0.1 * np.array([verts["x"][k], verts["y"][k], verts["z"][k]], dtype=np.float64)
    verts["x"][k], verts["y"][k], verts["z"][k] = new.astype(np.float32)
    blob[off:off + verts.nbytes] = verts.tobytes()
    path.write_bytes(bytes(blob))
    _rehash(b, "pieces")


def _map_out_of_range(b: Path) -> None:
    """Make the last coarse-face entry of the last piece that has any point past the mesh
    (the last piece_coarse_face row; in a 1.0-1.2 file, the last entry of the last
    non-empty coarse_faces list)."""
    path, blob, off, verts, faces = _pieces_arrays(b)
    m_coarse = _manifest(b)["coarse"]["triangles"]
    pos = off + verts.nbytes + faces.nbytes
    last_entry = None
    if b"\nelement piece_coarse_face " in blob[:off]:  # format 1.3: the rows end the file
        if _ply_count(blob, "piece_coarse_face"):
            last_entry = len(blob) - 4
        pos = len(blob)
    while pos < len(blob):
        cnt = int(np.frombuffer(blob, dtype="<u4", count=1, offset=pos)[0])
        if cnt:
            last_entry = pos + 4 * cnt  # offset of the last (largest) entry
        pos += 4 + 4 * cnt
    if last_entry is None:
        raise ValueError("no piece maps a coarse triangle")
    blob[last_entry:last_entry + 4] = np.array([m_coarse + 5], dtype="<u4").tobytes()
    path.write_bytes(bytes(blob))
    _rehash(b, "pieces")


def _exr_rewrite(b: Path, channels: tuple[str, ...], compression: str, edit=None) -> None:
    m = _manifest(b)
    path = b / m["files"]["atlas"]["path"]
    atlas = read_atlas_exr(path)
    if edit is not None:
        atlas = edit(atlas, b)
    keep = [("RGBA".index(c)) for c in channels]
    write_atlas_exr(path, atlas[:, :, keep], compression=compression, channels=channels)
    _rehash(b, "atlas")


def _missing_channel(b: Path) -> None:
    _exr_rewrite(b, ("R", "G", "A"), _manifest(b)["files"]["atlas"]["compression"])


def _rle_compression(b: Path) -> None:
    # RLE is lossless and OpenEXR 3.1 reads it, but the spec allows ZIP and PIZ only.
    import OpenEXR
    m = _manifest(b)
    path = b / m["files"]["atlas"]["path"]
    atlas = read_atlas_exr(path)
    pixels = {c: np.ascontiguousarray(atlas[:, :, k]) for k, c in enumerate("RGBA")}
    OpenEXR.File({"compression": OpenEXR.RLE_COMPRESSION, "type": OpenEXR.scanlineimage},
                 pixels).write(str(path))
    _rehash(b, "atlas")


def _nan_texel(b: Path) -> None:
    """NaN in the texel under the centroid of coarse triangle 0's UV triangle."""
    path, blob, faces, off, n = _coarse_faces_view(b)
    uv = faces["uv"][0].reshape(3, 2).astype(np.float64).mean(axis=0)

    def edit(atlas, _b):
        h, w = atlas.shape[:2]
        i = int(np.clip(np.floor(uv[0] * w), 0, w - 1))
        j = int(np.clip(np.floor((1 - uv[1]) * h), 0, h - 1))
        atlas = atlas.copy()
        atlas[j, i, 0] = np.nan
        return atlas

    _exr_rewrite(b, ("R", "G", "B", "A"), _manifest(b)["files"]["atlas"]["compression"], edit)


def _schema_missing_field(b: Path) -> None:
    m = _manifest(b)
    del m["mass"]
    _write_manifest(b, m)


VARIANTS: list[Variant] = [
    Variant("flipped_byte_atlas", "hash", "one byte of atlas.exr flipped (manifest unchanged)", _flip_atlas_byte),
    Variant("major_version", "version", "format_version edited to 2.0", _major_version),
    Variant("missing_pieces", "io", "pieces.ply deleted", _missing_pieces),
    Variant("schema_missing_field", "schema", "manifest without the required 'mass' object", _schema_missing_field),
    Variant("index_out_of_range", "mesh", "coarse face 0 uses vertex index N (rehashed)", _index_out_of_range),
    Variant("uv_outside", "mesh", "coarse face 0 corner 0 has u = 1.25 (rehashed)", _uv_outside),
    Variant("degenerate_face", "mesh", "coarse face 0 repeats a vertex index (rehashed)", _degenerate_face),
    Variant("missing_channel", "atlas", "atlas.exr rewritten without channel B (rehashed)", _missing_channel),
    Variant("rle_compression", "atlas", "atlas.exr rewritten with RLE compression (rehashed)", _rle_compression),
    Variant("nan_texel", "atlas", "NaN in R of a texel inside coarse triangle 0's UV triangle (rehashed)", _nan_texel),
    Variant("nonconvex_piece", "pieces", "a vertex of the largest piece pulled to 10% from its centroid "
            "(rehashed)", _nonconvex_piece),
    Variant("map_out_of_range", "pieces", "a piece maps a coarse triangle index past the mesh (rehashed)",
            _map_out_of_range),
]


def write_variants(source: str | Path, dest: str | Path) -> dict[str, Path]:
    """Write every variant of the valid bundle ``source`` into ``dest`` as
    ``<name>.hbundle`` plus ``index.json``; return {name: path}."""
    from hbake.errors import VALIDATE_EXIT

    source, dest = Path(source), Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    for v in VARIANTS:
        target = dest / f"{v.name}.hbundle"
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(source, target)
        v.apply(target)
        out[v.name] = target
    index = {
        "source": source.name,
        "note": "Each variant breaks one rule of docs/bundle-format.md; readers must reject it "
                "with this error class (the first problem `hbake validate` reports). "
                "Generated by tests/corrupt.py.",
        "variants": [{"name": v.name, "bundle": f"{v.name}.hbundle", "class": v.cls,
                      "exit_code": VALIDATE_EXIT[v.cls], "description": v.description}
                     for v in VARIANTS],
    }
    (dest / INDEX_NAME).write_text(json.dumps(index, indent=2, sort_keys=True) + "\n", "utf-8")
    return out


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: corrupt.py SOURCE.hbundle DEST_DIR")
    for name, path in write_variants(sys.argv[1], sys.argv[2]).items():
        print(f"{name}: {path}")
