"""The validator's check that every texel a coarse UV triangle needs holds a height
(docs/bundle-format.md, "Atlas coverage"), bounded in work before it runs."""
from __future__ import annotations

import numpy as np

from hbake.bundle.lookup import texel_coords

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
