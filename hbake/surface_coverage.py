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
# Faces per batch of the vectorized centre test (bounds the candidates held at once).
_FACE_BATCH = 4096


def filled_mask(alpha: np.ndarray, gutter: int) -> np.ndarray:
    """Texels within `gutter` (Chebyshev) of a covered texel (alpha != 0)."""
    g = max(1, int(gutter))
    return ndimage.maximum_filter(alpha != 0, size=2 * g + 1, mode="constant", cval=False)


def _edge_sq(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    d = (p - q).astype(np.float64)
    return d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]


def _quad_edges(pos: np.ndarray) -> np.ndarray:
    """Squared lengths of each quad's four edges, (4, H - 1, W - 1)."""
    a, b, c, d = pos[:-1, :-1], pos[:-1, 1:], pos[1:, :-1], pos[1:, 1:]
    return np.stack([_edge_sq(a, b), _edge_sq(c, d), _edge_sq(a, c), _edge_sq(b, d)])


def surface_coverage(data: BundleData) -> dict:
    """``{"quads", "cut_quads", "widest_cut"}``: the atlas quads whose centre lies inside a
    coarse UV triangle (each counted once), those of them that are not usable, and the
    longest edge of a cut quad (m; 0 when none)."""
    atlas = np.asarray(data.atlas)
    H, W = atlas.shape[:2]
    out = {"quads": 0, "cut_quads": 0, "widest_cut": 0.0}
    if W < 2 or H < 2 or len(data.coarse_faces) == 0:
        return out
    atlas_m = data.manifest.get("atlas", {}) if isinstance(data.manifest, dict) else {}
    gutter = atlas_m.get("gutter", DEFAULT_GUTTER)
    texel = float(data.manifest.get("quality", {}).get("texel_size", 0.0) or atlas_m.get("texel_size", 0.0))
    pos = atlas[..., :3]
    filled = filled_mask(atlas[..., 3], gutter if isinstance(gutter, int) else DEFAULT_GUTTER)

    # Quad (i, j) spans texels (i, j) .. (i + 1, j + 1); i <= W - 2, j <= H - 2.
    f4 = filled[:-1, :-1] & filled[:-1, 1:] & filled[1:, :-1] & filled[1:, 1:]
    # The rule on positions in double (float32 texels widened first); the widest cut
    # below from float32 differences (hrt::surface_coverage does both so).
    edges = _quad_edges(pos.astype(np.float64))
    jump2 = (RULE_TEXELS * texel) ** 2 if texel > 0 else 0.0
    ok = f4 & (np.all(edges <= jump2, axis=0) if jump2 > 0 else True)

    # Every quad centre (i + 0.5, j + 0.5) inside a UV triangle (barycentrics >= 0).
    xy = texel_coords(np.asarray(data.coarse_uvs, dtype=np.float32).astype(np.float64), W, H)  # (F, 3, 2)
    inside = np.zeros((H - 1, W - 1), dtype=bool)
    for s in range(0, len(xy), _FACE_BATCH):
        t = xy[s:s + _FACE_BATCH]
        ax, ay = t[..., 0], t[..., 1]
        e1x, e1y = ax[:, 1] - ax[:, 0], ay[:, 1] - ay[:, 0]
        e2x, e2y = ax[:, 2] - ax[:, 0], ay[:, 2] - ay[:, 0]
        area2 = e1x * e2y - e2x * e1y
        keep = np.abs(area2) > 1e-12
        i0 = np.clip(np.floor(ax.min(axis=1) - 0.5), 0, W - 2).astype(np.int64)
        i1 = np.clip(np.ceil(ax.max(axis=1) - 0.5), 0, W - 2).astype(np.int64)
        j0 = np.clip(np.floor(ay.min(axis=1) - 0.5), 0, H - 2).astype(np.int64)
        j1 = np.clip(np.ceil(ay.max(axis=1) - 0.5), 0, H - 2).astype(np.int64)
        nw = np.where(keep, i1 - i0 + 1, 0)
        nh = np.where(keep, j1 - j0 + 1, 0)
        counts = nw * nh
        owner = np.repeat(np.arange(len(t)), counts)
        k = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
        i = i0[owner] + k % nw[owner]
        j = j0[owner] + k // nw[owner]
        dx = i + 0.5 - ax[owner, 0]
        dy = j + 0.5 - ay[owner, 0]
        b1 = (dx * e2y[owner] - e2x[owner] * dy) / area2[owner]
        b2 = (e1x[owner] * dy - dx * e1y[owner]) / area2[owner]
        hit = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1)
        inside[j[hit], i[hit]] = True

    cut = inside & ~ok
    out["quads"] = int(inside.sum())
    out["cut_quads"] = int(cut.sum())
    if out["cut_quads"]:
        e = np.sqrt(_quad_edges(pos)[:, cut])
        e = e[np.isfinite(e)]
        out["widest_cut"] = float(e.max()) if e.size else 0.0
    return out
