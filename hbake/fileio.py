"""Reading input files safely (regular files only, with a size limit) and writing outputs
atomically.

A path may name a FIFO (``open`` blocks until a writer comes, ``read`` never ends), a
character device such as ``/dev/zero`` (endless bytes) or a directory, directly or
through a symlink. ``read_regular`` opens without blocking, checks the opened file
itself (``fstat``, so a file swapped after a check cannot slip through) and reads
only a regular file of at most ``limit`` bytes. Failures are ``OSError``s whose
``strerror`` reads well after "cannot read: ".

Outputs are written through a temporary sibling renamed into place (``write_atomic``).
"""
from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path
from typing import Callable

__all__ = ["NotRegularFileError", "FileTooLargeError", "read_regular", "check_regular",
           "file_kind", "write_atomic", "write_json_atomic"]


class NotRegularFileError(OSError):
    """The path names a FIFO, a device, a socket (or a directory)."""


class FileTooLargeError(OSError):
    """The file is larger than the reader's limit (``size``: its size in bytes, or None
    when it grew past the limit while being read; ``limit``: the limit)."""

    size: int | None = None
    limit: int | None = None


def file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _check(st: os.stat_result, path, limit: int | None) -> None:
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(errno.EISDIR, "is a directory, not a file", str(path))
    if not stat.S_ISREG(st.st_mode):
        raise NotRegularFileError(errno.EINVAL, f"not a regular file (it is {file_kind(st.st_mode)})",
                                  str(path))
    if limit is not None and st.st_size > limit:
        e = FileTooLargeError(errno.EFBIG, f"file is {st.st_size:,} bytes, more than the limit "
                              f"of {limit:,} bytes", str(path))
        e.size, e.limit = st.st_size, limit
        raise e


def check_regular(path: str | os.PathLike, limit: int | None = None) -> os.stat_result:
    """``os.stat`` (following symlinks) of a regular file of at most ``limit`` bytes."""
    st = os.stat(path)
    _check(st, path, limit)
    return st


def read_regular(path: str | os.PathLike, limit: int | None = None) -> bytes:
    """The bytes of the regular file ``path`` (at most ``limit`` of them)."""
    # O_NONBLOCK: opening a FIFO for reading would otherwise wait for a writer.
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        _check(os.fstat(fd), path, limit)
        os.set_blocking(fd, True)
        with os.fdopen(fd, "rb") as fh:
            fd = -1
            data = fh.read() if limit is None else fh.read(limit + 1)
    finally:
        if fd >= 0:
            os.close(fd)
    if limit is not None and len(data) > limit:      # it grew after fstat
        e = FileTooLargeError(errno.EFBIG, f"file is more than the limit of {limit:,} bytes",
                              str(path))
        e.limit = limit
        raise e
    return data


def write_atomic(path: Path | str, write: Callable[[Path], None], what: str = "",
                 suffix: str = ".tmp") -> Path:
    """Write ``path`` through a temporary sibling: ``write(tmp)`` fills it, then it is
    renamed into place, so that a reader never sees half a file and a failure leaves no
    file behind (the temporary is removed whatever happens). ``suffix`` ends the
    temporary's name (a writer that picks its format from the name needs the real one).
    An OSError becomes one line naming ``what`` and the path (exit 6, the
    output-unwritable class)."""
    from hbake.errors import OutputUnwritableError

    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}{suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        prefix = f"{what} " if what else ""
        raise OutputUnwritableError(f"{prefix}{path}: {exc.strerror or exc}") from None
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def write_json_atomic(path: Path | str, data: dict, what: str) -> None:
    """``data`` as sorted, indented JSON at ``path`` (write_atomic)."""
    text = json.dumps(data, indent=2, sort_keys=True) + "\n"
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"), what)
