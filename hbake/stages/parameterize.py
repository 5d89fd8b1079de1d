"""Stage 3: parameterize the coarse mesh into a texture atlas (xatlas).

xatlas cuts the coarse mesh into charts, flattens and packs them. Its ``resolution``
alone is not a hard cap (a 600-triangle hammer asked for 1024 comes out 1444 x 759), so
the texel density ``texels_per_unit`` is searched by bisection for the densest packing
that fits: for a square atlas, xatlas packs into pages of exactly ``W x W`` and the
search keeps a single page; for a non-square one, xatlas sizes one atlas to the content
(``resolution = 0``) and the search keeps it within ``W x H``. The search also refuses a
packing in which xatlas shrank a chart to fit (it does that to charts larger than its
page, leaving the others at the requested density): every chart gets one texel density,
which is what the manifest's texel size and the Sec. 7.2 resolution limit assume.
Then a chart longer than the page caps the density of the whole atlas (the hammer's
handle: 41.6 % of the page covered), so the search is repeated on xatlas's charts with
those longer than each of C.PACK_SPLIT_FRACTIONS of the page cut across into slabs
(``split_long_charts``; xatlas packs them as given, ``use_input_mesh_uvs``), and the
densest packing is kept; on a tie, xatlas's own.
Charts keep ``padding``
texels between them and
xatlas's ``bilinear`` margin, so a bilinear lookup inside one chart never reads a texel
another chart covers.

xatlas's tolerances are absolute (it ignores faces of area below FLT_EPSILON in its
units, among others), so a small part is handed to it scaled up by a power of two
(``xatlas_scale``; constants.XATLAS_MIN_MEDIAN_FACE_AREA says why and how far) with the
texel density divided by the same factor: exact in float32, the UVs are those of the part
in meters, and a part scaled by 2^j gets the same UVs.

Output UVs are per corner, normalised to the requested atlas in the convention of
docs/bundle-format.md: texel column ``x = u W - 0.5``, row ``y = (1 - v) H - 0.5``
(row 0 at the top, v up). xatlas's pixel grid maps to texel rows from the top, so a
chart texel of xatlas is a texel of the bundle's atlas.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hbake import constants as C
from hbake.errors import BakeFailedError
from hbake.stages.geometry import face_areas
from hbake.settings import ParameterizeSettings


@dataclass
class Parameterization:
    uvs: np.ndarray            # (M, 3, 2) float32 per-corner UVs in [0, 1]
    width: int                 # atlas size (texels), as requested
    height: int
    packed_width: int          # extent xatlas used (<= width, height)
    packed_height: int
    charts: int
    texels_per_unit: float     # texels per meter
    utilization: float         # fraction of the packed extent covered by charts


def parameterize(vertices: np.ndarray, faces: np.ndarray,
                 settings: ParameterizeSettings | None = None, *,
                 split_long: bool = True) -> Parameterization:
    """Charts and packing of the coarse mesh (see the module doc). ``split_long``: also
    try the packings with long charts cut into slabs (the cage route); False keeps
    xatlas's own charts whole (the preserve route, whose seams follow them)."""
    settings = settings or ParameterizeSettings()
    W, H = settings.atlas_width, settings.atlas_height
    area = float(face_areas(vertices, faces).sum())
    if not area > 0:
        raise BakeFailedError("cannot parameterize: the coarse mesh has no area")

    scale = xatlas_scale(vertices, faces)
    best = _search(vertices, faces, settings, area, uniform=True, scale=scale)
    if best is not None and split_long:
        best = _split_and_repack(vertices, faces, settings, area, scale, best)
    if best is None:
        # Every chart at one density never fitted (cannot happen with xatlas's own charts,
        # which fit at a small enough density; kept so a future xatlas cannot fail a bake).
        best = _search(vertices, faces, settings, area, uniform=False, scale=scale)
    if best is None:
        raise BakeFailedError(f"could not pack the charts into a {W}x{H} atlas")
    best.uvs = attach_unmapped_faces(vertices, faces, best.uvs, W, H)
    best.uvs = snap_small_charts(faces, best.uvs, W, H)
    return best


