"""The bundle format's constants, data types and the validator's small helpers (docs/bundle-format.md)."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hbake import constants as C
from hbake.fileio import FileTooLargeError

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


def _too_large(e: FileTooLargeError) -> str:
    """The C++ loader's wording for a file over its size limit."""
    if e.size is None:
        return f"more than the limit of {e.limit} bytes for this file"
    return f"{e.size} bytes, more than the limit of {e.limit} bytes for this file"


_INT64_MAX = (1 << 63) - 1
_SHA256 = re.compile(r"[0-9a-f]{64}")


def _n(count: int, noun: str, plural: str | None = None) -> str:
    """'1 face', '3 faces'."""
    return f"{count} {noun if count == 1 else (plural or noun + 's')}"


def _examples(items: list, fmt) -> str:
    """'a; b; c (and 4 more)' for problem messages that would otherwise repeat."""
    shown = "; ".join(fmt(x) for x in items[:_MAX_EXAMPLES])
    if len(items) > _MAX_EXAMPLES:
        shown += f" (and {len(items) - _MAX_EXAMPLES} more)"
    return shown
