"""The haptic bundle (``.hbundle``): writer, reader, validator and atlas lookup.

This module is the reference implementation of docs/bundle-format.md; the C++
loader in ``runtime/src/io/`` must agree with it, and both are checked against
the golden bundles in ``tests/golden/``.

* :func:`write_bundle` writes a bundle atomically (temporary sibling directory,
  then ``os.rename``) and byte-deterministically (fixed PLY headers, EXR without
  time stamps, manifest with sorted keys), and validates it before publishing it.
* :func:`validate_bundle` returns one :class:`Problem` per issue, each with the
  error class of the spec (``io``, ``version``, ``schema``, ``hash``, ``mesh``,
  ``atlas``, ``pieces``); :func:`read_bundle` raises the first as a
  :class:`~hbake.errors.BundleError`.
* :func:`atlas_lookup` is the bilinear lookup of the spec ("UV to texel").
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import secrets
import shutil
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hbake import constants as C
from hbake.errors import BakeFailedError, BundleError, OutputExistsError, OutputUnwritableError
from hbake.bundle.exrheader import ExrHeaderError, check_exr_header
from hbake.fileio import FileTooLargeError, read_regular

__all__ = [
    "FORMAT_NAME", "FORMAT_VERSION", "FORMAT_MAJOR", "FILE_NAMES", "ERROR_CLASSES",
    "PIECES_TABLE_MINOR", "pieces_layout_is_table",
    "BundleData", "Bundle", "Problem",
    "write_bundle", "read_bundle", "validate_bundle", "check_bundle",
    "atlas_lookup", "texel_coords",
    "load_schema", "manifest_bytes", "sha256_file",
    "write_coarse_ply", "read_coarse_ply", "write_pieces_ply", "read_pieces_ply",
    "write_atlas_exr", "read_atlas_exr", "write_ply_mesh", "read_ply_mesh",
    "convexity_tolerance",
]

# --------------------------------------------------------------------------- constants

FORMAT_NAME = "hbundle"
#: The version hbake writes (with or without the optional "route" field of 1.2).
FORMAT_VERSION = "1.3"
FORMAT_MAJOR = 1
#: The first minor version whose pieces.ply keeps the piece -> coarse-triangle map in
#: fixed-size elements (``piece`` counts, ``piece_coarse_face`` rows) that MeshLab and
#: trimesh read; 1.0-1.2 kept one variable-length list per piece, which they do not.
PIECES_TABLE_MINOR = 3

#: Fixed file names inside a bundle (the manifest's ``files.*.path`` may name others).
FILE_NAMES = {"manifest": "manifest.json", "coarse_mesh": "coarse.ply",
              "atlas": "atlas.exr", "pieces": "pieces.ply"}

#: Error classes in the order in which validation reports them (docs/bundle-format.md).
ERROR_CLASSES = ("io", "version", "schema", "hash", "mesh", "atlas", "pieces")

#: Channels of the atlas, as the manifest lists them (sorted, as OpenEXR stores them).
ATLAS_CHANNELS = ["A", "B", "G", "R"]
ATLAS_COMPRESSIONS = ("zip", "piz")


# At most this many individual examples per kind of problem; the rest are counted.
_MAX_EXAMPLES = 3

#: manifest.json is refused past this size (hbake writes about 10 kB; the C++ loader's
#: limit, kMaxManifestBytes: 1 MiB of JSON is at most ~30 MB as its DOM) and this nesting
#: depth (hbake's deepest field is 4 levels down; Python's json, jsonschema and repr()
#: recurse once per level, so an unbounded depth ends in a RecursionError).
MAX_MANIFEST_BYTES = 1 << 20
MAX_JSON_DEPTH = 64
#: format_version is at most this many characters (the C++ loader's kMaxVersionChars).
MAX_VERSION_CHARS = 32
#: Size limits of the bundle's files, checked before a byte is read (the C++ loader's
#: kMaxPlyBytes and kMaxExrBytes: 1 GiB holds 28M coarse triangles; the atlas limit's
#: 256 MiB of float32 texels is stored in at most slightly more).
MAX_FILE_BYTES = {"coarse_mesh": 1 << 30, "atlas": 512 << 20, "pieces": 1 << 30}
#: Largest atlas side the manifest's schema fields accept (the C++ loader's
#: kMaxSchemaAtlasSide; the atlas limit proper, 8192, is class ``atlas``) and largest gutter.
MAX_SCHEMA_ATLAS_SIDE = 65536
MAX_GUTTER = 1 << 20

_COARSE_HEADER = (
    "ply\n"
    "format binary_little_endian 1.0\n"
    "comment hbundle coarse mesh 1.0\n"
    "element vertex {n}\n"
    "property float x\n"
    "property float y\n"
    "property float z\n"
    "element face {m}\n"
    "property list uchar uint vertex_indices\n"
    "property list uchar float texcoord\n"
    "end_header\n"
)
_PIECES_HEADER = (
    "ply\n"
    "format binary_little_endian 1.0\n"
    "comment hbundle pieces 1.3\n"
    "element vertex {n}\n"
    "property float x\n"
    "property float y\n"
    "property float z\n"
    "property uint piece\n"
    "element face {m}\n"
    "property list uchar uint vertex_indices\n"
    "property uint piece\n"
    "element piece {p}\n"
    "property uint coarse_face_count\n"
    "element piece_coarse_face {k}\n"
    "property uint coarse_face\n"
    "end_header\n"
)
#: pieces.ply of format 1.0-1.2 (read, never written): the map as one list per piece.
_PIECES_HEADER_LISTS = (
    "ply\n"
    "format binary_little_endian 1.0\n"
    "comment hbundle pieces 1.0\n"
    "element vertex {n}\n"
    "property float x\n"
    "property float y\n"
    "property float z\n"
    "property uint piece\n"
    "element face {m}\n"
    "property list uchar uint vertex_indices\n"
    "property uint piece\n"
    "element piece {p}\n"
    "property list uint uint coarse_faces\n"
    "end_header\n"
)

# Binary records (numpy structured dtypes are packed: no padding).
_XYZ = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
_COARSE_FACE = np.dtype([("n", "u1"), ("idx", "<u4", (3,)), ("nuv", "u1"), ("uv", "<f4", (6,))])
_PIECE_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("piece", "<u4")])
_PIECE_FACE = np.dtype([("n", "u1"), ("idx", "<u4", (3,)), ("piece", "<u4")])

_MAX_HEADER_BYTES = 4096


# --------------------------------------------------------------------------- data types

@dataclass
class BundleData:
    """Everything a bundle holds, in memory (see docs/bundle-format.md for units)."""

    coarse_vertices: np.ndarray       # (N, 3) float64, metres, object frame (stored as float32)
    coarse_faces: np.ndarray          # (M, 3) uint32, CCW seen from outside
    coarse_uvs: np.ndarray            # (M, 3, 2) float32, per-corner UVs in [0, 1], v up
    atlas: np.ndarray                 # (H, W, 4) float32, row 0 = top (first scanline); RGB position, A coverage
    piece_vertices: list[np.ndarray]  # per piece (k, 3) float64
    piece_faces: list[np.ndarray]     # per piece (f, 3) uint32, local indices, CCW outward
    piece_coarse_faces: list[np.ndarray]  # per piece, sorted unique uint32 coarse triangle ids
    manifest: dict                    # all fields but "format", "format_version", "files"


@dataclass
class Bundle(BundleData):
    """A bundle read from disk: :class:`BundleData` with the full manifest and its path."""

    path: Path = field(default_factory=Path)


@dataclass(frozen=True)
class Problem:
    """One problem found in a bundle: an error class of the spec and one line of text."""

    cls: str
    message: str

    def __str__(self) -> str:
        return f"{self.cls}: {self.message}"


class _Fail(Exception):
    """Internal: stop checking the current file (the problem is already recorded)."""


# --------------------------------------------------------------------------- small helpers

def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"manifest value of type {type(obj).__name__} is not JSON-serialisable")


def manifest_bytes(manifest: dict) -> bytes:
    """The canonical manifest encoding: UTF-8, sorted keys, 2-space indent, trailing newline.

    NaN and infinities are refused (they are not JSON)."""
    text = json.dumps(manifest, sort_keys=True, indent=2, ensure_ascii=False,
                      allow_nan=False, default=_json_default)
    return (text + "\n").encode("utf-8")


_SCHEMA_CACHE: dict | None = None


def load_schema() -> dict:
    """The manifest's JSON Schema (draft 2020-12), shipped in ``hbake/schema``."""
    global _SCHEMA_CACHE
    if _SCHEMA_CACHE is None:
        # Next to this module (package data, see pyproject.toml).
        text = (Path(__file__).resolve().parents[1] / "schema" / "manifest.schema.json").read_text("utf-8")
        _SCHEMA_CACHE = json.loads(text)
    return _SCHEMA_CACHE


def _atlas_size_ok(w: int, h: int) -> bool:
    """The shared atlas limit (docs/input-contract.md)."""
    return (1 <= w <= C.MAX_ATLAS_SIDE and 1 <= h <= C.MAX_ATLAS_SIDE
            and w * h <= C.MAX_ATLAS_TEXELS)


def convexity_tolerance(bbox_diagonal: float) -> float:
    """How far (m) a piece vertex may lie in front of a face plane of its piece."""
    return C.CONVEX_TOLERANCE_REL * float(bbox_diagonal) + C.CONVEX_TOLERANCE_ABS


def _bbox_diagonal(points: np.ndarray) -> float:
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        return 0.0
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


def _short(value: Any, limit: int = 60, quote: bool = True) -> str:
    """repr (or str) of a value from a file, cut to ``limit`` characters for a message."""
    text = repr(value) if quote else str(value)
    return text if len(text) <= limit else f"{text[:limit - 3]}... ({len(text):,} characters)"


