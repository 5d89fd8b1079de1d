"""coarse.ply and pieces.ply: fixed-header binary PLY, written byte-deterministically and
read strictly (the header must match the spec's template)."""
from __future__ import annotations

import os
import re
import struct
from pathlib import Path

import numpy as np

from hbake.bundle.format import (
    _COARSE_FACE,
    _COARSE_HEADER,
    _MAX_HEADER_BYTES,
    _PIECE_FACE,
    _PIECE_VERTEX,
    _PIECES_HEADER,
    _PIECES_HEADER_LISTS,
    _XYZ,
    FORMAT_VERSION,
    PIECES_TABLE_MINOR,
    _Fail,
    _n,
)
from hbake.errors import (
    BundleError,
)

# --------------------------------------------------------------------------- PLY

def _read_header(blob: bytes, name: str, add) -> tuple[list[str], int]:
    end = blob.find(b"end_header\n", 0, _MAX_HEADER_BYTES)
    if not blob.startswith(b"ply\n"):
        add(f"{name}: not a PLY file (the first line must be 'ply')")
        raise _Fail
    if end < 0:
        add(f"{name}: PLY header has no 'end_header' line within {_MAX_HEADER_BYTES} bytes")
        raise _Fail
    header_end = end + len(b"end_header\n")
    try:
        text = blob[:header_end].decode("ascii")
    except UnicodeDecodeError:
        add(f"{name}: PLY header is not ASCII")
        raise _Fail
    return text.split("\n")[:-1], header_end


def _match_header(lines: list[str], template: str, name: str, add) -> dict[str, int]:
    """Match header lines against the spec's fixed header; return the element counts.

    The template's third line is the optional comment: any one ``comment`` line is
    accepted there and nowhere else. Counts are plain decimal integers."""
    want = template.split("\n")[:-1]
    had_comment = len(lines) >= 3 and lines[2].startswith("comment ")
    if had_comment:
        lines = lines[:2] + lines[3:]
    want = want[:2] + want[3:]
    counts: dict[str, int] = {}
    if len(lines) != len(want):
        add(f"{name}: PLY header has {len(lines)} lines, the spec's header has {len(want)} "
            "(not counting the optional comment)")
        raise _Fail
    for k, (got, exp) in enumerate(zip(lines, want)):
        line_no = k + 1 + (1 if had_comment and k >= 2 else 0)
        if "{" in exp:  # "element vertex {n}": the count is the last word
            prefix, key = exp[:exp.index("{")], exp[exp.index("{") + 1:exp.index("}")]
            digits = got[len(prefix):] if got.startswith(prefix) else ""
            if not re.fullmatch(r"0|[1-9][0-9]{0,9}", digits) or int(digits) > 0xFFFFFFFF:
                add(f"{name}: PLY header line {line_no} is {got!r}, expected {prefix + key.upper()!r}")
                raise _Fail
            counts[key] = int(digits)
        elif got != exp:
            add(f"{name}: PLY header line {line_no} is {got!r}, expected {exp!r}")
            raise _Fail
    return counts


def write_coarse_ply(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
                     uvs: np.ndarray) -> None:
    """Write ``coarse.ply`` exactly as the spec lays it out."""
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces).reshape(-1, 3)
    uv = np.asarray(uvs, dtype=np.float32).reshape(-1, 3, 2)
    if len(uv) != len(f):
        raise ValueError(f"coarse_uvs has {len(uv)} faces, coarse_faces {len(f)}")
    if len(f) and (f.min() < 0 or f.max() > np.iinfo(np.uint32).max):
        raise ValueError("coarse face indices do not fit uint32")
    vert = np.zeros(len(v), dtype=_XYZ)
    v32 = v.astype("<f4")
    vert["x"], vert["y"], vert["z"] = v32[:, 0], v32[:, 1], v32[:, 2]
    rec = np.zeros(len(f), dtype=_COARSE_FACE)
    rec["n"] = 3
    rec["idx"] = f.astype("<u4")
    rec["nuv"] = 6
    rec["uv"] = uv.reshape(-1, 6).astype("<f4")
    with open(path, "wb") as fh:
        fh.write(_COARSE_HEADER.format(n=len(v), m=len(f)).encode("ascii"))
        fh.write(vert.tobytes())
        fh.write(rec.tobytes())


