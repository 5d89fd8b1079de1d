"""Reading and validating a bundle: one Problem per issue, with the spec's error class
(io, version, schema, hash, mesh, atlas, pieces); read_bundle raises the first."""
from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path

import numpy as np

from hbake import constants as C
from hbake.bundle.exr import _compression_name, _exr, _open_exr
from hbake.bundle.exrheader import ExrHeaderError, check_exr_header
from hbake.bundle.format import (
    _MAX_EXAMPLES,
    ATLAS_COMPRESSIONS,
    ERROR_CLASSES,
    FILE_NAMES,
    FORMAT_MAJOR,
    FORMAT_NAME,
    MAX_FILE_BYTES,
    MAX_JSON_DEPTH,
    MAX_MANIFEST_BYTES,
    MAX_VERSION_CHARS,
    Bundle,
    Problem,
    _atlas_size_ok,
    _bbox_diagonal,
    _examples,
    _Fail,
    _n,
    _short,
    _too_large,
    convexity_tolerance,
)
from hbake.bundle.manifest import (
    _has_lone_surrogate,
    _json_depth,
    _loader_schema_rules,
    load_schema,
)
from hbake.bundle.pieces import (
    _CHUNK_FACES,
    MAX_PIECE_FACES,
    MAX_PIECE_VERTICES,
    _piece_invariants,
)
from hbake.bundle.ply import _parse_coarse, _parse_pieces
from hbake.bundle.uv_coverage import (
    _coverage_check,
    _Footprints,
    _work_limit,
    _work_problem,
)
from hbake.errors import (
    BundleError,
)
from hbake.fileio import FileTooLargeError, read_regular

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
