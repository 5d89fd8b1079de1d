"""write_bundle: atomic (a temporary sibling directory, then os.rename), deterministic,
validated before it is published; stale temporaries of killed writers are removed."""
from __future__ import annotations

import errno
import json
import os
import re
import secrets
import shutil
from pathlib import Path

import numpy as np

from hbake.bundle.exr import _compression_enum, write_atlas_exr
from hbake.bundle.format import (
    ATLAS_CHANNELS,
    FILE_NAMES,
    FORMAT_NAME,
    FORMAT_VERSION,
    BundleData,
)
from hbake.bundle.manifest import manifest_bytes, sha256_file
from hbake.bundle.ply import write_coarse_ply, write_pieces_ply
from hbake.bundle.validate import validate_bundle
from hbake.errors import (
    BakeFailedError,
    OutputExistsError,
    OutputUnwritableError,
)

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