def _json_depth(value: Any) -> int:
    """Nesting depth of parsed JSON (iterative: no recursion to overflow)."""
    depth, stack = 0, [(value, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = list(v.values())
        if isinstance(v, list):
            depth = max(depth, d)
            if d > MAX_JSON_DEPTH:
                return d
            stack.extend((x, d + 1) for x in v)
    return depth


def _too_large(e: FileTooLargeError) -> str:
    """The C++ loader's wording for a file over its size limit."""
    if e.size is None:
        return f"more than the limit of {e.limit} bytes for this file"
    return f"{e.size} bytes, more than the limit of {e.limit} bytes for this file"


def _has_lone_surrogate(value: Any) -> bool:
    """Whether a key or string of parsed JSON holds an unpaired UTF-16 surrogate (from a
    ``\\ud800`` escape; iterative)."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, dict):
            stack.extend(v.keys())
            stack.extend(v.values())
        elif isinstance(v, list):
            stack.extend(v)
        elif isinstance(v, str):
            try:
                v.encode("utf-8")
            except UnicodeEncodeError:
                return True
    return False


_INT64_MAX = (1 << 63) - 1
#: Integer fields as the C++ loader reads them (manifest.cpp, Checker::integer): int64,
#: or an integral double below 9e18; and the bounds it adds to the schema's.
_LOADER_INTEGERS = {
    ("source", "vertices"): None, ("source", "triangles"): None, ("source", "bodies"): None,
    ("seeds", "coacd"): None, ("seeds", "quality"): None,
    ("files", "coarse_mesh", "bytes"): None, ("files", "atlas", "bytes"): None,
    ("files", "pieces", "bytes"): None,
    ("files", "atlas", "width"): MAX_SCHEMA_ATLAS_SIDE, ("files", "atlas", "height"): MAX_SCHEMA_ATLAS_SIDE,
    ("coarse", "vertices"): None, ("coarse", "triangles"): None, ("pieces", "count"): None,
    ("atlas", "width"): MAX_SCHEMA_ATLAS_SIDE, ("atlas", "height"): MAX_SCHEMA_ATLAS_SIDE,
    ("atlas", "gutter"): MAX_GUTTER,
    ("quality", "reconstruction", "coarse_to_full", "samples"): None,
    ("quality", "reconstruction", "full_to_coarse", "samples"): None,
}
_SHA256 = re.compile(r"[0-9a-f]{64}")


def _loader_schema_rules(m: dict) -> list[tuple[str, str]]:
    """(path, message) for each rule of the C++ loader's manifest check that the JSON
    Schema does not state (runtime/src/io/manifest.cpp), for a schema-valid manifest:
    integers within int64 and its bounds on the atlas sides and gutter, SHA-256 digests of
    exactly 64 hex digits (the schema's ``$`` also matches before a final newline), file
    names without '..' or NUL, distinct file paths (none manifest.json)."""
    out = []
    for path, hi in _LOADER_INTEGERS.items():
        x = m
        for k in path:
            x = x[k]
        where = "/".join(path)
        if isinstance(x, float):
            if not abs(x) < 9.0e18:
                out.append((where, f"{x!r} is out of range"))
                continue
            x_int = int(x)
        else:
            if x < -(1 << 63) or x >= 1 << 64:      # a double for nlohmann-json
                out.append((where, f"{_short(x, 80)} is out of range"))
                continue
            x_int = x
        limit = _INT64_MAX if hi is None else hi
        if x_int > limit:
            out.append((where, f"{_short(x, 80)} is greater than the maximum of {limit}"))
    for where, v in [("source/sha256", m["source"]["sha256"])] + [
            (f"files/{k}/sha256", m["files"][k]["sha256"]) for k in ("coarse_mesh", "atlas", "pieces")]:
        if not _SHA256.fullmatch(v):
            out.append((where, f"{_short(v, 80)} does not match '^[0-9a-f]{{64}}$'"))
    for where, v in [("source/name", m["source"]["name"])] + [
            (f"files/{k}/path", m["files"][k]["path"]) for k in ("coarse_mesh", "atlas", "pieces")]:
        if v == ".":
            out.append((where, "'.' should not be valid under {'enum': ['.', '..']}"))
        elif ".." in v or "\0" in v:
            out.append((where, f"{_short(v, 80)} contains '..' (a file name inside the bundle is required)"))
    paths = [m["files"][k]["path"] for k in ("coarse_mesh", "atlas", "pieces")]
    if len(set(paths)) < 3 or FILE_NAMES["manifest"] in paths:
        out.append(("files", "two files have the same path (or one is manifest.json)"))
    return out


def _n(count: int, noun: str, plural: str | None = None) -> str:
    """'1 face', '3 faces'."""
    return f"{count} {noun if count == 1 else (plural or noun + 's')}"


def _examples(items: list, fmt) -> str:
    """'a; b; c (and 4 more)' for problem messages that would otherwise repeat."""
    shown = "; ".join(fmt(x) for x in items[:_MAX_EXAMPLES])
    if len(items) > _MAX_EXAMPLES:
        shown += f" (and {len(items) - _MAX_EXAMPLES} more)"
    return shown


# --------------------------------------------------------------------------- UV <-> texel

def texel_coords(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """Continuous texel coordinates (x, y) of UVs: x = u W - 0.5, y = (1 - v) H - 0.5.

    Texel centres are at integer (x, y); row 0 (y = 0) is the first stored scanline,
    the top of the image, since v points up."""
    uv = np.asarray(uv, dtype=np.float64)
    x = uv[..., 0] * width - 0.5
    y = (1.0 - uv[..., 1]) * height - 0.5
    return np.stack([x, y], axis=-1)


def atlas_lookup(atlas: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of all channels at UVs, by the spec's convention.

    ``atlas`` is (H, W, C) with row 0 the top; ``uv`` is (K, 2) (or (2,)).
    Returns (K, C) float64 (or (C,)). The four texels are clamped to the image."""
    atlas = np.asarray(atlas)
    if atlas.ndim != 3:
        raise ValueError(f"atlas must be (H, W, C), got shape {atlas.shape}")
    h, w = atlas.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    single = uv.ndim == 1
    uv = uv.reshape(-1, 2)
    xy = texel_coords(uv, w, h)
    x0f = np.floor(xy[:, 0])
    y0f = np.floor(xy[:, 1])
    fx = (xy[:, 0] - x0f)[:, None]
    fy = (xy[:, 1] - y0f)[:, None]
    x0 = x0f.astype(np.int64)
    y0 = y0f.astype(np.int64)
    i0 = np.clip(x0, 0, w - 1)
    i1 = np.clip(x0 + 1, 0, w - 1)
    j0 = np.clip(y0, 0, h - 1)
    j1 = np.clip(y0 + 1, 0, h - 1)
    a = atlas.astype(np.float64, copy=False)
    out = ((1 - fx) * (1 - fy) * a[j0, i0] + fx * (1 - fy) * a[j0, i1]
           + (1 - fx) * fy * a[j1, i0] + fx * fy * a[j1, i1])
    return out[0] if single else out


# Work bound of the atlas's per-triangle checks (the C++ loader's, docs/input-contract.md):
# rows and candidate texels examined, at most this many per texel of the atlas plus per
# triangle. Non-overlapping UV charts need 1.2-3.2 W H; overlapping copies or slivers
# across the atlas, which no baker writes, are refused before they cost W H each.
_WORK_PER_TEXEL = 16
_WORK_PER_TRIANGLE = 64
# Widening (texels) of the per-row candidate spans, far above their rounding.
_SPAN_PAD = 1e-6
# The loader's coverage-check margin (texels): see _coverage_check.
_COVERAGE_MARGIN = 1e-3
# Batch sizes of the vectorized footprint passes (rows, candidate texels).
_ROW_BATCH = 1 << 16
_TEXEL_BATCH = 1 << 18


def _work_limit(width: int, height: int, triangles: int) -> int:
    return _WORK_PER_TEXEL * width * height + _WORK_PER_TRIANGLE * triangles


def _work_problem(name: str, limit: int) -> str:
    return (f"{name}: the UV triangles need more than {limit} texel tests ({_WORK_PER_TEXEL} per "
            f"texel of the atlas + {_WORK_PER_TRIANGLE} per triangle): UV triangles overlap or are "
            "slivers across the atlas")


def _int_clip(x: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Integer-valued floats to int64, clipped to [lo, hi] first (no overflow)."""
    return np.clip(x, lo, hi).astype(np.int64)


def _batches(counts: np.ndarray, size: int):
    """Consecutive index ranges [a, b) of ``counts`` with at most ``size`` in all (or one
    item, if it alone is larger)."""
    ends = np.cumsum(counts)
    a, n = 0, len(counts)
    while a < n:
        base = ends[a - 1] if a else 0
        b = int(np.searchsorted(ends, base + size, side="right"))
        b = max(b, a + 1)
        yield a, b
        a = b


def _expand(starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, value): for each k, counts[k] entries owner k with values starts[k] + 0, 1, ..."""
    owner = np.repeat(np.arange(len(counts)), counts)
    first = np.cumsum(counts) - counts
    return owner, starts[owner] + (np.arange(len(owner)) - first[owner])


class _Footprints:
    """The footprint test of _footprint_texels for a batch of UV triangles (T, 3, 2).

    A point at texel coordinates (x, y) reads texels floor(x) + {0, 1} by floor(y) + {0, 1}
    (clamped), so texel (i, j) is read iff the triangle meets the square
    [i-1, i+1] x [j-1, j+1] (closed: conservative at exact ties): the separating-axis test
    on the two box axes and the three edge normals. Per row, only the x-span of the
    triangle within the band [j-1, j+1] (plus one texel each side) is examined, as the C++
    loader does (runtime/src/io/bundle.cpp, footprint()); that is a superset of the
    texels the test keeps, so the result is that of examining the whole bounding box."""

    def __init__(self, uv_tris: np.ndarray, width: int, height: int):
        self.w, self.h = width, height
        p = texel_coords(uv_tris, width, height)  # (T, 3, 2)
        self.px, self.py = np.ascontiguousarray(p[:, :, 0]), np.ascontiguousarray(p[:, :, 1])
        self.xmin, self.xmax = self.px.min(axis=1), self.px.max(axis=1)
        self.ymin, self.ymax = self.py.min(axis=1), self.py.max(axis=1)
        # candidate range bounded by the image (plus one): beyond it lookups clamp
        self.i0 = _int_clip(np.floor(self.xmin) - 1, -1, width + 1)
        self.i1 = _int_clip(np.ceil(self.xmax) + 1, -2, width)
        j0 = _int_clip(np.floor(self.ymin) - 1, -1, height + 1)
        j1 = _int_clip(np.ceil(self.ymax) + 1, -2, height)
        # rows that pass the y box axis: ymin - 1 <= j <= ymax + 1
        self.row0 = np.maximum(j0, _int_clip(np.ceil(self.ymin - 1), -2, height + 2))
        row1 = np.minimum(j1, _int_clip(np.floor(self.ymax + 1), -2, height + 2))
        self.rows = np.maximum(row1 - self.row0 + 1, 0)
        # edge normals n_k = (b_y - a_y, a_x - b_x) of edge a = p_k -> b = p_{k+1}, and the
        # triangle's extent along each; the projections are p @ n as a (3, 2) @ (2,)
        # product, the same BLAS call (and rounding) as one triangle at a time
        q = np.roll(p, -1, axis=1)
        self.nx = np.ascontiguousarray(q[:, :, 1] - p[:, :, 1])
        self.ny = np.ascontiguousarray(p[:, :, 0] - q[:, :, 0])
        self.tmin = np.zeros_like(self.nx)
        self.tmax = np.zeros_like(self.nx)
        for k in range(3):
            n = np.ascontiguousarray(np.stack([self.nx[:, k], self.ny[:, k]], axis=-1))[:, :, None]
            proj = np.matmul(p, n)[:, :, 0]
            self.tmin[:, k], self.tmax[:, k] = proj.min(axis=1), proj.max(axis=1)
        self.r = np.abs(self.nx) + np.abs(self.ny)

    def row_batches(self):
        return _batches(self.rows, _ROW_BATCH)

    def spans(self, a: int, b: int):
        """Rows of triangles a..b-1: (triangle, j, first candidate i, candidate count)."""
        tri, j = _expand(self.row0[a:b], self.rows[a:b])
        tri += a
        jf = j.astype(np.float64)
        ylo, yhi = jf - 1 - _SPAN_PAD, jf + 1 + _SPAN_PAD
        xa = np.full(len(j), np.inf)
        xb = np.full(len(j), -np.inf)
        px, py = self.px[tri], self.py[tri]
        with np.errstate(invalid="ignore", divide="ignore"):
            for k in range(3):
                k1 = (k + 1) % 3
                inside = (py[:, k] >= ylo) & (py[:, k] <= yhi)
                xa = np.where(inside, np.minimum(xa, px[:, k]), xa)
                xb = np.where(inside, np.maximum(xb, px[:, k]), xb)
                dy = py[:, k1] - py[:, k]
                for yl in (ylo, yhi):
                    cross = ((py[:, k] - yl) * (py[:, k1] - yl) <= 0) & (dy != 0)
                    x = px[:, k] + (yl - py[:, k]) / dy * (px[:, k1] - px[:, k])
                    xa = np.where(cross, np.minimum(xa, x), xa)
                    xb = np.where(cross, np.maximum(xb, x), xb)
        ok = xa <= xb
        w = self.w
        ia = np.maximum(self.i0[tri], _int_clip(np.floor(np.where(ok, xa, 0) - 1 - _SPAN_PAD) - 1, -3, w + 3))
        ib = np.minimum(self.i1[tri], _int_clip(np.ceil(np.where(ok, xb, 0) + 1 + _SPAN_PAD) + 1, -3, w + 3))
        count = np.where(ok, np.maximum(ib - ia + 1, 0), 0)
        return tri, j, ia, count

    def texels(self, tri: np.ndarray, j: np.ndarray, ia: np.ndarray, count: np.ndarray):
        """The texels the rows' candidates read: (triangle, i, j) clamped to the image, in
        the order of the rows and by i (the order of the bounding-box scan)."""
        row, ci = _expand(ia, count)
        # per-row terms, then one gather per term; centre = i n_x + j n_y as before
        keep = (ci >= (self.xmin[tri] - 1)[row]) & (ci <= (self.xmax[tri] + 1)[row])
        cf = ci.astype(np.float64)
        for k in range(3):
            nx, r = self.nx[tri, k], self.r[tri, k]
            centre = cf * nx[row]
            centre += (j * self.ny[tri, k])[row]
            keep &= (centre + r[row] >= self.tmin[tri, k][row])
            keep &= (centre - r[row] <= self.tmax[tri, k][row])
        row = row[keep]
        return (tri[row], np.clip(ci[keep], 0, self.w - 1), np.clip(j[row], 0, self.h - 1))

    def visit(self):
        """All texels read, in batches: yields (triangle, i, j) arrays in triangle order."""
        for a, b in self.row_batches():
            tri, j, ia, count = self.spans(a, b)
            for c, d in _batches(count, _TEXEL_BATCH):
                yield self.texels(tri[c:d], j[c:d], ia[c:d], count[c:d])


def _coverage_check(uv_tris: np.ndarray, width: int, height: int, alpha: np.ndarray | None,
                    budget: int):
    """The C++ loader's coverage check (runtime/src/io/bundle.cpp, check_atlas_texels): a
    texel whose centre lies more than _COVERAGE_MARGIN texels inside a UV triangle must have
    A = 1, and a texel with A = 1 must have its centre inside some UV triangle or within the
    margin of one (centres within the margin of an edge may go either way: the stored UVs
    are float32 and the writer may rasterise the unrounded ones).

    Examines per row only the candidate centres that each edge's signed distance allows, and
    counts the rows and candidates as the loader does; stops once the count is past
    ``budget``. Returns (work, first, near): ``first`` = (triangle of ``uv_tris``, i, j) of
    the first texel inside a triangle without A = 1 in the loader's order (by triangle, row,
    column), else None; ``near`` the (H, W) mask of centres inside or within the margin of
    some triangle. ``alpha`` None: count the work only."""
    px = uv_tris[:, :, 0].astype(np.float64) * width
    py = (1.0 - uv_tris[:, :, 1].astype(np.float64)) * height
    area2 = (px[:, 1] - px[:, 0]) * (py[:, 2] - py[:, 0]) - (px[:, 2] - px[:, 0]) * (py[:, 1] - py[:, 0])
    keep = np.flatnonzero(area2 != 0)
    px, py, area2 = px[keep], py[keep], area2[keep]
    m = _COVERAGE_MARGIN
    i0 = _int_clip(np.ceil(px.min(axis=1) - m - 0.5), 0, width)
    i1 = _int_clip(np.floor(px.max(axis=1) + m - 0.5), -1, width - 1)
    j0 = _int_clip(np.ceil(py.min(axis=1) - m - 0.5), 0, height)
    j1 = _int_clip(np.floor(py.max(axis=1) + m - 0.5), -1, height - 1)
    rows = np.maximum(j1 - j0 + 1, 0)
    work = int(rows.sum())
    near = None if alpha is None else np.zeros((height, width), dtype=bool)
    first = None
    if work > budget:
        return work, first, near
    sgn = np.where(area2 > 0, 1.0, -1.0)
    ex = np.roll(px, -1, axis=1) - px
    ey = np.roll(py, -1, axis=1) - py
    el = np.hypot(ex, ey)
    for a, b in _batches(rows, _ROW_BATCH):
        t, j = _expand(j0[a:b], rows[a:b])
        t += a
        cy = j + 0.5
        lo = i0[t] + 0.5
        hi = i1[t] + 0.5
        s = sgn[t]
        with np.errstate(invalid="ignore", divide="ignore"):
            for k in range(3):
                av = -s * ey[t, k]
                bv = -m * el[t, k] - s * ex[t, k] * (cy - py[t, k])
                x = px[t, k] + bv / av
                lo = np.where(av > 0, np.maximum(lo, x - _SPAN_PAD), lo)
                hi = np.where(av < 0, np.minimum(hi, x + _SPAN_PAD), hi)
                hi = np.where((av == 0) & (bv > _SPAN_PAD * el[t, k]), lo - 1, hi)
        ok = lo <= hi
        ia = np.maximum(i0[t], _int_clip(np.ceil(np.where(ok, lo, 0) - 0.5), -1, width + 1))
        ib = np.minimum(i1[t], _int_clip(np.floor(np.where(ok, hi, 0) - 0.5), -1, width + 1))
        count = np.where(ok, np.maximum(ib - ia + 1, 0), 0)
        work += int(count.sum())
        if work > budget:
            break
        if alpha is None:
            continue
        for c, d in _batches(count, _TEXEL_BATCH):
            row, ci = _expand(ia[c:d], count[c:d])
            tt, jj = t[c:d][row], j[c:d][row]
            cx = ci + 0.5
            cyy = jj + 0.5
            dist = np.full(len(ci), np.inf)
            for k in range(3):
                dk = s[c:d][row] * (ex[tt, k] * (cyy - py[tt, k]) - ey[tt, k] * (cx - px[tt, k])) / el[tt, k]
                dist = np.minimum(dist, dk)
            inside = dist >= -m
            near[jj[inside], ci[inside]] = True
            if first is None:
                bad = np.flatnonzero((dist > m) & (alpha[jj, ci] != 1))
                if len(bad):
                    q = bad[0]
                    first = (int(keep[tt[q]]), int(ci[q]), int(jj[q]))
        if first is not None:
            break
    return work, first, near


def _coverage_work(uv_tris: np.ndarray, width: int, height: int, budget: int) -> int:
    """Rows and candidate texels that the C++ loader's coverage check examines, counted as
    it does (see _coverage_check); stops counting once past ``budget``."""
    return _coverage_check(uv_tris, width, height, None, budget)[0]


def _footprint_texels(uv_tri: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Texels (i, j) that a bilinear lookup at some point of a UV triangle reads.

    A point at texel coordinates (x, y) reads texels floor(x) + {0, 1} by
    floor(y) + {0, 1} (clamped), so texel (i, j) is read iff the triangle meets the
    square [i-1, i+1] x [j-1, j+1] (closed: conservative at exact ties); see
    _Footprints, which tests many triangles at once."""
    fp = _Footprints(np.asarray(uv_tri, dtype=np.float64).reshape(1, 3, 2), width, height)
    parts = list(fp.visit())
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])


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


# --------------------------------------------------------------------------- EXR

def _exr():
    import OpenEXR  # imported lazily: the CLI's --help should not pay for it
    return OpenEXR


def _open_exr(path: Path, header_only: bool):
    """OpenEXR.File(path) with the library's own chatter captured, not printed.

    The binding reports undecodable pixel data by printing a warning (to Python's
    stdout) and the C library's messages (to fd 2), then returns a File with no
    parts; a validator must instead turn that into one problem line. Returns
    (file or None, exception text or captured messages)."""
    import contextlib
    import io
    import tempfile

    ex = _exr()
    py_out = io.StringIO()
    with tempfile.TemporaryFile(mode="w+b") as err:
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError):
            pass
        saved = os.dup(2)
        try:
            os.dup2(err.fileno(), 2)
            with contextlib.redirect_stdout(py_out):
                try:
                    f = ex.File(str(path), separate_channels=True, header_only=header_only)
                    exc = None
                except Exception as e:  # the binding raises bare RuntimeError / KeyError
                    f, exc = None, e
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        err.seek(0)
        c_msgs = err.read().decode("utf-8", "replace")
    lines = [ln.strip() for ln in (str(exc) if exc else "").splitlines() + c_msgs.splitlines()
             + py_out.getvalue().splitlines() if ln.strip()]
    # drop the file name that the C library prefixes to its messages
    lines = [ln.split(": ", 1)[1] if ln.startswith(str(path) + ": ") else ln for ln in lines]
    return f, (lines[0] if lines else "")


def _compression_enum(name: str):
    ex = _exr()
    table = {"zip": ex.ZIP_COMPRESSION, "piz": ex.PIZ_COMPRESSION}
    if name not in table:
        raise ValueError(f"atlas compression must be one of {sorted(table)}, not {name!r}")
    return table[name]


def _compression_name(value) -> str:
    # Compression.ZIP_COMPRESSION -> "zip"; ZIPS_COMPRESSION -> "zips" (invalid in bundles)
    return str(getattr(value, "name", value)).removesuffix("_COMPRESSION").lower()


def write_atlas_exr(path: str | os.PathLike, atlas: np.ndarray, compression: str = "zip",
                    channels: tuple[str, ...] = ("R", "G", "B", "A")) -> None:
    """Write the atlas as a single-part scanline EXR with FLOAT channels.

    ``atlas`` is (H, W, len(channels)) float32, row 0 = first scanline. The data and
    display windows are (0,0)-(W-1,H-1); the header carries no time stamp."""
    ex = _exr()
    a = np.asarray(atlas, dtype=np.float32)
    if a.ndim != 3 or a.shape[2] != len(channels):
        raise ValueError(f"atlas must be (H, W, {len(channels)}), got {a.shape}")
    header = {"compression": _compression_enum(compression), "type": ex.scanlineimage}
    # A fresh dict each time: OpenEXR.File replaces its values by Channel objects.
    pixels = {c: np.ascontiguousarray(a[:, :, k]) for k, c in enumerate(channels)}
    try:
        ex.File(header, pixels).write(str(path))
    except RuntimeError as e:
        # The OpenEXR binding reports a failed write (a full disk, a quota, an I/O
        # error) as RuntimeError with the system's message in its text; the writers'
        # callers turn OSError into the one "cannot write" exit. Anything else (a bad
        # header) stays what it is.
        text = str(e)
        for code in (errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EROFS, errno.EFBIG):
            if os.strerror(code) in text:
                raise OSError(code, os.strerror(code), str(path)) from None
        if "Failed to write" in text or "Cannot open" in text:
            raise OSError(errno.EIO, text, str(path)) from None
        raise


def read_atlas_exr(path: str | os.PathLike) -> np.ndarray:
    """The atlas as (H, W, 4) float32 RGBA; raises BundleError('atlas') if not readable."""
    f, why = _open_exr(Path(path), header_only=False)
    try:
        ch = f.parts[0].channels
        return np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in "RGBA"], axis=-1)
    except Exception as e:  # no parts (undecodable), a missing channel, ...
        raise BundleError("atlas", f"{Path(path).name}: cannot read the atlas: {why or e}") from None


# --------------------------------------------------------------------------- writing

def _check_data(data: BundleData) -> None:
    """Programming errors in the BundleData (not user errors): shapes and types."""
    v = np.asarray(data.coarse_vertices)
    f = np.asarray(data.coarse_faces)
    uv = np.asarray(data.coarse_uvs)
    a = np.asarray(data.atlas)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"coarse_vertices must be (N, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"coarse_faces must be (M, 3), got {f.shape}")
    if uv.shape != (len(f), 3, 2):
        raise ValueError(f"coarse_uvs must be ({len(f)}, 3, 2), got {uv.shape}")
    if a.ndim != 3 or a.shape[2] != 4:
        raise ValueError(f"atlas must be (H, W, 4), got {a.shape}")
    if not isinstance(data.manifest, dict):
        raise ValueError("manifest must be a dict")
    for key in ("format", "format_version", "files"):
        if key in data.manifest:
            raise ValueError(f"manifest must not contain {key!r}: write_bundle fills it in")


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _write_files(tmp: Path, data: BundleData, compression: str) -> dict:
    names = FILE_NAMES
    write_coarse_ply(tmp / names["coarse_mesh"], data.coarse_vertices, data.coarse_faces, data.coarse_uvs)
    write_atlas_exr(tmp / names["atlas"], data.atlas, compression)
    write_pieces_ply(tmp / names["pieces"], data.piece_vertices, data.piece_faces, data.piece_coarse_faces)
    h, w = np.asarray(data.atlas).shape[:2]
    files: dict[str, dict] = {}
    for key in ("coarse_mesh", "atlas", "pieces"):
        p = tmp / names[key]
        files[key] = {"path": names[key], "sha256": sha256_file(p), "bytes": p.stat().st_size}
    files["atlas"].update(width=int(w), height=int(h), channels=list(ATLAS_CHANNELS),
                          pixel_type="float", compression=compression)
    manifest = dict(data.manifest)
    # 1.3 (pieces.ply's map in fixed-size elements), with or without 1.2's optional "route"
    manifest.update(format=FORMAT_NAME, format_version=FORMAT_VERSION, files=files)
    blob = manifest_bytes(manifest)
    (tmp / names["manifest"]).write_bytes(blob)
    for key in names.values():
        with open(tmp / key, "rb+") as fh:
            os.fsync(fh.fileno())
    _fsync_dir(tmp)
    return json.loads(blob)


def _looks_like_bundle(path: Path) -> bool:
    try:
        return path.is_dir() and (not any(path.iterdir()) or (path / FILE_NAMES["manifest"]).is_file())
    except OSError:
        return False


#: ``.NAME.<pid>.<8 hex>.tmp`` (a bundle being written) and ``.old`` (one being replaced).
_TEMP_NAME = re.compile(r"\.(?P<name>.+)\.(?P<pid>[0-9]{1,10})\.[0-9a-f]{8}\.(?P<kind>tmp|old)")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:           # EPERM: it exists
        return True
    return True


def remove_stale_temporaries(path: str | os.PathLike) -> list[str]:
    """Remove the temporary siblings of the bundle ``path`` that write_bundle left in a
    process that no longer runs (killed with SIGKILL, a crash, a power cut); put back a
    bundle that such a process had moved aside to replace it. Temporaries of running
    processes are left alone. Returns one message per thing done, for warnings."""
    out = Path(os.path.abspath(os.fspath(path)))
    done: list[str] = []
    try:
        entries = [e for e in out.parent.iterdir() if e.name.startswith(f".{out.name}.")]
    except OSError:
        return done
    for entry in sorted(entries):
        m = _TEMP_NAME.fullmatch(entry.name)
        if m is None or m["name"] != out.name:
            continue
        pid = int(m["pid"])
        if pid == os.getpid() or _pid_alive(pid):
            continue
        try:
            if m["kind"] == "old" and not (out.exists() or out.is_symlink()):
                os.rename(entry, out)
                done.append(f"restored {out.name} from {entry.name}, moved aside by an earlier "
                            f"bake (process {pid}) that did not finish")
                continue
            shutil.rmtree(entry)
            done.append(f"removed {entry.name}, left by an earlier bake (process {pid}) "
                        "that did not finish")
        except OSError as e:
            done.append(f"cannot remove {entry.name}, left by an earlier bake (process {pid}): "
                        f"{e.strerror}")
    return done


def write_bundle(path: str | os.PathLike, data: BundleData, *, force: bool = False,
                 compression: str = "zip") -> dict:
    """Write ``data`` as a bundle directory at ``path``; return the final manifest.

    Atomic: the files go to a temporary sibling directory (same parent, name starting
    with '.'), which is validated with :func:`validate_bundle` and then renamed onto
    ``path``; on any exception, KeyboardInterrupt included, the temporary directory is
    removed and an existing bundle is left as it was. With ``force`` an existing
    bundle (a directory holding ``manifest.json``, or an empty directory) is replaced
    only once the new one is complete. Byte-deterministic: the same data give the
    same bytes. Raises OutputExistsError, OutputUnwritableError, or BakeFailedError
    when the data would make an invalid bundle."""
    _check_data(data)
    compression = str(compression).lower()
    _compression_enum(compression)  # ValueError for anything but zip / piz
    out = Path(os.path.abspath(os.fspath(path)))
    parent = out.parent
    if not parent.exists():
        raise OutputUnwritableError(f"output directory {parent} does not exist")
    if not parent.is_dir():
        raise OutputUnwritableError(f"cannot create {out}: {parent} is not a directory")
    if out.exists() or out.is_symlink():
        if not force:
            raise OutputExistsError(f"{out} already exists (use --force to replace it)")
        if out.is_symlink() or not _looks_like_bundle(out):
            raise OutputExistsError(f"refusing to replace {out}: it is not a bundle directory")

    tmp = None
    for _ in range(100):
        cand = parent / f".{out.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
        try:
            os.mkdir(cand)  # honours the umask, unlike tempfile.mkdtemp's 0700
            tmp = cand
            break
        except FileExistsError:
            continue
        except OSError as e:
            raise OutputUnwritableError(f"cannot write to {parent}: {e.strerror}") from None
    if tmp is None:
        raise OutputUnwritableError(f"cannot create a temporary directory in {parent}")

    old = None
    try:
        try:
            manifest = _write_files(tmp, data, compression)
        except OSError as e:
            # Named by the output (the temporary directory is gone by the time it is read).
            what = f" ({Path(e.filename).name})" if e.filename else ""
            raise OutputUnwritableError(f"cannot write {out}{what}: {e.strerror}") from None
        problems = validate_bundle(tmp)
        if problems:
            raise BakeFailedError(f"the bundle for {out.name} would be invalid: {problems[0].cls}: "
                                  f"{problems[0].message}"
                                  + (f" (and {len(problems) - 1} more problems)" if len(problems) > 1 else ""))
        try:
            if out.exists() or out.is_symlink():
                old = parent / f".{out.name}.{os.getpid()}.{secrets.token_hex(4)}.old"
                os.rename(out, old)
            os.rename(tmp, out)
        except OSError as e:
            if old is not None and not out.exists():
                os.rename(old, out)
                old = None
            if e.errno in (errno.ENOTEMPTY, errno.EEXIST):  # someone created it meanwhile
                raise OutputExistsError(f"{out} already exists (use --force to replace it)") from None
            raise OutputUnwritableError(f"cannot rename the bundle into {out}: {e.strerror}") from None
        tmp = None
        _fsync_dir(parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
            old = None
        return manifest
    except BaseException:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and not out.exists():
            try:
                os.rename(old, out)
            except OSError:
                pass
        raise


#: Most vertices of one convex piece (docs/input-contract.md, shared with the runtime):
#: the convexity test is vertices x faces per piece, so this bounds it at 1024 plane
#: tests per face, linear in the file.
MAX_PIECE_VERTICES = 1024
#: Most faces of one convex piece (the C++ loader's kMaxPieceFaces): a closed convex
#: triangulated polyhedron of V vertices has 2 V - 4 faces.
MAX_PIECE_FACES = 2 * MAX_PIECE_VERTICES - 4
#: Plane tests per batch of the convexity check: the (faces x vertices) distance
#: matrices of a batch take 8 bytes per test, twice (8 MiB x 2 at 2^20).
_CONVEX_BATCH = 1 << 20
#: Faces per chunk of pieces checked together (bounded temporaries, ~100 bytes a face).
_CHUNK_FACES = 1 << 17


def _piece_invariants(v, f, vp, fp, vstart, fstart, check, tol):
    """Closedness, zero-area faces, orientation and convexity of the pieces selected by
    ``check`` (a mask over pieces), with time and memory linear in the file.

    Each piece gets the first failing check of: closed and consistently wound; no
    zero-area face; positive volume; convex within ``tol``. Returns the lists
    (open, degenerate, inward, nonconvex) for the messages of check_pieces."""
    p = len(vstart) - 1
    fsel = np.flatnonzero(check[fp])
    open_mask = np.zeros(p, dtype=bool)
    ff = f[fsel].astype(np.int64)
    fpp = fp[fsel].astype(np.int64)
    # closed: every directed edge once and its reverse once (global indices are fine: a
    # face only uses vertices of its own piece, checked before)
    n = np.uint64(len(v))
    src = ff.ravel().astype(np.uint64)
    dst = ff[:, [1, 2, 0]].ravel().astype(np.uint64)
    key = np.sort(src * n + dst)
    dup = np.flatnonzero(key[1:] == key[:-1])
    open_mask[vp[(key[dup] // n).astype(np.int64)]] = True
    rkey = dst * n + src
    pos = np.minimum(np.searchsorted(key, rkey), max(len(key) - 1, 0))
    missing = key[pos] != rkey if len(key) else np.zeros(0, dtype=bool)
    open_mask[vp[src[missing].astype(np.int64)]] = True
    open_ = [int(k) for k in np.flatnonzero(open_mask & check)]
    # zero-area faces, then orientation, for the closed pieces
    alive = check & ~open_mask
    keep = alive[fpp]
    ff, fpp, fsel = ff[keep], fpp[keep], fsel[keep]
    a, b, c = v[ff[:, 0]], v[ff[:, 1]], v[ff[:, 2]]
    ln = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    zero = ln == 0
    degen = []
    if zero.any():
        first = {}
        for gi, k in zip(fsel[zero].tolist(), fpp[zero].tolist()):
            first.setdefault(k, gi - int(fstart[k]))
        degen = sorted(first.items())
        alive[list(first)] = False
    nvp = np.diff(vstart).astype(np.float64)
    ctr = np.stack([np.bincount(vp, weights=v[:, i], minlength=p) for i in range(3)], axis=1)
    ctr /= np.maximum(nvp, 1)[:, None]
    cf = ctr[fpp]
    vol_f = np.einsum("ij,ij->i", a - cf, np.cross(b - cf, c - cf)) / 6.0
    vol = np.bincount(fpp, weights=vol_f, minlength=p)
    inward_mask = alive & (vol <= 0)
    inward = [(int(k), float(vol[k])) for k in np.flatnonzero(inward_mask)]
    alive &= ~inward_mask
    nonconvex = _convexity(v, f, vstart, fstart, np.flatnonzero(alive), tol)
    return open_, degen, inward, nonconvex


def _convexity(v, f, vstart, fstart, pieces, tol):
    """(piece, worst distance, local face, local vertex) of every piece with a vertex more
    than ``tol`` in front of one of its face planes.

    Every vertex of a piece is tested against every face plane of it. Pieces are batched
    by size (vertex and face counts rounded up to powers of two, padded with copies of
    their last vertex and face, which change no maximum), so many small pieces cost a
    few numpy calls rather than one each, and every batch holds at most _CONVEX_BATCH
    tests. Positions are taken relative to the piece's first vertex, as exact as
    n . (x - a) per pair."""
    out = []
    if len(pieces) == 0:
        return out
    nv = (vstart[pieces + 1] - vstart[pieces]).astype(np.int64)
    nf = (fstart[pieces + 1] - fstart[pieces]).astype(np.int64)
    pv_pad = 1 << np.ceil(np.log2(nv)).astype(np.int64)
    pf_pad = 1 << np.ceil(np.log2(nf)).astype(np.int64)
    buckets: dict[tuple[int, int], list[int]] = {}
    for i, (a, b) in enumerate(zip(pv_pad.tolist(), pf_pad.tolist())):
        buckets.setdefault((a, b), []).append(i)
    for (vpad, fpad), members in sorted(buckets.items()):
        members = np.asarray(members)
        if vpad * fpad > _CONVEX_BATCH:      # one big piece: face chunks, no padding
            for i in members.tolist():
                res = _convex_one(v, f, int(pieces[i]), vstart, fstart, tol)
                if res is not None:
                    out.append(res)
            continue
        per = max(1, _CONVEX_BATCH // (vpad * fpad))
        for s in range(0, len(members), per):
            idx = members[s:s + per]
            ks = pieces[idx]
            vi = vstart[ks][:, None] + np.minimum(np.arange(vpad)[None, :], nv[idx][:, None] - 1)
            fi = fstart[ks][:, None] + np.minimum(np.arange(fpad)[None, :], nf[idx][:, None] - 1)
            ref = v[vstart[ks]][:, None, :]
            pts = v[vi] - ref                                    # (B, vpad, 3)
            tri = v[f[fi].astype(np.int64)] - ref[:, None, :, :]  # (B, fpad, 3, 3)
            nrm = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
            nrm /= np.linalg.norm(nrm, axis=2, keepdims=True)
            off = np.einsum("bfk,bfk->bf", nrm, tri[:, :, 0])
            dist = np.matmul(nrm, pts.transpose(0, 2, 1))        # (B, fpad, vpad)
            dist -= off[:, :, None]
            flat = dist.reshape(len(idx), -1)
            arg = flat.argmax(axis=1)
            worst = flat[np.arange(len(idx)), arg]
            for j in np.flatnonzero(worst > tol).tolist():
                fj, vj = divmod(int(arg[j]), vpad)
                out.append((int(ks[j]), float(worst[j]), fj, vj))
    out.sort()
    return out


# Rows per product in _rows_max: 32 x 4 x 1024 multiply-adds stay below OpenBLAS's
# threshold for starting threads (65,536 x 4).
_GEMM_ROWS = 32


def _rows_max(plane: np.ndarray, pts4: np.ndarray) -> np.ndarray:
    """``(plane @ pts4).max(axis=1)`` as a stack of products of _GEMM_ROWS rows each, one
    numpy call. OpenBLAS runs each small product on one thread, where one big product
    started its threads for a few microseconds of work: 200 pieces of 1024 vertices took
    2.4-7 s on a loaded 2-core box instead of 0.15 s (the float32 pass's error bound
    covers any order of its 4-term sums, so the verdict does not depend on this)."""
    n = len(plane)
    m = -(-n // _GEMM_ROWS) * _GEMM_ROWS
    if m != n:
        plane = np.concatenate([plane, np.repeat(plane[-1:], m - n, axis=0)])
    stacked = np.matmul(plane.reshape(-1, _GEMM_ROWS, plane.shape[1]), pts4)
    return stacked.max(axis=2).reshape(-1)[:n]


def _convex_one(v, f, k, vstart, fstart, tol):
    pv = v[vstart[k]:vstart[k + 1]]
    ref = 0.5 * (pv.min(axis=0) + pv.max(axis=0))
    pts = pv - ref
    pf = f[fstart[k]:fstart[k + 1]].astype(np.int64)
    # A float32 pass (one matrix product with the plane offset folded in, half the
    # memory traffic of float64) finds the faces that may fail; only those are redone
    # in float64, so the verdict is the float64 one. Its error is below
    # bound = 16 u ext (u = 2^-24: rounding of the inputs and of a 4-term dot product,
    # positions taken from the piece's centre); when 2 bound < tol, a face that fails
    # in float64 has a float32 maximum above tol - bound, and a face whose vertices lie
    # on or behind its plane does not.
    ext = float(np.abs(pts).max())
    bound = 16 * ext * 2.0 ** -24
    exact32 = 2 * bound < tol
    margin = bound
    pts4 = np.hstack([pts, np.ones((len(pts), 1))]).astype(np.float32).T.copy()
    chunk = max(1, _CONVEX_BATCH // len(pv))
    best = (-np.inf, 0, 0)
    for s in range(0, len(pf), chunk):
        tri = v[pf[s:s + chunk]] - ref
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        off = np.einsum("fk,fk->f", nrm, tri[:, 0])
        if exact32:
            plane = np.hstack([nrm, -off[:, None]]).astype(np.float32)
            rough = _rows_max(plane, pts4)
            sel = np.flatnonzero(rough > tol - margin)
            if len(sel) == 0:
                continue
        else:
            sel = np.arange(len(nrm))
        dist = nrm[sel] @ pts.T
        dist -= off[sel][:, None]
        a = int(np.argmax(dist))
        fi, vi = divmod(a, len(pv))
        if dist[fi, vi] > best[0]:
            best = (float(dist[fi, vi]), s + int(sel[fi]), vi)
    return (k, best[0], best[1], best[2]) if best[0] > tol else None


# --------------------------------------------------------------------------- reading and validation

class _Checker:
    """Reads a bundle and records every problem it finds (one Problem per issue)."""

    def __init__(self, path: str | os.PathLike, verify_hashes: bool, invariants: bool):
        self.path = Path(path)
        self.verify_hashes = verify_hashes
        self.invariants = invariants
        self.problems: list[Problem] = []
        self.manifest: dict | None = None
        self.coarse = None    # (v, f, uv)
        self.atlas = None     # (H, W, 4)
        self.pieces = None    # parsed pieces tuple

    def add(self, cls: str, msg: str) -> None:
        self.problems.append(Problem(cls, msg))

    def adder(self, cls: str):
        return lambda msg: self.add(cls, msg)

    # -- manifest ------------------------------------------------------------
    def load_manifest(self) -> bool:
        mpath = self.path / FILE_NAMES["manifest"]
        if not self.path.exists():
            self.add("io", "bundle directory does not exist")
            return False
        if not self.path.is_dir():
            self.add("io", "not a directory (a bundle is a directory)")
            return False
        try:
            raw = read_regular(mpath, MAX_MANIFEST_BYTES)
        except FileNotFoundError:
            self.add("io", "manifest.json: missing")
            return False
        except FileTooLargeError as e:
            self.add("io", f"manifest.json: {_too_large(e)}")
            return False
        except OSError as e:
            self.add("io", f"manifest.json: cannot read: {e.strerror}")
            return False
        def no_constants(token: str):
            # Python's json accepts NaN and Infinity; JSON (and nlohmann-json) does not.
            raise ValueError(f"{token} is not valid JSON")

        def finite_float(text: str) -> float:
            # ... and turns 1e999 into inf, which is no JSON number either
            x = float(text)
            if not np.isfinite(x):
                raise ValueError(f"number {_short(text)} is out of range")
            return x

        def finite_int(text: str) -> int:
            # an integer literal past the double range is an overflow for nlohmann-json
            if len(text) > 300 and not np.isfinite(float(text)):
                raise ValueError(f"number {_short(text)} is out of range")
            return int(text)

        try:
            m = json.loads(raw.decode("utf-8"), parse_constant=no_constants, parse_float=finite_float,
                           parse_int=finite_int)
        except RecursionError:
            # the json module recurses once per level; the limit below stops what it survives
            self.add("schema", f"manifest.json: nested deeper than {MAX_JSON_DEPTH} levels")
            return False
        except (UnicodeDecodeError, ValueError) as e:  # JSONDecodeError is a ValueError
            self.add("schema", f"manifest.json: not valid UTF-8 JSON: {_short(str(e), 200)}")
            return False
        if not isinstance(m, dict):
            self.add("schema", f"manifest.json: top level is a {type(m).__name__}, not an object")
            return False
        if _json_depth(m) > MAX_JSON_DEPTH:
            # jsonschema and repr() recurse too (in its messages), so a deep value would
            # overflow the stack there instead
            self.add("schema", f"manifest.json: nested deeper than {MAX_JSON_DEPTH} levels")
            return False
        if _has_lone_surrogate(m):
            # "\ud800" alone: Python's json keeps it, JSON (and nlohmann-json) refuses it
            self.add("schema", "manifest.json: not valid UTF-8 JSON: a string has a \\u escape of "
                     "a lone UTF-16 surrogate")
            return False
        # Format and version first: a bundle of another major version may have
        # another schema, so its schema errors would only hide the real problem.
        if m.get("format") != FORMAT_NAME:
            self.add("version", f"manifest.json: format is {_short(m.get('format'))}, not {FORMAT_NAME!r} "
                     "(not an hbundle)")
            return False
        ver = m.get("format_version")
        mm = re.fullmatch(r"([0-9]+)\.([0-9]+)", ver) if isinstance(ver, str) else None
        if mm is None or len(ver) > MAX_VERSION_CHARS:
            self.add("version", f"manifest.json: format_version {_short(ver)} is not MAJOR.MINOR"
                     + (f" (at most {MAX_VERSION_CHARS} characters)"
                        if isinstance(ver, str) and len(ver) > MAX_VERSION_CHARS else ""))
            return False
        # Compared as digits: int() refuses more than 4300 of them (and would gain nothing).
        if (mm.group(1).lstrip("0") or "0") != str(FORMAT_MAJOR):
            self.add("version", f"manifest.json: unsupported major version {_short(ver, quote=False)} "
                     f"(this reader supports {FORMAT_MAJOR}.x)")
            return False
        import jsonschema
        validator = jsonschema.Draft202012Validator(load_schema())
        try:
            errors = sorted(validator.iter_errors(m),
                            key=lambda e: (list(map(str, e.absolute_path)), e.message))
        except RecursionError:       # not reached below MAX_JSON_DEPTH; kept as a guard
            self.add("schema", f"manifest.json: nested deeper than {MAX_JSON_DEPTH} levels")
            return False
        for e in errors:
            where = "/".join(str(p) for p in e.absolute_path) or "(top level)"
            msg = e.message if len(e.message) <= 200 else e.message[:197] + "..."
            self.add("schema", f"manifest.json: {where}: {msg}")
        if errors:
            return False
        extra = _loader_schema_rules(m)
        for where, msg in extra:
            self.add("schema", f"manifest.json: {where}: {msg}")
        if extra:
            return False
        self.manifest = m
        return True

    # -- files ----------------------------------------------------------------
    def read_file(self, key: str) -> bytes | None:
        entry = self.manifest["files"][key]
        p = self.path / entry["path"]
        try:
            blob = read_regular(p, MAX_FILE_BYTES[key])
        except FileNotFoundError:
            self.add("io", f"{entry['path']}: missing ({key} file named by the manifest)")
            return None
        except FileTooLargeError as e:
            self.add("io", f"{entry['path']}: {_too_large(e)}")
            return None
        except IsADirectoryError:
            self.add("io", f"{entry['path']}: is a directory, not a file")
            return None
        except OSError as e:
            self.add("io", f"{entry['path']}: cannot read: {e.strerror}")
            return None
        if self.verify_hashes:
            if len(blob) != entry["bytes"]:
                self.add("hash", f"{entry['path']}: {len(blob)} bytes, the manifest says {entry['bytes']}")
            digest = hashlib.sha256(blob).hexdigest()
            if digest != entry["sha256"]:
                self.add("hash", f"{entry['path']}: SHA-256 {digest[:12]}... differs from the "
                         f"manifest's {entry['sha256'][:12]}...")
        return blob

    # -- coarse mesh ------------------------------------------------------------
    def check_coarse(self, blob: bytes) -> None:
        name = self.manifest["files"]["coarse_mesh"]["path"]
        add = self.adder("mesh")
        try:
            v, f, uv = _parse_coarse(blob, name, add)
        except _Fail:
            return
        n, m = len(v), len(f)
        want = self.manifest["coarse"]
        if n != want["vertices"] or m != want["triangles"]:
            add(f"{name}: {n} vertices and {m} faces, the manifest says {want['vertices']} and "
                f"{want['triangles']}")
        if n < 3:
            add(f"{name}: {n} vertices (at least 3 needed)")
        if m < 1:
            add(f"{name}: no faces")
        bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
        if len(bad):
            add(f"{name}: {_n(len(bad), 'vertex', 'vertices')} with non-finite positions: "
                + _examples(list(bad), lambda k: f"vertex {k} = {v[k].tolist()}"))
        with np.errstate(invalid="ignore"):
            far = np.flatnonzero(np.any(np.abs(v) > C.MAX_COORDINATE, axis=1))
        if len(far):
            add(f"{name}: {_n(len(far), 'vertex', 'vertices')} farther than 10000 m from the origin along "
                "an axis: " + _examples(list(far), lambda k: f"vertex {k} = {v[k].tolist()}"))
        oob = np.flatnonzero(np.any(f >= n, axis=1))
        if len(oob):
            add(f"{name}: {_n(len(oob), 'face')} with a vertex index out of range (vertex count {n}): "
                + _examples(list(oob), lambda k: f"face {k} = {f[k].tolist()}"))
        ok = ~np.any(f >= n, axis=1)
        fi = f[ok].astype(np.int64)
        if len(fi):
            e1 = v[fi[:, 1]] - v[fi[:, 0]]
            e2 = v[fi[:, 2]] - v[fi[:, 0]]
            area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
            same = (fi[:, 0] == fi[:, 1]) | (fi[:, 1] == fi[:, 2]) | (fi[:, 0] == fi[:, 2])
            degen = np.flatnonzero(ok)[(same | (area2 == 0)) & np.isfinite(area2)]
            if len(degen):
                add(f"{name}: {_n(len(degen), 'degenerate face')} (zero area): "
                    + _examples(list(degen), lambda k: f"face {k} = {f[k].tolist()}"))
        uvf = uv.reshape(m, 6)
        nonfinite = np.flatnonzero(~np.all(np.isfinite(uvf), axis=1))
        if len(nonfinite):
            add(f"{name}: {_n(len(nonfinite), 'face')} with non-finite UVs: "
                + _examples(list(nonfinite), lambda k: f"face {k}"))
        with np.errstate(invalid="ignore"):
            outside = np.flatnonzero(np.any((uvf < 0) | (uvf > 1), axis=1))
        if len(outside):
            add(f"{name}: {_n(len(outside), 'face')} with UVs outside [0, 1]: "
                + _examples(list(outside), lambda k: f"face {k} has {uv[k].tolist()}"))
        self.coarse = (v, f, uv)

    # -- atlas ------------------------------------------------------------------
    def check_atlas(self, blob: bytes | None) -> None:
        entry = self.manifest["files"]["atlas"]
        name = entry["path"]
        add = self.adder("atlas")
        decl = self.manifest["atlas"]
        if (decl["width"], decl["height"]) != (entry["width"], entry["height"]):
            add(f"manifest.json: atlas is {decl['width']}x{decl['height']} but files.atlas says "
                f"{entry['width']}x{entry['height']}")
        sizes = {(entry["width"], entry["height"]), (decl["width"], decl["height"])}
        over = [(w, h) for w, h in sorted(sizes) if not _atlas_size_ok(w, h)]
        if over:
            # before OpenEXR reads a pixel: a ZIP block can expand a thousandfold, so the
            # file's size bounds nothing (the header's window must equal this size below)
            add(f"{name}: atlas is {over[0][0]}x{over[0][1]}, over the limit of "
                f"{C.MAX_ATLAS_SIDE} texels per side and {C.MAX_ATLAS_TEXELS:,} texels")
            return
        if blob is None:
            return
        ex = _exr()
        p = self.path / name
        # The C++ loader's walk of the header, before OpenEXR allocates what it claims.
        try:
            check_exr_header(blob, entry["width"], entry["height"])
        except ExrHeaderError as e:
            add(f"{name}: {e}")
            return
        f, why = _open_exr(p, header_only=True)
        if f is None:
            add(f"{name}: cannot read the OpenEXR header: {why or 'unknown error'}")
            return
        if len(f.parts) != 1:
            add(f"{name}: {len(f.parts)} parts (a single-part scanline image is required)")
            return
        part = f.parts[0]
        hdr = part.header
        ok = True
        if part.type() != ex.scanlineimage:
            add(f"{name}: storage is {getattr(part.type(), 'name', part.type())}, "
                "not a scanline image")
            return
        comp = _compression_name(part.compression())
        if comp not in ATLAS_COMPRESSIONS:
            add(f"{name}: compression {comp.upper()} is not allowed (ZIP or PIZ only)")
        elif comp != entry["compression"]:
            add(f"{name}: compression is {comp.upper()}, the manifest says {entry['compression'].upper()}")
        dw = hdr.get("dataWindow")
        dsp = hdr.get("displayWindow")
        w, h = entry["width"], entry["height"]
        want = [0, 0, w - 1, h - 1]
        if dw is not None:
            got = [int(dw[0][0]), int(dw[0][1]), int(dw[1][0]), int(dw[1][1])]
            if got[:2] != [0, 0]:
                add(f"{name}: data window starts at ({got[0]}, {got[1]}), not at (0, 0)")
                ok = False
            elif got != want:
                add(f"{name}: image is {got[2] + 1}x{got[3] + 1}, the manifest says {w}x{h}")
                ok = False
        if dsp is not None:
            got = [int(dsp[0][0]), int(dsp[0][1]), int(dsp[1][0]), int(dsp[1][1])]
            if got != want:
                add(f"{name}: display window is ({got[0]}, {got[1]}) - ({got[2]}, {got[3]}), "
                    f"expected (0, 0) - ({w - 1}, {h - 1})")
        chans = {c.name: c for c in hdr.get("channels", [])}
        names = sorted(chans)
        declared = sorted(entry["channels"])
        missing = [c for c in declared if c not in names]
        extra = [c for c in names if c not in declared]
        for c in missing:
            add(f"{name}: missing channel {c!r} (channels present: {', '.join(names) or 'none'})")
            ok = False
        if extra:
            add(f"{name}: channels {', '.join(extra)} are not declared in the manifest")
        for c in names:
            chan = chans[c]
            if chan.xSampling != 1 or chan.ySampling != 1:
                add(f"{name}: channel {c!r} is subsampled ({chan.xSampling}x{chan.ySampling})")
                ok = False
        if not ok:
            return
        f, why = _open_exr(p, header_only=False)
        if f is None or len(f.parts) != 1:
            add(f"{name}: cannot decode the pixel data: {why or 'unknown error'}")
            return
        part = f.parts[0]
        # The binding gives each channel's pixels in its stored type (FLOAT -> float32,
        # HALF -> float16, UINT -> uint32); the header alone does not expose it.
        for c in names:
            dt = np.asarray(part.channels[c].pixels).dtype
            if dt != np.float32:
                kind = {np.dtype(np.float16): "HALF", np.dtype(np.uint32): "UINT"}.get(dt, str(dt))
                add(f"{name}: channel {c!r} has pixel type {kind}, the manifest says "
                    f"{entry['pixel_type'].upper()}")
                ok = False
        if not ok:
            return
        atlas = np.stack([np.asarray(part.channels[c].pixels, dtype=np.float32) for c in "RGBA"], axis=-1)
        if atlas.shape[:2] != (h, w):
            add(f"{name}: decoded pixels are {atlas.shape[1]}x{atlas.shape[0]}, expected {w}x{h}")
            return
        self.atlas = atlas
        if not self.invariants:
            return
        alpha = atlas[:, :, 3]
        with np.errstate(invalid="ignore"):
            bad_a = np.argwhere(np.isfinite(alpha) & (alpha != 0) & (alpha != 1))
        if len(bad_a):
            j, i = bad_a[0]
            add(f"{name}: {_n(len(bad_a), 'texel')} with coverage A other than 0 or 1 "
                f"(first: texel ({i}, {j}) has A = {alpha[j, i]})")

    def check_atlas_footprints(self) -> None:
        """Every texel that a bilinear lookup inside a UV triangle reads must be finite
        and filled (covered, or within the gutter of a covered texel).

        Bounded like the C++ loader's texel checks: the rows and candidate texels
        examined are counted first (rows from each triangle's extent, then each row's
        candidate span) and past 16 per texel of the atlas + 64 per triangle the bundle
        is refused before any texel is tested; the count includes the loader's coverage
        check, so both readers refuse the same bundles."""
        if self.atlas is None or self.coarse is None or not self.invariants:
            return
        name = self.manifest["files"]["atlas"]["path"]
        gutter = int(self.manifest["atlas"]["gutter"])
        atlas = self.atlas
        h, w = atlas.shape[:2]
        v, f, uv = self.coarse
        limit = _work_limit(w, h, len(f))
        uv = uv.reshape(len(uv), 3, 2)
        tris = np.flatnonzero(np.all(np.isfinite(uv.reshape(len(uv), 6)), axis=1))
        fp = _Footprints(uv[tris], w, h)
        work = int(fp.rows.sum())
        if work <= limit:
            for a, b in fp.row_batches():
                work += int(fp.spans(a, b)[3].sum())
                if work > limit:
                    break
        if work > limit:
            self.add("atlas", _work_problem(name, limit))
            return
        finite = np.all(np.isfinite(atlas), axis=2)
        covered = finite & (atlas[:, :, 3] == 1)
        # filled = within Chebyshev distance `gutter` of a covered texel
        from scipy.ndimage import maximum_filter
        filled = maximum_filter(covered.astype(np.uint8), size=2 * gutter + 1, mode="constant") > 0
        read = np.zeros((h, w), dtype=bool)
        # per triangle (of `tris`): texels read that are non-finite / unfilled, and the
        # first of them (j w + i), in the order of a row-by-row scan
        counts = np.zeros((2, len(tris)), np.int64)
        firsts = np.full((2, len(tris)), -1, np.int64)
        for t, ci, cj in fp.visit():
            read[cj, ci] = True
            fin = finite[cj, ci]
            for kind, bad in enumerate((~fin, fin & ~filled[cj, ci])):
                if not bad.any():
                    continue
                tb, kb = t[bad], (cj[bad] * w + ci[bad])
                u, pos, cnt = np.unique(tb, return_index=True, return_counts=True)  # tb is sorted
                counts[kind, u] += cnt
                new = firsts[kind, u] < 0
                firsts[kind, u[new]] = kb[pos[new]]
        nonfinite_tris, unfilled_tris = [
            [(int(tris[k]), int(counts[kind, k]), int(firsts[kind, k] % w), int(firsts[kind, k] // w))
             for k in np.flatnonzero(counts[kind])] for kind in (0, 1)]
        if nonfinite_tris:
            self.add("atlas", f"{name}: bilinear lookups inside {_n(len(nonfinite_tris), 'UV triangle')} read "
                     "non-finite texels: " + _examples(
                         nonfinite_tris, lambda x: f"triangle {x[0]} reads {x[1]}, e.g. texel ({x[2]}, {x[3]})"))
        if unfilled_tris:
            self.add("atlas", f"{name}: bilinear lookups inside {_n(len(unfilled_tris), 'UV triangle')} read "
                     f"texels that are neither covered nor within the gutter ({gutter}) of a covered "
                     "texel: " + _examples(
                         unfilled_tris, lambda x: f"triangle {x[0]} reads {x[1]}, e.g. texel ({x[2]}, {x[3]})"))
        stray = np.argwhere(~finite & ~read)
        if len(stray):
            j, i = stray[0]
            self.add("atlas", f"{name}: {_n(len(stray), 'non-finite texel')} outside every UV triangle's "
                     f"footprint (first: texel ({i}, {j})); unused texels must hold 0")
        with np.errstate(invalid="ignore"):
            far_texels = np.argwhere(finite & np.any(np.abs(atlas[:, :, :3]) > C.MAX_COORDINATE, axis=2))
        if len(far_texels):
            j, i = far_texels[0]
            self.add("atlas", f"{name}: {_n(len(far_texels), 'texel')} with a position farther than 10000 m "
                     f"from the origin along an axis (first: texel ({i}, {j}))")
        # Coverage against the UVs (the loader's check: A = 1 exactly where a texel centre
        # lies inside a UV triangle, within its margin)
        cov_work, bad, near = _coverage_check(uv[tris], w, h, atlas[:, :, 3], limit - work)
        if bad is not None:
            t, i, j = bad
            self.add("atlas", f"{name}: texel ({i}, {j}) has its centre inside the UV triangle of "
                     f"coarse face {int(tris[t])} but coverage A = {float(atlas[j, i, 3]):.9g} (must be 1)")
        elif work + cov_work > limit:
            self.add("atlas", _work_problem(name, limit))
        else:
            lone = np.argwhere((atlas[:, :, 3] == 1) & ~near)
            if len(lone):
                j, i = lone[0]
                self.add("atlas", f"{name}: texel ({i}, {j}) has coverage A = 1 but its centre lies "
                         "in no UV triangle of the coarse mesh")

    # -- pieces -------------------------------------------------------------------
    def check_pieces(self, blob: bytes) -> None:
        name = self.manifest["files"]["pieces"]["path"]
        add = self.adder("pieces")
        try:
            v, vp, f, fp, maps = _parse_pieces(blob, name, add, self.manifest["format_version"])
        except _Fail:
            return
        p = len(maps)
        if p != self.manifest["pieces"]["count"]:
            add(f"{name}: {p} pieces, the manifest says {self.manifest['pieces']['count']}")
        if p == 0:
            add(f"{name}: no pieces")
            return
        structural_ok = True
        if len(vp) and np.any(vp >= p):
            k = int(np.flatnonzero(vp >= p)[0])
            add(f"{name}: vertex {k} has piece id {vp[k]} (pieces are 0..{p - 1})")
            structural_ok = False
        if len(fp) and np.any(fp >= p):
            k = int(np.flatnonzero(fp >= p)[0])
            add(f"{name}: face {k} has piece id {fp[k]} (pieces are 0..{p - 1})")
            structural_ok = False
        if len(vp) > 1 and np.any(np.diff(vp.astype(np.int64)) < 0):
            k = int(np.flatnonzero(np.diff(vp.astype(np.int64)) < 0)[0]) + 1
            add(f"{name}: vertices are not stored piece by piece (vertex {k} has piece {vp[k]} "
                f"after piece {vp[k - 1]})")
            structural_ok = False
        if len(fp) > 1 and np.any(np.diff(fp.astype(np.int64)) < 0):
            k = int(np.flatnonzero(np.diff(fp.astype(np.int64)) < 0)[0]) + 1
            add(f"{name}: faces are not stored piece by piece (face {k} has piece {fp[k]} "
                f"after piece {fp[k - 1]})")
            structural_ok = False
        oob = np.flatnonzero(np.any(f >= len(v), axis=1))
        if len(oob):
            add(f"{name}: {_n(len(oob), 'face')} with a vertex index out of range (vertex count {len(v)}): "
                + _examples(list(oob), lambda k: f"face {k} = {f[k].tolist()}"))
            structural_ok = False
        else:
            wrong = np.flatnonzero(np.any(vp[f] != fp[:, None], axis=1)) if len(f) else np.zeros(0, int)
            if len(wrong):
                add(f"{name}: {_n(len(wrong), 'face')} using vertices of another piece: "
                    + _examples(list(wrong), lambda k: f"face {k} (piece {fp[k]}) uses vertices of pieces "
                                f"{sorted(set(vp[f[k]].tolist()))}"))
                structural_ok = False
        bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
        if len(bad):
            add(f"{name}: {_n(len(bad), 'vertex', 'vertices')} with non-finite positions (first: vertex {bad[0]})")
            structural_ok = False
        with np.errstate(invalid="ignore"):
            far = np.flatnonzero(np.any(np.abs(v) > C.MAX_COORDINATE, axis=1))
        if len(far):
            add(f"{name}: {_n(len(far), 'vertex', 'vertices')} farther than 10000 m from the origin along "
                f"an axis (first: vertex {far[0]})")
            structural_ok = False
        m_coarse = len(self.coarse[1]) if self.coarse is not None else self.manifest["coarse"]["triangles"]
        self._check_maps(name, add, maps, m_coarse)
        if not structural_ok:
            return
        vstart = np.searchsorted(vp, np.arange(p + 1))
        fstart = np.searchsorted(fp, np.arange(p + 1))
        if self.coarse is not None:
            diag = _bbox_diagonal(self.coarse[0])
        else:
            diag = _bbox_diagonal(v)
        tol = convexity_tolerance(diag)
        nv, nf = np.diff(vstart), np.diff(fstart)
        small_mask = (nv < 4) | (nf < 4)
        big_mask = ~small_mask & (nv > MAX_PIECE_VERTICES)
        small = [(int(k), int(nv[k]), int(nf[k])) for k in np.flatnonzero(small_mask)]
        big = [(int(k), int(nv[k])) for k in np.flatnonzero(big_mask)]
        bigf_mask = ~small_mask & ~big_mask & (nf > MAX_PIECE_FACES)
        bigf = [(int(k), int(nf[k])) for k in np.flatnonzero(bigf_mask)]
        open_, inward, nonconvex, degen = [], [], [], []
        if self.invariants:
            # in chunks of whole pieces, so the temporaries stay bounded (_CHUNK_FACES)
            check = ~small_mask & ~big_mask & ~bigf_mask
            k0 = 0
            while k0 < p:
                k1 = int(np.searchsorted(fstart, fstart[k0] + _CHUNK_FACES, side="right")) - 1
                k1 = min(max(k1, k0 + 1), p)
                vs, ve, fs, fe = vstart[k0], vstart[k1], fstart[k0], fstart[k1]
                o, d, i, c = _piece_invariants(
                    v[vs:ve], f[fs:fe].astype(np.int64) - vs, vp[vs:ve].astype(np.int64) - k0,
                    fp[fs:fe].astype(np.int64) - k0, vstart[k0:k1 + 1] - vs,
                    fstart[k0:k1 + 1] - fs, check[k0:k1], tol)
                open_ += [k + k0 for k in o]
                degen += [(k + k0, x) for k, x in d]
                inward += [(k + k0, x) for k, x in i]
                nonconvex += [(x[0] + k0,) + tuple(x[1:]) for x in c]
                k0 = k1
        if small:
            add(f"{name}: {_n(len(small), 'piece')} with fewer than 4 vertices or 4 faces: "
                + _examples(small, lambda x: f"piece {x[0]} has {x[1]} vertices, {x[2]} faces"))
        if big:
            add(f"{name}: {_n(len(big), 'piece')} over the vertex limit: "
                + _examples(big, lambda x: f"piece {x[0]} has {x[1]} vertices, more than the "
                            f"limit {MAX_PIECE_VERTICES}"))
        if bigf:
            add(f"{name}: {_n(len(bigf), 'piece')} over the face limit: "
                + _examples(bigf, lambda x: f"piece {x[0]} has {x[1]} faces, more than the limit "
                            f"{MAX_PIECE_FACES} (a convex piece of at most {MAX_PIECE_VERTICES} "
                            f"vertices has at most {MAX_PIECE_FACES} triangles)"))
        if open_:
            add(f"{name}: {_n(len(open_), 'piece')} not a closed, consistently wound polyhedron: "
                + _examples(open_, lambda k: f"piece {k}"))
        if degen:
            add(f"{name}: {_n(len(degen), 'piece')} with a zero-area face: "
                + _examples(degen, lambda x: f"piece {x[0]} face {x[1]} (local)"))
        if inward:
            add(f"{name}: {_n(len(inward), 'piece')} wound inward (negative volume): "
                + _examples(inward, lambda x: f"piece {x[0]} (volume {x[1]:.3g} m^3)"))
        if nonconvex:
            add(f"{name}: {_n(len(nonconvex), 'piece')} not convex (tolerance {tol:.3g} m): "
                + _examples(nonconvex, lambda x: f"piece {x[0]}: vertex {x[3]} lies {x[1]:.3g} m in front "
                            f"of face {x[2]} (local indices)"))
        self.pieces = (v, vp, f, fp, maps, vstart, fstart)

    def _check_maps(self, name: str, add, maps: list[np.ndarray], m_coarse: int) -> None:
        """coarse_faces of every piece in range, ascending and unique (all pieces at once:
        a loop over 10^5 small pieces would dominate the check)."""
        if not maps:
            return
        counts = np.fromiter((len(mp) for mp in maps), dtype=np.int64, count=len(maps))
        if counts.sum() == 0:
            return
        entries = np.concatenate(maps).astype(np.int64)
        pid = np.repeat(np.arange(len(maps)), counts)
        out_of_range = np.unique(pid[entries >= m_coarse])
        same = pid[1:] == pid[:-1]
        unordered = np.unique(pid[1:][same & (np.diff(entries) <= 0)])
        flagged = np.union1d(out_of_range, unordered)
        for k in flagged[:_MAX_EXAMPLES].tolist():
            mp = maps[k]
            if k in out_of_range:
                add(f"{name}: piece {k} maps to coarse triangle {int(mp.max())}, out of range "
                    f"(coarse triangle count {m_coarse})")
            if k in unordered:
                add(f"{name}: coarse_faces of piece {k} are not ascending and unique")
        if len(flagged) > _MAX_EXAMPLES:
            add(f"{name}: coarse_faces of {_n(len(flagged) - _MAX_EXAMPLES, 'more piece')} out of range, "
                "not ascending or not unique")

    # -- everything ---------------------------------------------------------------
    def run(self) -> Bundle | None:
        if not self.load_manifest():
            return None
        blobs = {key: self.read_file(key) for key in ("coarse_mesh", "atlas", "pieces")}
        if blobs["coarse_mesh"] is not None:
            self.check_coarse(blobs["coarse_mesh"])
        self.check_atlas(blobs["atlas"])
        self.check_atlas_footprints()
        if blobs["pieces"] is not None:
            self.check_pieces(blobs["pieces"])
        # Stable order: by error class as in the spec, then by discovery.
        order = {c: k for k, c in enumerate(ERROR_CLASSES)}
        self.problems.sort(key=lambda pr: order[pr.cls])
        if self.problems or self.coarse is None or self.atlas is None or self.pieces is None:
            return None
        v, f, uv = self.coarse
        pv, _, pf, _, maps, vstart, fstart = self.pieces
        p = len(maps)
        manifest = self.manifest
        _, _, _, fpid, _, _, _ = self.pieces
        local = (pf.astype(np.int64) - vstart[fpid][:, None]).astype(np.uint32)
        return Bundle(
            coarse_vertices=v, coarse_faces=f, coarse_uvs=uv, atlas=self.atlas,
            piece_vertices=[pv[vstart[k]:vstart[k + 1]] for k in range(p)],
            piece_faces=[local[fstart[k]:fstart[k + 1]] for k in range(p)],
            piece_coarse_faces=list(maps), manifest=manifest, path=self.path)


def validate_bundle(path: str | os.PathLike) -> list[Problem]:
    """Every problem of the bundle at ``path`` (empty list: valid), ordered by class
    (io, version, schema, hash, mesh, atlas, pieces)."""
    return check_bundle(path)[1]


def check_bundle(path: str | os.PathLike) -> tuple[dict | None, list[Problem]]:
    """(manifest, problems): the manifest when it is readable, of version 1.x and
    schema-valid (else None), and every problem as :func:`validate_bundle` lists it."""
    manifest, problems, _ = check_bundle_data(path)
    return manifest, problems


def check_bundle_data(path: str | os.PathLike) -> tuple[dict | None, list[Problem], Bundle | None]:
    """:func:`check_bundle` and the bundle read (None unless there is no problem)."""
    checker = _Checker(path, verify_hashes=True, invariants=True)
    bundle = checker.run()
    return checker.manifest, checker.problems, (bundle if not checker.problems else None)


def read_bundle(path: str | os.PathLike, *, verify: bool = True) -> Bundle:
    """Read a bundle; raise BundleError(cls, message) for its first problem.

    ``verify=False`` skips the SHA-256 checks and the costlier invariants (piece
    convexity, atlas footprints) but still checks the structure (headers, sizes,
    index ranges, channels)."""
    checker = _Checker(path, verify_hashes=verify, invariants=verify)
    bundle = checker.run()
    if checker.problems:
        first = checker.problems[0]
        raise BundleError(first.cls, first.message)
    assert bundle is not None
    return bundle
