"""A bounded walk of an OpenEXR header, before OpenEXR sees the file.

OpenEXR (and so its Python binding) trusts the sizes and counts its header claims: it
allocates a string attribute's claimed size, a preview's width x height, a string
vector entry's length and line tables sized by the data window before it reads a byte
of them. This is the C++ loader's walk (runtime/src/io/exr.cpp, read_atlas_exr and
check_header_bounds) in Python, with the same limits, order of checks and messages, so
that ``hbake validate`` refuses every atlas header the loader refuses, with class
``atlas``: every claim is bounded by the bytes actually in the file, the data window
by the atlas limit and the manifest.

Only :mod:`struct` and byte searches: at most 1 MiB of header and 1024 attributes are
walked, whatever the file claims.
"""
from __future__ import annotations

import struct

from hbake import constants as C

__all__ = ["ExrHeaderError", "check_exr_header", "MAX_HEADER_BYTES", "MAX_ATTRIBUTES",
           "MAX_CHANNELS"]

MAGIC = 20000630
# Version field: the low byte is the file version, the rest flags (ImfVersion.h).
TILED_FLAG = 0x200
LONG_NAMES_FLAG = 0x400
NON_IMAGE_FLAG = 0x800
MULTI_PART_FILE_FLAG = 0x1000
ALL_FLAGS = TILED_FLAG | LONG_NAMES_FLAG | NON_IMAGE_FLAG | MULTI_PART_FILE_FLAG

#: Bounds of the walk (OpenEXR's own headers are about 350 bytes with 8 attributes and
#: the atlas has 4 channels: these are generous); the C++ loader's kMaxHeaderBytes,
#: kMaxAttributes and kMaxChannels.
MAX_HEADER_BYTES = 1 << 20
MAX_ATTRIBUTES = 1024
MAX_CHANNELS = 64

ATLAS_LIMIT_TEXT = (f" (each side at most {C.MAX_ATLAS_SIDE}, at most {C.MAX_ATLAS_TEXELS} "
                    "texels)")

_I32 = struct.Struct("<i")
_U32 = struct.Struct("<I")
_BAD = "cannot read the OpenEXR header: "


class ExrHeaderError(ValueError):
    """The header breaks a bound; ``str(e)`` is the message without the file name."""


def _printable(b: bytes) -> str:
    return "".join(chr(c) if 0x20 <= c < 0x7F else "?" for c in b)


def _within_atlas_limit(w: int, h: int) -> bool:
    return 1 <= w <= C.MAX_ATLAS_SIDE and 1 <= h <= C.MAX_ATLAS_SIDE and w * h <= C.MAX_ATLAS_TEXELS


