"""Stage 1: load, validate and repair the full-resolution mesh.

Reads OBJ, PLY and STL (ASCII and binary), OFF, glTF and GLB through trimesh, scales
to meters and repairs what can be repaired without guessing:

* polygons are triangulated (by trimesh's readers, fan triangulation);
* vertices at identical positions are merged (exact float equality, after scaling);
* degenerate faces (a repeated vertex, or a height below ``DEGENERATE_HEIGHT_REL`` times
  the longest edge, i.e. zero area to round-off) are dropped, and so are duplicate
  faces (the same three vertices, in any order: the first stays);
* unreferenced vertices are dropped;
* closed bodies wound inside-out are flipped.

Refused with a one-line ``InputMissingError``/``InputInvalidError``: a missing or
unreadable file, an unsupported extension, an empty or unparsable file, NaN/Inf
coordinates, and a mesh with nothing left after repair.

Accepted with a warning (recorded in the manifest): an open mesh (mass properties
then come from the coarse mesh or the convex hull, see ``hbake.stages.mass``), several
separate bodies in one file (baked together as one rigid object), an unknown unit.
"""
from __future__ import annotations

import hashlib
import logging
import os
import re
import warnings as pywarnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hbake import constants as C
from hbake.errors import InputInvalidError, InputMissingError
from hbake.fileio import FileTooLargeError, check_regular, read_regular
from hbake.stages.geometry import (bbox_diagonal, boundary_edge_count, face_components,
                            is_closed, signed_volumes, unique_rows)
from hbake.settings import LoadSettings


@dataclass
class LoadedMesh:
    """The repaired full-resolution mesh, in meters."""

    vertices: np.ndarray            # (N, 3) float64, meters
    faces: np.ndarray               # (M, 3) int64
    name: str                       # file name only (no directory: bundles hold no paths)
    sha256: str                     # of the file's bytes
    source_unit: str                # "mm" | "cm" | "m" | "in" | "unknown"
    scale_to_meters: float
    closed: bool                    # closed and consistently oriented
    bodies: int                     # connected components
    boundary_edges: int
    repair: dict = field(default_factory=dict)   # counts of what was repaired
    warnings: list[str] = field(default_factory=list)

    @property
    def bbox_diagonal(self) -> float:
        return bbox_diagonal(self.vertices)


