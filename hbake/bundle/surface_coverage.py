"""Where the mesh heights' guarantee holds: the atlas quads inside the coarse UV triangles,
and those a discontinuity cuts (docs/bundle-format.md, "Heights over a texel's square").

A reader of the spec, independent of the runtime's code: the same definitions as `hrt
check`'s ``surface`` (hrt::surface_coverage), written from the spec with numpy. The
runtime reads each coarse face's full surface as the atlas quads whose centre lies in
the face's UV triangle; a quad is *usable* when its four texels are filled (within the
gutter of a covered texel) and none of its four edges is longer than the discontinuity
rule (``rule_texels`` = 4 atlas texel sizes). A cut quad holds no surface, so the
surface between its corners is missing from the mesh heights.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from hbake.bundle import BundleData, texel_coords

# The discontinuity rule (docs/bundle-format.md, "Discontinuities"): 4 texel sizes.
RULE_TEXELS = 4.0
# The spec's default gutter, for a manifest without atlas.gutter.
DEFAULT_GUTTER = 4
# Candidates (quad centres in a face's box) tested at once, and atlas rows of quads whose
# edges are measured at once: both bound the memory (an 8192-wide atlas row band of 128
# quads holds 4 x 1 M edge lengths) whatever the atlas and the faces' sizes.
_CANDIDATES = 1 << 21
_ROWS = 128


def filled_mask(alpha: np.ndarray, gutter: int) -> np.ndarray:
    """Texels within `gutter` (Chebyshev) of a covered texel (alpha != 0)."""
    g = max(1, int(gutter))
    return ndimage.maximum_filter(alpha != 0, size=2 * g + 1, mode="constant", cval=False)


def _edge_sq(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    d = (p - q).astype(np.float64)
    return d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]


def _quad_edges(pos: np.ndarray) -> np.ndarray:
    """Squared lengths of each quad's four edges, (4, rows - 1, W - 1), for the texel rows
    `pos` holds."""
    a, b, c, d = pos[:-1, :-1], pos[:-1, 1:], pos[1:, :-1], pos[1:, 1:]
    return np.stack([_edge_sq(a, b), _edge_sq(c, d), _edge_sq(a, c), _edge_sq(b, d)])


def _boxes(xy: np.ndarray, W: int, H: int):
    """Per face with a non-degenerate UV triangle, its corners and its box of quad indices,
    the box cut into bands of rows so that no band holds more than _CANDIDATES quads:
    (face, i0, i1, j0, j1) arrays, one entry per band."""
    ax, ay = xy[..., 0], xy[..., 1]
    e1x, e1y = ax[:, 1] - ax[:, 0], ay[:, 1] - ay[:, 0]
    e2x, e2y = ax[:, 2] - ax[:, 0], ay[:, 2] - ay[:, 0]
    keep = np.abs(e1x * e2y - e2x * e1y) > 1e-12
    i0 = np.clip(np.floor(ax.min(axis=1) - 0.5), 0, W - 2).astype(np.int64)
    i1 = np.clip(np.ceil(ax.max(axis=1) - 0.5), 0, W - 2).astype(np.int64)
    j0 = np.clip(np.floor(ay.min(axis=1) - 0.5), 0, H - 2).astype(np.int64)
    j1 = np.clip(np.ceil(ay.max(axis=1) - 0.5), 0, H - 2).astype(np.int64)
    f = np.nonzero(keep)[0]
    i0, i1, j0, j1 = i0[f], i1[f], j0[f], j1[f]
    rows = np.maximum(1, _CANDIDATES // (i1 - i0 + 1))          # rows per band
    bands = (j1 - j0) // rows + 1
    owner = np.repeat(np.arange(len(f)), bands)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(bands) - bands, bands)
    bj0 = j0[owner] + k * rows[owner]
    bj1 = np.minimum(bj0 + rows[owner] - 1, j1[owner])
    return f[owner], i0[owner], i1[owner], bj0, bj1


def _mark_inside(xy: np.ndarray, inside: np.ndarray) -> None:
    """Sets inside[j, i] for every quad whose centre (i + 0.5, j + 0.5) lies in a UV
    triangle (barycentrics >= 0, in the runtime's arithmetic)."""
    H1, W1 = inside.shape
    face, i0, i1, j0, j1 = _boxes(xy, W1 + 1, H1 + 1)
    counts = (i1 - i0 + 1) * (j1 - j0 + 1)
    ends = np.cumsum(counts)
    start = 0
    while start < len(face):
        # The bands of this batch: at most _CANDIDATES quads (one band alone may reach it).
        stop = max(start + 1, int(np.searchsorted(ends, (ends[start] - counts[start]) + _CANDIDATES, "right")))
        sl = slice(start, stop)
        f, bi0, bj0, nw, cnt = face[sl], i0[sl], j0[sl], (i1 - i0 + 1)[sl], counts[sl]
        owner = np.repeat(np.arange(len(f)), cnt)
        k = np.arange(len(owner)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        i = bi0[owner] + k % nw[owner]
        j = bj0[owner] + k // nw[owner]
        t = xy[f[owner]]
        ax, ay = t[:, :, 0], t[:, :, 1]
        e1x, e1y = ax[:, 1] - ax[:, 0], ay[:, 1] - ay[:, 0]
        e2x, e2y = ax[:, 2] - ax[:, 0], ay[:, 2] - ay[:, 0]
        area2 = e1x * e2y - e2x * e1y
        dx = i + 0.5 - ax[:, 0]
        dy = j + 0.5 - ay[:, 0]
        b1 = (dx * e2y - e2x * dy) / area2
        b2 = (e1x * dy - dx * e1y) / area2
        hit = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1)
        inside[j[hit], i[hit]] = True
        start = stop


def surface_coverage(data: BundleData) -> dict:
    """``{"quads", "cut_quads", "widest_cut"}``: the atlas quads whose centre lies inside a
    coarse UV triangle (each counted once), those of them that are not usable, and the
    longest edge of a cut quad (m; 0 when none). Memory: the atlas, two byte masks of its
    size, and bounded batches."""
    atlas = np.asarray(data.atlas)
    H, W = atlas.shape[:2]
    out = {"quads": 0, "cut_quads": 0, "widest_cut": 0.0}
    if W < 2 or H < 2 or len(data.coarse_faces) == 0:
        return out
    atlas_m = data.manifest.get("atlas", {}) if isinstance(data.manifest, dict) else {}
    gutter = atlas_m.get("gutter", DEFAULT_GUTTER)
    texel = float(data.manifest.get("quality", {}).get("texel_size", 0.0) or atlas_m.get("texel_size", 0.0))
    filled = filled_mask(atlas[..., 3], gutter if isinstance(gutter, int) else DEFAULT_GUTTER)
    jump2 = (RULE_TEXELS * texel) ** 2 if texel > 0 else 0.0

    inside = np.zeros((H - 1, W - 1), dtype=bool)
    xy = texel_coords(np.asarray(data.coarse_uvs, dtype=np.float32).astype(np.float64), W, H)  # (F, 3, 2)
    _mark_inside(xy, inside)

    # Quad (i, j) spans texels (i, j) .. (i + 1, j + 1), by bands of rows. The rule on
    # positions in double (float32 texels widened first); the widest cut from float32
    # differences (hrt::surface_coverage does both so).
    widest = 0.0
    for r0 in range(0, H - 1, _ROWS):
        r1 = min(r0 + _ROWS, H - 1)
        pos = atlas[r0:r1 + 1, :, :3]
        f = filled[r0:r1 + 1]
        ok = f[:-1, :-1] & f[:-1, 1:] & f[1:, :-1] & f[1:, 1:]
        if jump2 > 0:
            ok &= np.all(_quad_edges(pos.astype(np.float64)) <= jump2, axis=0)
        band = inside[r0:r1]
        cut = band & ~ok
        out["quads"] += int(band.sum())
        n_cut = int(cut.sum())
        if n_cut:
            out["cut_quads"] += n_cut
            e = np.sqrt(_quad_edges(pos)[:, cut])
            e = e[np.isfinite(e)]
            if e.size:
                widest = max(widest, float(e.max()))
    out["widest_cut"] = widest
    return out