def check_exr_header(b: bytes, width: int, height: int) -> None:
    """Raise :class:`ExrHeaderError` unless ``b`` starts with a single-part scanline
    OpenEXR header every claim of which is within the file and whose data window is
    (0, 0) - (width - 1, height - 1) within the atlas limit (the manifest's size)."""
    n = len(b)
    if n < 8:
        raise ExrHeaderError(f"not an OpenEXR file ({n} bytes)")
    if _I32.unpack_from(b, 0)[0] != MAGIC:
        raise ExrHeaderError("not an OpenEXR file (bad magic number)")
    version = _I32.unpack_from(b, 4)[0]
    if version & 0xFF != 2:
        raise ExrHeaderError(f"unsupported OpenEXR file version {version & 0xFF}")
    if version & MULTI_PART_FILE_FLAG:
        raise ExrHeaderError("multi-part OpenEXR file (a single-part scanline image is required)")
    if version & NON_IMAGE_FLAG:
        raise ExrHeaderError("storage is deep, not a scanline image")
    if version & TILED_FLAG:
        raise ExrHeaderError("storage is tiled, not a scanline image")
    if (version & ~0xFF) & ~ALL_FLAGS:
        raise ExrHeaderError("unknown OpenEXR version flags")
    if not _within_atlas_limit(width, height):
        raise ExrHeaderError(f"the manifest's atlas is {width} x {height} texels, more than the "
                             f"limit{ATLAS_LIMIT_TEXT}")
    max_name = 255 if version & LONG_NAMES_FLAG else 31
    p = 8

    def cstr(what: str) -> bytes:
        nonlocal p
        end = b.find(b"\0", p, p + max_name + 1)
        if end < 0:
            raise ExrHeaderError(f"{_BAD}attribute {what} at byte {p} is not a string of at most "
                                 f"{max_name} characters within the file")
        out = b[p:end]
        p = end + 1
        return out

    dw = None
    count = 0
    while True:
        if p >= n:
            raise ExrHeaderError(f"{_BAD}the header is truncated (no end-of-header byte)")
        if b[p] == 0:
            break
        if count >= MAX_ATTRIBUTES:
            raise ExrHeaderError(f"{_BAD}more than {MAX_ATTRIBUTES} attributes")
        count += 1
        name, typ = cstr("name"), cstr("type name")
        what = f"attribute '{_printable(name)}' ({_printable(typ)})"
        if n - p < 4:
            raise ExrHeaderError(f"{_BAD}the header is truncated in {what}")
        size = _I32.unpack_from(b, p)[0]
        p += 4
        # attribute values are stored uncompressed: none can exceed the bytes left
        if size < 0 or size > n - p:
            raise ExrHeaderError(f"{_BAD}{what} claims {size} bytes, more than the {n - p} bytes "
                                 "left in the file")
        v, vs = p, size
        if typ == b"preview":
            if vs < 8:
                raise ExrHeaderError(f"{_BAD}{what} has {vs} bytes (at least 8 needed)")
            w, h = _U32.unpack_from(b, v)[0], _U32.unpack_from(b, v + 4)[0]
            if w * h * 4 + 8 != vs:
                raise ExrHeaderError(f"{_BAD}{what} claims {w} x {h} pixels in {vs} bytes")
        elif typ == b"stringvector":
            q, k = 0, 0
            while q < vs:
                if vs - q < 4:
                    raise ExrHeaderError(f"{_BAD}{what} entry {k} is truncated")
                ln = _I32.unpack_from(b, v + q)[0]
                q += 4
                if ln < 0 or ln > vs - q:
                    raise ExrHeaderError(f"{_BAD}{what} entry {k} claims {ln} bytes, more than the "
                                         f"{vs - q} left in the attribute")
                q += ln
                k += 1
        elif typ == b"chlist":
            # name\0, pixel type int32, pLinear u8, 3 reserved, x/y sampling int32; a null
            # byte ends the list
            q, k = 0, 0
            while True:
                if q >= vs:
                    raise ExrHeaderError(f"{_BAD}{what} is truncated")
                if b[v + q] == 0:
                    break
                if k >= MAX_CHANNELS:
                    raise ExrHeaderError(f"{_BAD}{what} has more than {MAX_CHANNELS} channels")
                end = b.find(b"\0", v + q, v + vs)
                if end < 0 or end - (v + q) > 255 or v + vs - (end + 1) < 16:
                    raise ExrHeaderError(f"{_BAD}{what} is truncated in channel {k}")
                q = end + 1 + 16 - v
                k += 1
        elif name == b"dataWindow":
            if typ != b"box2i" or vs != 16:
                raise ExrHeaderError(f"{_BAD}{what} is not a box2i of 16 bytes")
            dw = struct.unpack_from("<4i", b, v)
        p += vs
        if p - 8 > MAX_HEADER_BYTES:
            raise ExrHeaderError(f"{_BAD}the header is larger than {MAX_HEADER_BYTES} bytes")
    if dw is None:
        raise ExrHeaderError(f"{_BAD}no dataWindow attribute")
    if dw[0] != 0 or dw[1] != 0:
        raise ExrHeaderError(f"data window starts at ({dw[0]}, {dw[1]}), not at (0, 0)")
    w, h = dw[2] + 1, dw[3] + 1
    if not _within_atlas_limit(w, h):
        raise ExrHeaderError(f"image is {w} x {h} texels, more than the limit{ATLAS_LIMIT_TEXT}")
    if (w, h) != (width, height):
        raise ExrHeaderError(f"image is {w}x{h}, the manifest says {width}x{height}")
