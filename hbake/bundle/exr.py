"""atlas.exr: the float32 haptic texture, written without time stamps, read after a bounded
header walk (hbake.bundle.exrheader)."""
from __future__ import annotations

import errno
import os
import sys
from pathlib import Path

import numpy as np

from hbake.errors import (
    BundleError,
)

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