def load_mesh(path: str | os.PathLike, settings: LoadSettings | None = None,
              warn=None) -> LoadedMesh:
    """Load, validate and repair ``path``; ``warn(msg)`` is called for each warning."""
    settings = settings or LoadSettings()
    path = Path(path)
    name = path.name
    ext = path.suffix.lower()
    warnings: list[str] = []

    def _warn(msg: str):
        warnings.append(msg)
        if warn is not None:
            warn(msg)

    # Regular files only (a FIFO or /dev/zero, also behind a symlink, would block or
    # never end), checked on the opened file; then the size limit, before reading.
    try:
        check_regular(path, C.MAX_INPUT_BYTES)
    except FileNotFoundError:
        raise InputMissingError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputMissingError(f"{path}: is a directory, not a mesh file") from None
    except FileTooLargeError as exc:
        raise InputInvalidError(f"{path}: {exc.strerror}") from None
    except OSError as exc:
        raise InputMissingError(f"{path}: cannot read: {exc.strerror}") from None
    if ext not in C.SUPPORTED_EXTENSIONS:
        raise InputInvalidError(f"{path}: unsupported file type '{ext or '(none)'}' "
                                f"(supported: {' '.join(C.SUPPORTED_EXTENSIONS)})")
    try:
        data = read_regular(path, C.MAX_INPUT_BYTES)
    except FileTooLargeError as exc:
        raise InputInvalidError(f"{path}: {exc.strerror}") from None
    except OSError as exc:
        raise InputMissingError(f"{path}: cannot read: {exc.strerror}") from None
    if len(data.strip()) == 0:
        raise InputInvalidError(f"{path}: file is empty")
    sha256 = hashlib.sha256(data).hexdigest()
    if ext == ".obj":
        _check_obj_face_indices(data, path)

    vertices, faces = _parse(path, ext)
    if len(faces) == 0 or len(vertices) == 0:
        raise InputInvalidError(f"{path}: no triangles in the file")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputInvalidError(f"{path}: face index out of range")
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        bad = np.nonzero(~finite)[0]
        raise InputInvalidError(f"{path}: {len(bad)} vertices have NaN or Inf coordinates "
                                f"(first: vertex {bad[0] + 1})")

    # --- units -------------------------------------------------------------------------
    if settings.units != "auto":
        unit = settings.units
    else:
        unit = C.UNIT_FROM_FORMAT.get(ext, "unknown")
    scale = C.UNIT_SCALE.get(unit, 1.0)
    with np.errstate(over="ignore"):
        vertices = vertices * scale
    _check_extent(vertices, faces, path, unit)

    # --- repair ------------------------------------------------------------------------
    vertices, faces, repair = repair_mesh(vertices, faces)
    if len(faces) == 0:
        raise InputInvalidError(f"{path}: nothing left after repair: all "
                                f"{repair['faces_in']} faces are degenerate")
    if unit == "unknown":
        size = vertices.max(axis=0) - vertices.min(axis=0)
        _warn(f"{name} records no unit; assuming meters, which makes the part "
              f"{size[0]:.4g} x {size[1]:.4g} x {size[2]:.4g} m "
              f"(pass --units mm|cm|m|in if that is wrong)")
    nbodies, labels = face_components(faces, len(vertices))
    faces, flipped = _orient_closed_bodies(vertices, faces, labels, nbodies)
    closed = is_closed(faces)
    nboundary = boundary_edge_count(faces)
    repair["flipped_bodies"] = flipped

    # Merging duplicate vertices is routine, not a warning: an STL stores every
    # triangle's corners apart, so every STL bake would print it and hide the warnings
    # that matter (no unit, not closed). The count stays in the manifest's repair record.
    changes = [f"{repair[k]} {txt}" for k, txt in (
        ("degenerate_faces", "degenerate faces dropped"),
        ("duplicate_faces", "duplicate faces dropped"),
        ("unreferenced_vertices", "unreferenced vertices dropped"),
        ("flipped_bodies", "inside-out bodies flipped")) if repair[k]]
    if changes:
        _warn(f"{name}: repaired: " + ", ".join(changes))
    if not closed:
        _warn(f"{name} is not closed ({nboundary} boundary edges): mass properties and "
              f"convex pieces use the coarse mesh with its holes capped (or else the convex "
              f"hull); inside and outside follow the file's winding")
    if nbodies > 1:
        _warn(f"{name} has {nbodies} separate bodies: they are baked as one rigid "
              f"object (one coarse mesh, atlas and set of pieces)")
    return LoadedMesh(vertices=vertices, faces=faces, name=name, sha256=sha256,
                      source_unit=unit, scale_to_meters=scale, closed=closed,
                      bodies=nbodies, boundary_edges=nboundary, repair=repair,
                      warnings=warnings)


def _parse(path: Path, ext: str) -> tuple[np.ndarray, np.ndarray]:
    """Read vertices and triangles with trimesh; any failure is an InputInvalidError."""
    import trimesh

    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        with pywarnings.catch_warnings():
            pywarnings.simplefilter("ignore")
            loaded = trimesh.load(str(path), force="mesh", process=False,
                                  skip_materials=True)
    except AssertionError:
        # trimesh's glTF reader asserts that each buffer view and accessor fits its
        # buffer; the bare AssertionError says nothing
        what = ("a buffer, buffer view or accessor is shorter than the file declares "
                "(truncated or inconsistent binary data)" if ext in (".gltf", ".glb")
                else "the reader found inconsistent data")
        raise InputInvalidError(f"{path}: cannot parse as {ext[1:].upper()}: {what}") from None
    except ImportError:
        # trimesh falls back to the optional charset_normalizer to guess the
        # encoding of text that is not UTF-8: for a mesh file that means bytes
        # that are neither valid text nor a valid binary layout.
        raise InputInvalidError(f"{path}: cannot parse as {ext[1:].upper()}: the file is neither "
                                f"UTF-8 text nor a valid binary {ext[1:].upper()}") from None
    except Exception as exc:  # trimesh raises many kinds on malformed input
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputInvalidError(f"{path}: cannot parse as {ext[1:].upper()}: {msg[:200]}") from None
    if isinstance(loaded, trimesh.Scene):          # an empty scene stays a Scene
        raise InputInvalidError(f"{path}: no triangles in the file")
    if not hasattr(loaded, "faces"):                # a point cloud or a path
        raise InputInvalidError(f"{path}: no triangles in the file (not a surface mesh)")
    vertices = np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
    return vertices, faces