def write_pieces_ply(path: str | os.PathLike, piece_vertices: list[np.ndarray],
                     piece_faces: list[np.ndarray], piece_coarse_faces: list[np.ndarray]) -> None:
    """Write ``pieces.ply`` (format 1.3): global vertex indices, piece ids, and the
    coarse-face map as fixed-size elements (per piece its count, then all rows)."""
    if not (len(piece_vertices) == len(piece_faces) == len(piece_coarse_faces)):
        raise ValueError("piece_vertices, piece_faces and piece_coarse_faces differ in length")
    verts, faces, vid, fid = [], [], [], []
    offset = 0
    for p, (pv, pf) in enumerate(zip(piece_vertices, piece_faces)):
        pv = np.asarray(pv, dtype=np.float64).reshape(-1, 3)
        pf = np.asarray(pf, dtype=np.int64).reshape(-1, 3)
        if len(pf) and (pf.min() < 0 or pf.max() >= len(pv)):
            raise ValueError(f"piece {p}: face index out of range")
        verts.append(pv)
        faces.append(pf + offset)
        vid.append(np.full(len(pv), p, dtype=np.uint32))
        fid.append(np.full(len(pf), p, dtype=np.uint32))
        offset += len(pv)
    v = np.concatenate(verts) if verts else np.zeros((0, 3))
    f = np.concatenate(faces) if faces else np.zeros((0, 3), np.int64)
    vrec = np.zeros(len(v), dtype=_PIECE_VERTEX)
    v32 = v.astype("<f4")
    vrec["x"], vrec["y"], vrec["z"] = v32[:, 0], v32[:, 1], v32[:, 2]
    vrec["piece"] = np.concatenate(vid) if vid else np.zeros(0, np.uint32)
    frec = np.zeros(len(f), dtype=_PIECE_FACE)
    frec["n"] = 3
    frec["idx"] = f.astype("<u4")
    frec["piece"] = np.concatenate(fid) if fid else np.zeros(0, np.uint32)
    maps = [np.asarray(cf, dtype=np.int64).ravel() for cf in piece_coarse_faces]
    counts = np.array([len(cf) for cf in maps], dtype="<u4")
    rows = np.concatenate(maps).astype("<u4") if maps else np.zeros(0, "<u4")
    with open(path, "wb") as fh:
        fh.write(_PIECES_HEADER.format(n=len(v), m=len(f), p=len(maps), k=len(rows)).encode("ascii"))
        fh.write(vrec.tobytes())
        fh.write(frec.tobytes())
        fh.write(counts.tobytes())
        fh.write(rows.tobytes())


def _parse_coarse(blob: bytes, name: str, add) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lines, off = _read_header(blob, name, add)
    c = _match_header(lines, _COARSE_HEADER, name, add)
    n, m = c["n"], c["m"]
    need = off + n * _XYZ.itemsize + m * _COARSE_FACE.itemsize
    if len(blob) != need:
        add(f"{name}: {len(blob)} bytes, the header's {n} vertices and {m} faces need {need}")
        raise _Fail
    vert = np.frombuffer(blob, dtype=_XYZ, count=n, offset=off)
    rec = np.frombuffer(blob, dtype=_COARSE_FACE, count=m, offset=off + n * _XYZ.itemsize)
    bad = np.flatnonzero((rec["n"] != 3) | (rec["nuv"] != 6))
    if len(bad):
        add(f"{name}: {_n(len(bad), 'face record')} not '3 indices, 6 texcoords' "
            f"(first: face {bad[0]} has {rec['n'][bad[0]]} indices, {rec['nuv'][bad[0]]} texcoords)")
        raise _Fail
    v = np.stack([vert["x"], vert["y"], vert["z"]], axis=1).astype(np.float64)
    f = rec["idx"].astype(np.uint32)
    uv = rec["uv"].reshape(-1, 3, 2).astype(np.float32)
    return v, f, uv


def pieces_layout_is_table(format_version: str) -> bool:
    """Whether a bundle of ``format_version`` ("1.x") stores pieces.ply's map in the
    fixed-size elements of 1.3 (else in the per-piece lists of 1.0-1.2)."""
    minor = format_version.partition(".")[2]
    return minor.isdigit() and int(minor) >= PIECES_TABLE_MINOR


_PIECES_LAYOUT_13 = ("the piece -> coarse-triangle map is in the layout of format 1.3 (elements piece and "
                     "piece_coarse_face), but the manifest's format_version is below 1.3 (one coarse_faces "
                     "list per piece)")
_PIECES_LAYOUT_12 = ("the piece -> coarse-triangle map is in the layout of format 1.0-1.2 (one coarse_faces "
                     "list per piece), but the manifest's format_version is 1.3 or later (elements piece and "
                     "piece_coarse_face)")