def xatlas_scale(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The power of two (>= 1) by which the coarse mesh is scaled for xatlas: the least
    one that brings the median face area to XATLAS_MIN_MEDIAN_FACE_AREA, so that xatlas's
    absolute tolerances (its zero-area rule above all) see a part of ordinary size; 1 for
    parts already that large. Capped so that no scaled coordinate passes
    XATLAS_MAX_SCALED_COORDINATE. Areas of a mesh scaled by 2^j are exactly 4^j times
    these, so such a mesh gets the same scaled mesh (module doc)."""
    v = np.asarray(vertices, dtype=np.float64)
    med = float(np.median(face_areas(v, np.asarray(faces, dtype=np.int64))))
    if not med > 0 or med >= C.XATLAS_MIN_MEDIAN_FACE_AREA:
        return 1.0
    k = 0                       # the least k with med * 4^k >= the threshold (exact)
    while math.ldexp(med, 2 * k) < C.XATLAS_MIN_MEDIAN_FACE_AREA:
        k += 1
    reach = float(np.abs(v).max())
    while k > 0 and math.ldexp(reach, k) > C.XATLAS_MAX_SCALED_COORDINATE:
        k -= 1
    return math.ldexp(1.0, k)


def _split_and_repack(vertices, faces, settings, area, scale, best):
    """The densest of ``best`` (xatlas's own charts) and the packings of the same charts
    with those longer than C.PACK_SPLIT_FRACTIONS of the page cut across (see the module
    doc). A tie keeps the earlier candidate, so the choice is deterministic."""
    W, H = settings.atlas_width, settings.atlas_height
    fill = math.sqrt(W * H / area)             # texels per meter that would fill W x H
    chart_uvs = _chart_uvs(vertices, faces, settings, fill, scale)
    if chart_uvs is None:
        return best
    seen = set()
    for frac in C.PACK_SPLIT_FRACTIONS:
        # the page's shorter side at the fill density, in meters
        uvs, pieces = split_long_charts(faces, chart_uvs, frac * min(W, H) / fill)
        if pieces is None or pieces in seen:
            continue                            # nothing cut, or the same cut as before
        seen.add(pieces)
        res = _search(vertices, faces, settings, area, uniform=True, scale=scale,
                      input_uvs=uvs)
        if res is not None and res.texels_per_unit > best.texels_per_unit:
            best = res
    return best


def _chart_uvs(vertices, faces, settings, texels_per_unit, scale) -> np.ndarray | None:
    """xatlas's charts of the mesh, flattened: per-corner (M, 3, 2) UVs in meters (one
    UV unit is one meter on the surface, up to xatlas's distortion), charts apart in UV.
    None when xatlas left a face out of every chart."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(np.asarray(vertices, dtype=np.float64) * scale,
                                        dtype=np.float32),
                   np.ascontiguousarray(faces, dtype=np.uint32))
    po = xatlas.PackOptions()
    po.resolution = 0                     # one atlas sized to the content
    po.texels_per_unit = float(texels_per_unit) / scale
    po.padding = int(settings.padding)
    po.bilinear = True
    atlas.generate(_chart_options(settings), po)
    vmap, idx, uv = atlas.get_mesh(0)
    idx = np.asarray(idx, dtype=np.int64).reshape(-1, 3)
    if idx.shape != faces.shape or not np.array_equal(np.asarray(vmap, dtype=np.int64)[idx], faces):
        return None
    px = np.asarray(uv, dtype=np.float64)[idx] * np.array([atlas.width, atlas.height], dtype=np.float64)
    return px / float(texels_per_unit)