#: An OBJ face line with a vertex index of 0 (OBJ counts from 1; trimesh would quietly
#: turn it into another vertex and the face into a degenerate one, dropped by repair).
_OBJ_ZERO_INDEX = re.compile(rb"(?m)^[ \t]*f[ \t](?:[^\n]*?[ \t])?[+-]?0+(?=[/ \t\r\n]|$)")


def _check_obj_face_indices(data: bytes, path: Path) -> None:
    m = _OBJ_ZERO_INDEX.search(data)
    if m is not None:
        line = data.count(b"\n", 0, m.start()) + 1
        raise InputInvalidError(f"{path}: line {line}: face with vertex index 0 (OBJ vertex "
                                f"indices start at 1)")


def _check_extent(vertices: np.ndarray, faces: np.ndarray, path: Path, unit: str) -> None:
    """Refuse coordinates that the bake cannot represent (see constants.MAX_COORDINATE):
    beyond 1e4 m, a bounding box outside [1e-5 m, 1e4 m], or a part farther from the
    origin than MAX_OFFSET_RATIO times its size. Only vertices that faces use count."""
    used = np.unique(faces)
    v = vertices[used]
    how = "" if unit == "m" else f" (in meters, the file's unit taken as {unit if unit != 'unknown' else 'm'})"
    with np.errstate(over="ignore", invalid="ignore"):
        if not np.isfinite(v).all():          # finite in the file, overflowed by the unit scale
            raise InputInvalidError(f"{path}: coordinates overflow when scaled to meters")
        amax = float(np.abs(v).max())
        if amax > C.MAX_COORDINATE:
            raise InputInvalidError(
                f"{path}: a coordinate is {amax:.3g} m{how}, beyond the limit of "
                f"{C.MAX_COORDINATE:g} m (wrong --units? hbake bakes objects up to "
                f"{C.MAX_BBOX_DIAGONAL:g} m across, near the origin)")
        diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    if not C.MIN_BBOX_DIAGONAL <= diag <= C.MAX_BBOX_DIAGONAL:
        raise InputInvalidError(
            f"{path}: the bounding box diagonal is {diag:.3g} m{how}, outside "
            f"[{C.MIN_BBOX_DIAGONAL:g} m, {C.MAX_BBOX_DIAGONAL:g} m] (wrong --units?)")
    if amax > C.MAX_OFFSET_RATIO * diag:
        raise InputInvalidError(
            f"{path}: the part is {diag:.3g} m across but {amax:.3g} m from the origin "
            f"(more than {C.MAX_OFFSET_RATIO:g} times its size): float32 positions there "
            f"are too coarse for its texels; move it nearer the origin")