def _parse_pieces(blob: bytes, name: str, add, format_version: str = FORMAT_VERSION):
    table = pieces_layout_is_table(format_version)
    head = blob[:_MAX_HEADER_BYTES]
    end = head.find(b"end_header\n")
    head = head if end < 0 else head[:end]
    if table and b"\nproperty list uint uint coarse_faces\n" in head:
        add(f"{name}: {_PIECES_LAYOUT_12}")
        raise _Fail
    if not table and b"\nelement piece_coarse_face " in head:
        add(f"{name}: {_PIECES_LAYOUT_13}")
        raise _Fail
    if not table:
        return _parse_pieces_lists(blob, name, add)
    lines, off = _read_header(blob, name, add)
    c = _match_header(lines, _PIECES_HEADER, name, add)
    n, m, p, k = c["n"], c["m"], c["p"], c["k"]
    need = off + n * _PIECE_VERTEX.itemsize + m * _PIECE_FACE.itemsize + 4 * p + 4 * k
    if len(blob) != need:
        add(f"{name}: {len(blob)} bytes, the header's {n} vertices, {m} faces, {p} pieces and {k} "
            f"coarse-face rows need {need}" + (" (file is truncated)" if len(blob) < need else " (trailing bytes)"))
        raise _Fail
    vrec = np.frombuffer(blob, dtype=_PIECE_VERTEX, count=n, offset=off)
    frec = np.frombuffer(blob, dtype=_PIECE_FACE, count=m, offset=off + n * _PIECE_VERTEX.itemsize)
    bad = np.flatnonzero(frec["n"] != 3)
    if len(bad):
        add(f"{name}: {_n(len(bad), 'face record')} without 3 indices (first: face {bad[0]})")
        raise _Fail
    fixed = off + n * _PIECE_VERTEX.itemsize + m * _PIECE_FACE.itemsize
    counts = np.frombuffer(blob, dtype="<u4", count=p, offset=fixed).astype(np.int64)
    total = int(counts.sum())
    if total != k:
        add(f"{name}: the pieces' coarse_face_count add up to {total}, the piece_coarse_face "
            f"element has {k} rows")
        raise _Fail
    words = np.frombuffer(blob, dtype="<u4", count=k, offset=fixed + 4 * p).astype(np.uint32)
    ends = np.cumsum(counts)
    maps = [words[e - c:e] for e, c in zip(ends.tolist(), counts.tolist())]
    v = np.stack([vrec["x"], vrec["y"], vrec["z"]], axis=1).astype(np.float64)
    return v, vrec["piece"].astype(np.uint32), frec["idx"].astype(np.uint32), \
        frec["piece"].astype(np.uint32), maps


def _parse_pieces_lists(blob: bytes, name: str, add):
    """pieces.ply of format 1.0-1.2: the map as a variable-length list per piece."""
    lines, off = _read_header(blob, name, add)
    c = _match_header(lines, _PIECES_HEADER_LISTS, name, add)
    n, m, p = c["n"], c["m"], c["p"]
    fixed = off + n * _PIECE_VERTEX.itemsize + m * _PIECE_FACE.itemsize
    if len(blob) < fixed + 4 * p:
        add(f"{name}: file is truncated ({len(blob)} bytes; the header's {n} vertices, {m} faces "
            f"and {p} pieces need at least {fixed + 4 * p})")
        raise _Fail
    vrec = np.frombuffer(blob, dtype=_PIECE_VERTEX, count=n, offset=off)
    frec = np.frombuffer(blob, dtype=_PIECE_FACE, count=m, offset=off + n * _PIECE_VERTEX.itemsize)
    bad = np.flatnonzero(frec["n"] != 3)
    if len(bad):
        add(f"{name}: {_n(len(bad), 'face record')} without 3 indices (first: face {bad[0]})")
        raise _Fail
    # Walk the count prefixes with struct (a numpy call per piece costs ~1 us, which is
    # most of the parse for a file of many small pieces); the lists are then views of
    # one array read at once.
    starts = np.zeros(p, dtype=np.int64)
    counts = np.zeros(p, dtype=np.int64)
    pos = fixed
    size = len(blob)
    unpack = struct.Struct("<I").unpack_from
    for k in range(p):
        if pos + 4 > size:
            add(f"{name}: file is truncated in the coarse_faces list of piece {k}")
            raise _Fail
        cnt = unpack(blob, pos)[0]
        pos += 4
        if pos + 4 * cnt > size:
            add(f"{name}: file is truncated in the coarse_faces list of piece {k} ({cnt} entries)")
            raise _Fail
        starts[k] = (pos - fixed) // 4
        counts[k] = cnt
        pos += 4 * cnt
    if pos != size:
        add(f"{name}: {size - pos} bytes after the last element")
        raise _Fail
    words = np.frombuffer(blob, dtype="<u4", count=(size - fixed) // 4, offset=fixed).astype(np.uint32)
    maps = [words[s:s + c] for s, c in zip(starts.tolist(), counts.tolist())]
    v = np.stack([vrec["x"], vrec["y"], vrec["z"]], axis=1).astype(np.float64)
    return v, vrec["piece"].astype(np.uint32), frec["idx"].astype(np.uint32), \
        frec["piece"].astype(np.uint32), maps


def read_coarse_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices float64 (N,3), faces uint32 (M,3), uvs float32 (M,3,2)); raises BundleError('mesh')."""
    msgs: list[str] = []
    try:
        return _parse_coarse(Path(path).read_bytes(), Path(path).name, msgs.append)
    except _Fail:
        raise BundleError("mesh", msgs[0]) from None


def read_pieces_ply(path: str | os.PathLike, format_version: str = FORMAT_VERSION):
    """(vertices, vertex piece ids, faces (global), face piece ids, coarse-face maps) of
    the pieces.ply of a bundle of ``format_version`` (the layout of 1.3, or of 1.0-1.2)."""
    msgs: list[str] = []
    try:
        return _parse_pieces(Path(path).read_bytes(), Path(path).name, msgs.append, format_version)
    except _Fail:
        raise BundleError("pieces", msgs[0]) from None


# The generic names of the API contract.
write_ply_mesh = write_coarse_ply
read_ply_mesh = read_coarse_ply
