"""manifest.json: its canonical bytes, the JSON schema, the loader's own rules, file hashes."""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from hbake.bundle.format import (
    _INT64_MAX,
    _SHA256,
    FILE_NAMES,
    MAX_GUTTER,
    MAX_JSON_DEPTH,
    MAX_SCHEMA_ATLAS_SIDE,
    _short,
)

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
        # hbake/schema, package data (see pyproject.toml).
        text = (Path(__file__).resolve().parents[1] / "schema" / "manifest.schema.json").read_text("utf-8")
        _SCHEMA_CACHE = json.loads(text)
    return _SCHEMA_CACHE


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