def repair_mesh(vertices: np.ndarray, faces: np.ndarray, cancel_fins: bool = False):
    """Merge identical vertices; drop degenerate, duplicate faces and unused vertices.

    Faces on the same three vertices keep one copy; with ``cancel_fins`` a pair in
    opposite windings cancels instead (for the output of a simplifier, where such a pair
    is a zero-thickness fin; in an input file it may be a deliberate two-sided face).

    Deterministic (sort-based), order-preserving for faces. Returns
    (vertices, faces, counts).
    """
    counts = {"faces_in": int(len(faces)), "vertices_in": int(len(vertices))}
    used = np.nonzero(np.bincount(faces.ravel(), minlength=len(vertices)))[0]
    # merge exactly identical positions (np.unique sorts; map back to first appearance
    # order so the output does not depend on how the file ordered duplicates)
    first, inverse = unique_rows(vertices[used])
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = inverse
    new_vertices = vertices[used][first]
    faces = remap[faces]
    counts["merged_vertices"] = int(len(used) - len(new_vertices))
    counts["unreferenced_vertices"] = int(len(vertices) - len(used))

    degenerate = degenerate_faces(new_vertices, faces)
    counts["degenerate_faces"] = int(degenerate.sum())
    faces = faces[~degenerate]
    if len(faces):
        faces = _drop_duplicate_faces(faces, cancel_fins)
        counts["duplicate_faces"] = int(counts["faces_in"] - counts["degenerate_faces"] - len(faces))
    else:
        counts["duplicate_faces"] = 0
    # vertices left unused by dropped faces
    used2 = np.nonzero(np.bincount(faces.ravel(), minlength=len(new_vertices)))[0]
    if len(used2) < len(new_vertices):
        counts["unreferenced_vertices"] += int(len(new_vertices) - len(used2))
        remap2 = np.full(len(new_vertices), -1, dtype=np.int64)
        remap2[used2] = np.arange(len(used2))
        new_vertices = new_vertices[used2]
        faces = remap2[faces]
    return new_vertices, faces.astype(np.int64), counts


def _drop_duplicate_faces(faces: np.ndarray, cancel_fins: bool = True) -> np.ndarray:
    """Faces on the same three vertices: without ``cancel_fins`` the first one stays.
    With it, copies with the same winding collapse to one and pairs with opposite
    windings cancel (a zero-thickness fin, which edge collapses leave behind; keeping
    one of them would open the surface)."""
    first, group = unique_rows(np.sort(faces, axis=1))
    if not cancel_fins:
        return faces[first]
    # winding of each face relative to its sorted vertex order: +1 even, -1 odd permutation
    rot = np.argmin(faces, axis=1)
    r = faces[np.arange(len(faces))[:, None], (rot[:, None] + np.arange(3)) % 3]
    parity = np.where(r[:, 1] < r[:, 2], 1, -1)
    net = np.bincount(group, weights=parity, minlength=len(first)).astype(np.int64)
    # keep the first face (in file order) whose winding has the majority; none if tied
    order = np.lexsort((np.arange(len(faces)), group))
    g_sorted, p_sorted = group[order], parity[order]
    want = np.sign(net)[g_sorted]
    cand = order[(p_sorted == want) & (want != 0)]
    gc = group[cand]
    firsts = np.r_[True, gc[1:] != gc[:-1]] if len(cand) else np.zeros(0, dtype=bool)
    keep = np.sort(cand[firsts])
    return faces[keep]


def degenerate_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Mask of faces with a repeated vertex or zero area (height <= DEGENERATE_HEIGHT_REL
    * longest edge)."""
    tri = vertices[faces]
    e = tri[:, [1, 2, 0]] - tri
    longest = np.linalg.norm(e, axis=2).max(axis=1)
    area2 = np.linalg.norm(np.cross(e[:, 0], -e[:, 2]), axis=1)     # 2 * area
    # height = 2*area / longest  <=  eps * longest
    return ((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
            | (area2 <= C.DEGENERATE_HEIGHT_REL * longest * longest))


def _orient_closed_bodies(vertices, faces, labels, nbodies):
    """Flip every closed body whose signed volume is negative (wound inside-out)."""
    vol = np.bincount(labels, weights=signed_volumes(vertices, faces), minlength=nbodies)
    flip = np.zeros(nbodies, dtype=bool)
    for b in np.nonzero(vol < 0)[0]:
        if is_closed(faces[labels == b]):
            flip[b] = True
    if flip.any():
        faces = faces.copy()
        sel = flip[labels]
        faces[sel] = faces[sel][:, ::-1]
    return faces, int(flip.sum())