def split_long_charts(faces: np.ndarray, uvs: np.ndarray, cap: float):
    """Cut every chart of per-corner ``uvs`` whose longer side passes ``cap`` (UV units)
    across that side into ceil(side / cap) slabs of equal width (a face goes to the slab
    of its centroid), and move every piece to a cell of its own so that no two pieces
    share a UV edge. Returns the new UVs (same shape, float64) and the number of pieces,
    or (uvs, None) when no chart is that long. The flattening inside a piece is
    unchanged, only translated."""
    charts = chart_labels(faces, uvs.astype(np.float32))
    piece = charts.copy()
    nxt = int(charts.max()) + 1
    cut = False
    for c in range(int(charts.max()) + 1):
        members = np.nonzero(charts == c)[0]
        p = uvs[members].reshape(-1, 2)
        lo, ext = p.min(axis=0), p.max(axis=0) - p.min(axis=0)
        ax = int(np.argmax(ext))
        k = int(math.ceil(ext[ax] / cap)) if cap > 0 else 1
        if k <= 1:
            continue
        cut = True
        centroid = uvs[members, :, ax].mean(axis=1)
        slab = np.minimum(((centroid - lo[ax]) / ext[ax] * k).astype(np.int64), k - 1)
        for j in range(1, k):
            sel = members[slab == j]
            if len(sel):
                piece[sel] = nxt
                nxt += 1
    if not cut:
        return uvs, None
    ids, piece = np.unique(piece, return_inverse=True)
    n = len(ids)
    out = np.zeros_like(uvs, dtype=np.float64)
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, piece, uvs.min(axis=1))
    np.maximum.at(hi, piece, uvs.max(axis=1))
    cell = float((hi - lo).max()) * 1.25 + 1e-9
    cols = int(math.ceil(math.sqrt(n)))
    origin = np.stack([np.arange(n) % cols, np.arange(n) // cols], axis=1) * cell
    out[:] = uvs - lo[piece][:, None, :] + origin[piece][:, None, :]
    return out, n


def _chart_options(settings):
    import xatlas

    co = xatlas.ChartOptions()
    co.max_cost = float(settings.max_chart_cost)
    co.normal_deviation_weight = float(settings.normal_deviation_weight)
    return co


def _search(vertices, faces, settings, area, uniform, scale=1.0, input_uvs=None):
    """Bisection for the densest packing that fits one W x H page (see the module doc)."""
    W, H = settings.atlas_width, settings.atlas_height
    # Start from the density at which the charts, without padding or distortion, would
    # fill W x H; walk up while that fits, or down until it fits, then bisect between
    # fitting and not fitting.
    lo = hi = math.sqrt(W * H / area)
    best = None
    for _ in range(C.PACK_SEARCH_MAX_STEPS):
        res = _pack(vertices, faces, settings, hi, uniform, scale, input_uvs)
        if res is None:
            break
        lo, best = hi, res
        hi *= 1.4
    if best is None:
        for _ in range(C.PACK_SEARCH_MAX_STEPS):
            lo *= 0.7
            res = _pack(vertices, faces, settings, lo, uniform, scale, input_uvs)
            if res is not None:
                best = res
                break
            hi = lo
    if best is None:
        return None
    steps = 0
    while hi / lo > C.PACK_SEARCH_RATIO and steps < C.PACK_SEARCH_MAX_STEPS:
        mid = math.sqrt(lo * hi)
        res = _pack(vertices, faces, settings, mid, uniform, scale, input_uvs)
        if res is not None:
            lo, best = mid, res
        else:
            hi = mid
        steps += 1
    return best


def attach_unmapped_faces(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                          W: int, H: int) -> np.ndarray:
    """Give faces that xatlas left without area in UV space (it parks the slivers it
    cannot flatten at UV (0, 0)) the UVs of the edge they share with a mapped neighbour,
    preferring their longest edge: the two shared corners take the neighbour's UVs and the
    third corner the UV of its projection onto that edge. Their lookups then read the neighbour's texels, which
    describe the same thin strip of surface."""
    p = texel_coordinates(uvs, W, H)
    e = np.roll(p, -1, axis=1) - p
    area2 = np.abs(e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0])
    bad = area2 <= C.UV_DEGENERATE_TEXELS2
    if not bad.any():
        return uvs
    uvs = uvs.copy()
    # directed edge (a, b) of face f at corner k -> (f, k); a neighbour across the edge
    # has the directed edge (b, a)
    edge_of = {}
    for f in np.nonzero(~bad)[0]:
        for k in range(3):
            edge_of[(int(faces[f, k]), int(faces[f, (k + 1) % 3]))] = (int(f), k)
    todo = list(np.nonzero(bad)[0])
    while todo:
        left = []
        for f in todo:
            done = False
            # Longest edge first: these faces are caps (a vertex on or near the opposite
            # edge), and only across their long edge does the third vertex project inside
            # the shared edge; across a short one it would be clamped to an end and the
            # face's lookups would read surface texels up to the face's length away.
            length = np.linalg.norm(vertices[faces[f]] - vertices[np.roll(faces[f], -1)], axis=1)
            for k in np.argsort(-length, kind="stable"):
                a, b = int(faces[f, k]), int(faces[f, (k + 1) % 3])
                hit = edge_of.get((b, a))
                if hit is None:
                    continue
                g, j = hit                                        # g's corner j is b, j+1 is a
                uv_b, uv_a = uvs[g, j].astype(np.float64), uvs[g, (j + 1) % 3].astype(np.float64)
                c = int(faces[f, (k + 2) % 3])
                va, vb, vc = vertices[a], vertices[b], vertices[c]
                d = vb - va
                t = float(np.clip(np.dot(vc - va, d) / max(np.dot(d, d), 1e-300), 0.0, 1.0))
                uvs[f, k] = uv_a
                uvs[f, (k + 1) % 3] = uv_b
                uvs[f, (k + 2) % 3] = (1 - t) * uv_a + t * uv_b
                for kk in range(3):                              # now a mapped neighbour
                    edge_of[(int(faces[f, kk]), int(faces[f, (kk + 1) % 3]))] = (int(f), kk)
                done = True
                break
            if not done:
                left.append(f)
        if len(left) == len(todo):
            break                      # isolated: no mapped neighbour anywhere
        todo = left
    return uvs


def texel_candidates(lo: np.ndarray, hi: np.ndarray, chunk: int = 1 << 18):
    """Texel centres (t, i, j) in the integer boxes [lo, hi] of triangles t, in groups of
    about ``chunk`` candidates (whole triangles per group), so memory stays bounded."""
    nx = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    ny = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    count = nx * ny
    m = len(count)
    if m == 0:
        return
    cum = np.cumsum(count)
    edges = np.unique(np.r_[0, np.searchsorted(cum, np.arange(chunk, cum[-1], chunk)) + 1, m])
    for start, end in zip(edges[:-1], edges[1:]):
        sel = np.arange(start, end)
        cnt = count[sel]
        tot = int(cnt.sum())
        if tot == 0:
            continue
        t = np.repeat(sel, cnt)
        k = np.arange(tot) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        yield t, lo[t, 0] + k % nx[t], lo[t, 1] + k // nx[t]


def texel_coordinates(uvs: np.ndarray, W: int, H: int) -> np.ndarray:
    """Continuous texel coordinates (x, y) of UVs (texel centres at integers, row 0 on top)."""
    p = np.zeros(uvs.shape[:-1] + (2,))
    p[..., 0] = uvs[..., 0].astype(np.float64) * W - 0.5
    p[..., 1] = (1.0 - uvs[..., 1].astype(np.float64)) * H - 0.5
    return p


def barycentric_2d(q, a, b, c):
    """Barycentric coordinates of 2D points q in triangles (a, b, c); may be negative."""
    v0, v1, v2 = b - a, c - a, q - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(den == 0, 1e-300, den)
    beta = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    gamma = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    return np.stack([1.0 - beta - gamma, beta, gamma], axis=1)


def covered_triangles(uvs: np.ndarray, W: int, H: int) -> np.ndarray:
    """Whether each UV triangle contains at least one texel centre."""
    p = texel_coordinates(uvs, W, H)
    lo = np.maximum(np.ceil(p.min(axis=1)).astype(np.int64), 0)
    hi = np.minimum(np.floor(p.max(axis=1)).astype(np.int64), [W - 1, H - 1])
    hit = np.zeros(len(uvs), dtype=bool)
    for t, i, j in texel_candidates(lo, hi):
        q = np.stack([i, j], axis=1).astype(np.float64)
        bary = barycentric_2d(q, p[t, 0], p[t, 1], p[t, 2])
        hit[t[bary.min(axis=1) >= -C.INSIDE_EPS]] = True
    return hit


def snap_small_charts(faces: np.ndarray, uvs: np.ndarray, W: int, H: int) -> np.ndarray:
    """Shift every chart that contains no texel centre by less than half a texel so that
    the centroid of its largest UV triangle lands on a texel centre.

    A chart smaller than a texel (slivers) may cover no texel centre; its lookups would
    then read only gutter texels, which docs/bundle-format.md defines around covered
    texels. After the shift the chart covers at least that texel. xatlas keeps charts
    ``padding`` (>= 2) texels plus a bilinear margin apart, so a shift of at most half a
    texel per axis keeps them apart.
    """
    charts = chart_labels(faces, uvs)
    has = np.zeros(charts.max() + 1, dtype=bool)
    has[charts[covered_triangles(uvs, W, H)]] = True
    if has.all():
        return uvs
    uvs = uvs.copy()
    px = texel_coordinates(uvs, W, H)
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    for chart in np.nonzero(~has)[0]:
        members = np.nonzero(charts == chart)[0]
        t = members[np.argmax(area[members])]
        centroid = px[t].mean(axis=0)
        target = np.clip(np.round(centroid), 0, [W - 1, H - 1])
        dx, dy = target - centroid
        uvs[members, :, 0] = np.clip(uvs[members, :, 0].astype(np.float64) + dx / W, 0, 1)
        uvs[members, :, 1] = np.clip(uvs[members, :, 1].astype(np.float64) - dy / H, 0, 1)
    return uvs


def _pack(vertices, faces, settings: ParameterizeSettings, texels_per_unit: float,
          uniform: bool = True, scale: float = 1.0,
          input_uvs: np.ndarray | None = None) -> Parameterization | None:
    """Pack at the given density (texels per meter); None when the charts do not fit one
    W x H atlas (or, with ``uniform``, when xatlas had to shrink a chart to make them fit).
    xatlas gets the vertices times ``scale`` (a power of two, see xatlas_scale) and the
    density divided by it, which is the same packing in texels. With ``input_uvs``
    (per-corner UVs in meters, from split_long_charts) xatlas packs those charts as they
    are (``use_input_mesh_uvs``, one vertex per corner) instead of making its own."""
    import xatlas

    W, H = settings.atlas_width, settings.atlas_height
    atlas = xatlas.Atlas()
    # vertices hold float32 values; times a power of two they stay exact
    v = np.asarray(vertices, dtype=np.float64) * scale
    if input_uvs is None:
        atlas.add_mesh(np.ascontiguousarray(v, dtype=np.float32),
                       np.ascontiguousarray(faces, dtype=np.uint32))
        co = _chart_options(settings)
        corners = faces
    else:
        corners = np.arange(3 * len(faces), dtype=np.int64).reshape(-1, 3)
        atlas.add_mesh(np.ascontiguousarray(v[faces].reshape(-1, 3), dtype=np.float32),
                       np.ascontiguousarray(corners, dtype=np.uint32), None,
                       np.ascontiguousarray(np.asarray(input_uvs, dtype=np.float64).reshape(-1, 2)
                                            * scale, dtype=np.float32))
        co = xatlas.ChartOptions()
        co.use_input_mesh_uvs = True
    po = xatlas.PackOptions()
    po.resolution = W if W == H else 0
    po.texels_per_unit = float(texels_per_unit) / scale
    po.padding = int(settings.padding)
    po.bilinear = True
    po.bruteForce = False
    po.rotate_charts = True
    atlas.generate(co, po)
    w, h = int(atlas.width), int(atlas.height)
    if atlas.atlas_count != 1 or w > W or h > H:
        return None
    vmap, idx, uv = atlas.get_mesh(0)
    idx = np.asarray(idx, dtype=np.int64).reshape(-1, 3)
    vmap = np.asarray(vmap, dtype=np.int64)
    if idx.shape != faces.shape or not np.array_equal(vmap[idx], corners):
        raise BakeFailedError("xatlas changed the face order of the coarse mesh")
    # xatlas's normalised uv times its size is the position in texels from the top-left
    # corner of its atlas; place that at the top-left of the W x H atlas.
    px = np.asarray(uv, dtype=np.float64)[idx] * np.array([w, h], dtype=np.float64)
    if uniform and not _uniform_density(vertices, faces, px, texels_per_unit):
        return None
    u = px[..., 0] / W
    v = 1.0 - px[..., 1] / H
    uvs = np.stack([u, v], axis=-1).astype(np.float32)
    uvs = np.clip(uvs, 0.0, 1.0)
    return Parameterization(uvs=uvs, width=W, height=H, packed_width=w, packed_height=h,
                            charts=int(atlas.chart_count), texels_per_unit=float(texels_per_unit),
                            utilization=float(atlas.utilization[0]) if hasattr(atlas.utilization, "__len__") else float(atlas.utilization))


def _uniform_density(vertices, faces, px, texels_per_unit) -> bool:
    """Whether every chart has (about) the requested texel density.

    xatlas scales down a chart that would not fit its page on its own, while the others
    keep the density asked for. On a long bar (the procedural rasp: 160 mm faces, 6 mm
    end caps) that gave the end caps 8 times the faces' density and 66 % of the texels,
    so the texel size of the toothed faces, the ones that matter, was 8 times the
    manifest's. One density for the whole mesh is what the texel size and the Sec. 7.2
    resolution limit mean, so such a packing counts as not fitting and the search lowers
    the density until every chart fits at it.
    """
    tri = np.asarray(vertices, dtype=np.float64)[faces]
    area3 = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    areat = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    # Per chart (xatlas's scale is per chart): UV area in texels against the 3D area at the
    # requested density. Charts are found from the UVs as in chart_labels; stretch inside
    # a chart averages out over its area.
    charts = chart_labels(faces, (px / np.maximum(px.max(), 1.0)).astype(np.float32))
    a3 = np.bincount(charts, weights=area3)
    at = np.bincount(charts, weights=areat)
    # Only charts of some size: xatlas shrinks the big ones, and a small one's area is off
    # by its rounding to whole texels (measured: +2.5 % on a 35 x 10 texel chart).
    big = (a3 > 0) & (at >= C.PACK_DENSITY_MIN_CHART_TEXELS2)
    ratio = np.sqrt(at[big] / (a3[big] * texels_per_unit ** 2))
    return bool(ratio.min(initial=1.0) >= C.PACK_MIN_DENSITY_RATIO)


def chart_labels(faces: np.ndarray, uvs: np.ndarray) -> np.ndarray:
    """Chart id per face: faces sharing an edge with equal UVs on both ends belong to
    the same chart (connected components of the UV-continuous face adjacency)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(faces)
    e_v = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)   # (3M, 2)
    e_uv = np.stack([uvs, np.roll(uvs, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    face_of = np.repeat(np.arange(m), 3)
    # Canonical key: (min vertex, max vertex, uv at min, uv at max)
    swap = e_v[:, 0] > e_v[:, 1]
    a = np.where(swap, e_v[:, 1], e_v[:, 0])
    b = np.where(swap, e_v[:, 0], e_v[:, 1])
    ua = np.where(swap[:, None], e_uv[:, 1], e_uv[:, 0])
    ub = np.where(swap[:, None], e_uv[:, 0], e_uv[:, 1])
    key = np.column_stack([a, b, ua.view(np.int32).reshape(-1, 2), ub.view(np.int32).reshape(-1, 2)])
    order = np.lexsort(key.T[::-1])
    sk = key[order]
    same = (sk[1:] == sk[:-1]).all(axis=1)
    i = face_of[order[:-1][same]]
    j = face_of[order[1:][same]]
    g = coo_matrix((np.ones(len(i), dtype=np.int8), (i, j)), shape=(m, m))
    _, labels = connected_components(g, directed=False)
    return labels.astype(np.int64)
