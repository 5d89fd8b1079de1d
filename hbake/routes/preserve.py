"""The parameterization-preserving route (``method = "pp"``, alias ``preserve``; Sec. 6.1).

The paper parameterizes the full-resolution mesh, stores its surface positions in the
atlas, and simplifies the mesh while preserving that parameterization, so the coarse
mesh's UVs index an atlas rasterized from the full surface itself (no rays from a
cage). Data flow (:func:`bake_preserve`, the route's one public entry):

    proxy      full mesh                    -> low-pass proxy (the simplify stage, at
                                               ``preserve.proxy_faces``; this stage and the
                                               next three see the part scaled to a fixed
                                               diagonal, so the unit changes nothing)
    charts     proxy                        -> xatlas charts and packing (the
                                               parameterize stage, unchanged)
    transfer   full mesh + proxy charts     -> per-corner UVs of the full mesh: each full
                                               triangle joins the chart of the proxy face
                                               nearest its centroid, each of its vertices
                                               takes the UV of its closest point on that
                                               chart (clamped onto it)
    simplify   seam-split full mesh         -> coarse mesh: meshoptimizer's
                                               attribute-aware edge collapse, chart borders
                                               locked (``preserve.seams``)
    rasterize  full mesh at (u, v, 0)       -> atlas: embree rays along z through the
                                               texel centres give the full triangle and its
                                               barycentrics, hence the full-surface point

Why a proxy: xatlas on the full mesh is far too slow (220 s on 128k triangles with its
default options, growing faster than linearly) and the relief cuts a detailed mesh into
many small charts whose locked borders keep the coarse mesh from its target. Charting
the proxy gives the charts of the surface's low-pass shape, a few dozen at most, in
well under a second; carrying them to the full mesh is a closest-point map per chart.

Why meshoptimizer (``meshopt_simplifyWithAttributes``): it is an endpoint-collapse
quadric simplifier that keeps attribute seams (a vertex split by a seam only collapses
along the seam, on both sides at once) and takes a per-vertex lock mask, which is what
"chart borders locked" needs; coarse vertices are full vertices, so a coarse UV is the
full surface's own UV of that point, and with the borders locked every coarse UV
triangle lies inside its chart (the chart's outline is kept vertex for vertex). The
pymeshlab texture-aware collapse lets seams drift (0.3-0.5 of the bbox diagonal
measured when the route was built) and has no lock mask.

A route that cannot reach the triangle target (every chart keeps its whole locked
outline, so its border vertices bound the count from below) raises
``TargetUnreachableError`` (its own exit code); ``method = "auto"`` then takes the cage
route. Everything is deterministic: fixed orders, no random choices, single-threaded
libraries.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from hbake import constants as C
from hbake.stages.atlas import (BakedAtlas, RayCaster, assign_texels, fill_gutter, midpoint_offsets,
                         texel_edges, texel_image)
from hbake.errors import BakeFailedError, TargetUnreachableError
from hbake.stages.geometry import (ClosestPointQuery, closest_point_on_triangles, face_areas,
                            is_closed, signed_distances)
from hbake.stages.load import degenerate_faces
from hbake.stages.parameterize import (Parameterization, barycentric_2d, chart_labels, parameterize,
                                texel_coordinates)
from hbake.stages.simplify import CoarseMesh, simplify

__all__ = ["PreserveResult", "bake_preserve", "transfer_charts", "split_seams",
           "simplify_preserving", "rasterize_full", "uv_containment"]


@dataclass
class PreserveResult:
    coarse: CoarseMesh
    param: Parameterization       # the coarse mesh's per-corner UVs and the atlas size
    baked: BakedAtlas
    stats: dict                   # manifest["route"]["pp"]
    coarse_chart: np.ndarray      # (K,) chart of each coarse face
    full_uvs: np.ndarray          # (M, 3, 2) per-corner UVs of the full mesh
    full_chart: np.ndarray        # (M,) chart of each full face
    proxy_uvs: np.ndarray         # (P, 3, 2) the proxy's per-corner UVs (xatlas's charts)
    proxy_chart: np.ndarray       # (P,) chart of each proxy face


# ------------------------------------------------------------------------------------
# charts of the proxy, carried to the full mesh
# ------------------------------------------------------------------------------------
def _nearest_faces(tri: np.ndarray, points: np.ndarray, k: int, chunk: int = 1 << 16):
    """Closest point of each point on the triangles ``tri`` (K, 3, 3), searched among the
    ``k`` triangles with the nearest centroids (exact for the proxy's well-shaped
    triangles, whose closest face is always among its nearest centroids at k = 16):
    (face index, barycentrics clamped onto it, distance)."""
    from scipy.spatial import cKDTree

    k = int(min(k, len(tri)))
    tree = cKDTree(tri.mean(axis=1))
    face = np.zeros(len(points), dtype=np.int64)
    bary = np.zeros((len(points), 3))
    dist = np.zeros(len(points))
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk]
        _, cand = tree.query(p, k=k)
        cand = np.asarray(cand, dtype=np.int64).reshape(len(p), k)
        pp = np.repeat(p, k, axis=0)
        t = tri[cand.ravel()]
        c, b = closest_point_on_triangles(pp, t[:, 0], t[:, 1], t[:, 2])
        d = np.linalg.norm(c - pp, axis=1).reshape(len(p), k)
        best = np.argmin(d, axis=1)                 # ties: the nearer centroid (stable)
        rows = np.arange(len(p))
        face[s:s + len(p)] = cand[rows, best]
        bary[s:s + len(p)] = b.reshape(len(p), k, 3)[rows, best]
        dist[s:s + len(p)] = d[rows, best]
    return face, bary, dist


def transfer_charts(full_vertices, full_faces, proxy_vertices, proxy_faces, proxy_uvs):
    """Per-corner UVs (M, 3, 2) float64 and chart id per face of the full mesh, from the
    proxy's charts (module doc). A full vertex on a chart border gets one UV per chart
    it belongs to: the seam."""
    V = np.asarray(full_vertices, dtype=np.float64)
    F = np.asarray(full_faces, dtype=np.int64)
    pv = np.asarray(proxy_vertices, dtype=np.float64)
    pf = np.asarray(proxy_faces, dtype=np.int64)
    puv = np.asarray(proxy_uvs, dtype=np.float64)
    pchart = chart_labels(pf, np.asarray(proxy_uvs, dtype=np.float32))
    ptri = pv[pf]
    face, _, _ = _nearest_faces(ptri, V[F].mean(axis=1), C.PRESERVE_NEAREST_FACES)
    chart = pchart[face]
    uvs = np.zeros((len(F), 3, 2))
    for c in np.unique(chart):
        members = np.nonzero(pchart == c)[0]
        tris = np.nonzero(chart == c)[0]
        verts, inv = np.unique(F[tris].ravel(), return_inverse=True)
        f, b, _ = _nearest_faces(ptri[members], V[verts], C.PRESERVE_NEAREST_FACES)
        uv = np.einsum("kc,kcd->kd", b, puv[members[f]])
        uvs[tris] = uv[inv].reshape(-1, 3, 2)
    return uvs, chart


def split_seams(faces: np.ndarray, chart: np.ndarray):
    """The mesh split along chart borders: one vertex per (vertex, chart) pair in sorted
    order. Returns (split faces (M, 3), the full vertex of each split vertex, its chart)."""
    F = np.asarray(faces, dtype=np.int64)
    nch = int(chart.max()) + 1
    key = F * nch + chart[:, None]
    uniq, inv = np.unique(key.ravel(), return_inverse=True)
    return inv.reshape(F.shape), uniq // nch, uniq % nch


def chart_outlines(proxy_faces, proxy_uvs, proxy_chart):
    """The outline of every proxy chart in UV: (chart of each segment, segments (S, 2, 2)),
    the chart's edges that no other face of the chart shares, in sorted order."""
    pf = np.asarray(proxy_faces, dtype=np.int64)
    uv = np.asarray(proxy_uvs, dtype=np.float64)
    e = np.stack([pf, np.roll(pf, -1, axis=1)], axis=2).reshape(-1, 2)
    euv = np.stack([uv, np.roll(uv, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    ch = np.repeat(proxy_chart, 3)
    key = np.column_stack([ch, np.sort(e, axis=1)])
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    once = cnt[inv.ravel()] == 1
    order = np.lexsort(key[once].T[::-1])
    return ch[once][order], euv[once][order]


def fit_seams(split_faces, s_chart, uv_split, seg_chart, segments, border):
    """Seam vertices onto their chart's proxy outline, and the chart corners locked.

    Every border vertex of the split mesh (``border``) moves in UV to the nearest point of
    its chart's outline (by less than a full triangle: chart_of triangles were assigned
    by the proxy face nearest their centroid, and vertices take their closest point on the
    chart, clamped onto it), and the nearest border vertex of every outline corner moves
    onto the corner. The full chart's outline is then the proxy's polygon, straight
    between corners, so a seam collapse between two locked corners (meshoptimizer
    collapses seam vertices only along the seam) keeps every coarse UV triangle inside
    the chart. Returns (the new UVs, the lock mask of the corners)."""
    uv = np.array(uv_split, dtype=np.float64)
    lock = np.zeros(len(uv), dtype=bool)
    for c in np.unique(seg_chart):
        seg = segments[seg_chart == c]
        vs = np.nonzero(border & (s_chart == c))[0]
        if len(vs) == 0:
            continue
        q = uv[vs]
        a, b = seg[:, 0], seg[:, 1]
        d = b - a
        t = np.clip(np.einsum("nsd,sd->ns", q[:, None, :] - a[None], d)
                    / np.maximum(np.einsum("sd,sd->s", d, d), 1e-300)[None], 0.0, 1.0)
        p = a[None] + t[..., None] * d[None]
        dist = np.linalg.norm(p - q[:, None, :], axis=2)
        best = np.argmin(dist, axis=1)
        uv[vs] = p[np.arange(len(vs)), best]
        corners = np.unique(seg.reshape(-1, 2), axis=0)
        dc = np.linalg.norm(uv[vs][None, :, :] - corners[:, None, :], axis=2)
        pick = np.argmin(dc, axis=1)
        uv[vs[pick]] = corners
        lock[vs[pick]] = True
    return uv, lock


def border_vertices(split_faces: np.ndarray, n: int) -> np.ndarray:
    """Mask of the split mesh's vertices on an edge used once (a chart border or the
    input's own open border)."""
    e = np.sort(np.stack([split_faces, np.roll(split_faces, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    key = e[:, 0] * n + e[:, 1]
    u, cnt = np.unique(key, return_counts=True)
    once = u[cnt == 1]
    mask = np.zeros(n, dtype=bool)
    mask[once // n] = True
    mask[once % n] = True
    return mask


def _signed_uv_area(uv_tri):
    e1, e2 = uv_tri[:, 1] - uv_tri[:, 0], uv_tri[:, 2] - uv_tri[:, 0]
    return e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]


def chart_orientation(split_faces, uv_split, s_chart) -> np.ndarray:
    """+1 or -1 per chart: the sign of its UV area (xatlas may mirror a chart)."""
    a = _signed_uv_area(uv_split[split_faces])
    tot = np.bincount(s_chart[split_faces[:, 0]], weights=a)
    return np.where(tot < 0, -1.0, 1.0)


def uv_flipped(split_faces, uv_split, s_chart, chart_sign, strict=False) -> np.ndarray:
    """Faces whose UV triangle is folded over against its chart's orientation (with
    ``strict``, of negative area only; else also of no UV area)."""
    a = _signed_uv_area(uv_split[split_faces]) * chart_sign[s_chart[split_faces[:, 0]]]
    return a < 0 if strict else a <= 0


def pinched_vertices(faces: np.ndarray) -> np.ndarray:
    """Vertices of the edges that more than two triangles share, or two triangles in the
    same direction (sorted, unique)."""
    e = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    _, dcnt = np.unique(e, axis=0, return_counts=True)
    ud, ucnt = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    bad = [ud[ucnt > 2]]
    if (dcnt > 1).any():
        u, c = np.unique(e, axis=0, return_counts=True)
        bad.append(u[c > 1])
    return np.unique(np.concatenate(bad).ravel())


# ------------------------------------------------------------------------------------
# simplification that keeps the parameterization
# ------------------------------------------------------------------------------------
def simplify_preserving(positions, split_faces, uv_split, target: int, *, lock: np.ndarray,
                        uv_weight: float):
    """meshoptimizer's attribute-aware collapse of the seam-split mesh to at most
    ``target`` triangles (module doc). ``uv_split`` (n, 2) as lengths on the surface in
    the unit of ``positions``. meshoptimizer rescales the positions by their largest
    bounding-box side but takes the attributes as given (times ``uv_weight``), so the
    weight of a UV error against a position error of the same length is ``uv_weight``
    times that side in this unit: the caller passes the part scaled to
    PRESERVE_FRAME_DIAGONAL (bake_preserve), so that it does not depend on the unit the
    part came in (in meters it weighed 1000 times more for a part given in m than for
    the same part given in mm). Returns (faces (K, 3) into the split vertices,
    meshoptimizer's relative error)."""
    import ctypes

    try:
        from meshoptimizer._loader import lib
    except ImportError:
        raise BakeFailedError("--method preserve needs meshoptimizer (pip install "
                              "meshoptimizer==0.2.30a0, as pyproject.toml pins it)") from None

    # The wrapper (meshoptimizer 0.2.30a0) declares no argument types for this entry, so
    # ctypes cannot pass the float and would pass the size_t counts as C ints; they are
    # declared here from meshoptimizer.h.
    f = lib.meshopt_simplifyWithAttributes
    P = ctypes.POINTER
    f.argtypes = [P(ctypes.c_uint), P(ctypes.c_uint), ctypes.c_size_t, P(ctypes.c_float),
                  ctypes.c_size_t, ctypes.c_size_t, P(ctypes.c_float), ctypes.c_size_t,
                  P(ctypes.c_float), ctypes.c_size_t, P(ctypes.c_ubyte), ctypes.c_size_t,
                  ctypes.c_float, ctypes.c_uint, P(ctypes.c_float)]
    f.restype = ctypes.c_size_t
    pos = np.ascontiguousarray(positions, dtype=np.float32)
    idx = np.ascontiguousarray(np.asarray(split_faces, dtype=np.uint32).ravel())
    attr = np.ascontiguousarray(uv_split, dtype=np.float32)
    weights = np.array([uv_weight, uv_weight], dtype=np.float32)
    locks = np.ascontiguousarray(lock, dtype=np.uint8)
    dest = np.zeros(len(idx), dtype=np.uint32)
    err = ctypes.c_float(0.0)
    # target_error 1 (the whole mesh extent): the triangle count is the only stop, the
    # seams and the lock mask the only constraints.
    count = f(dest.ctypes.data_as(P(ctypes.c_uint)), idx.ctypes.data_as(P(ctypes.c_uint)),
              len(idx), pos.ctypes.data_as(P(ctypes.c_float)), len(pos), 12,
              attr.ctypes.data_as(P(ctypes.c_float)), 8, weights.ctypes.data_as(P(ctypes.c_float)),
              2, locks.ctypes.data_as(P(ctypes.c_ubyte)), int(3 * target), 1.0, 0,
              ctypes.byref(err))
    err = err.value
    return dest[:count].astype(np.int64).reshape(-1, 3), float(err)


def seam_vertices_under(tri_uvs, tri_chart, uv_split, s_chart, border) -> np.ndarray:
    """Mask of the border vertices of each triangle's chart inside its UV bounding box."""
    mask = np.zeros(len(uv_split), dtype=bool)
    idx = np.nonzero(border)[0]
    for t, c in zip(tri_uvs, tri_chart):
        lo, hi = t.min(axis=0), t.max(axis=0)
        q = uv_split[idx]
        sel = (s_chart[idx] == c) & np.all(q >= lo, axis=1) & np.all(q <= hi, axis=1)
        mask[idx[sel]] = True
    return mask


def uv_containment(coarse_uvs, coarse_chart, full_uvs, full_chart, W: int, H: int,
                   samples_per_face: int = 16, seed: int = 0):
    """For its corners, edge midpoints and seeded points of every coarse UV triangle: the UV distance in texels to the
    nearest full UV triangle of the same chart (0 inside it). The coarse UV region of a
    chart lies inside the full chart's when every distance is ~0."""
    rng = np.random.default_rng(seed)
    m = len(coarse_uvs)
    r = rng.random((m, samples_per_face, 2))
    flip = r.sum(axis=2) > 1
    r[flip] = 1 - r[flip]
    b = np.concatenate([1 - r.sum(axis=2, keepdims=True), r], axis=2)         # (m, s, 3)
    fixed = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [.5, .5, 0], [0, .5, .5], [.5, 0, .5]], float)
    b = np.concatenate([np.broadcast_to(fixed, (m, 6, 3)), b], axis=1)
    samples_per_face += 6
    cp = texel_coordinates(np.asarray(coarse_uvs, dtype=np.float64), W, H)
    pts = np.einsum("msk,mkd->msd", b, cp).reshape(-1, 2)
    chart = np.repeat(coarse_chart, samples_per_face)
    fp = texel_coordinates(np.asarray(full_uvs, dtype=np.float64), W, H)
    out = np.zeros(len(pts))
    for c in np.unique(chart):
        sel = np.nonzero(chart == c)[0]
        tri = np.concatenate([fp[full_chart == c], np.zeros((int((full_chart == c).sum()), 3, 1))], axis=2)
        _, _, d = _nearest_faces(tri, np.concatenate([pts[sel], np.zeros((len(sel), 1))], axis=1), 32)
        out[sel] = d
    return out


# ------------------------------------------------------------------------------------
# the atlas, rasterized from the full surface
# ------------------------------------------------------------------------------------
def degenerate_footprints(uvs, tri_of, bary, dist, W: int, H: int) -> int:
    """Bake the footprints of the coarse UV triangles of no area too, in place.

    assign_texels skips a UV triangle of no area, as the lookups on it read the texels of
    the triangles around it. Here that fails on a chart's outline: a coarse triangle whose
    three seam vertices fit_seams put on one straight outline segment (an ear of the
    full mesh's border kept by the collapse) is a segment in UV with no triangle of its
    chart beside it, and its lookups read texels nobody baked, farther than the gutter
    from any covered texel. Texels within BAKE_BORDER_TEXELS of such a segment are baked
    from it when no triangle claimed them (a preserve texel's value depends only on its
    chart), never as covered (barycentrics -1), and every texel's distance becomes the
    nearer of the two, so fill_gutter widens the gutter over all of them. Returns the
    number of texels added."""
    from hbake.stages.atlas import _segment_distance_2d

    p = texel_coordinates(uvs, W, H)
    e = np.roll(p, -1, axis=1) - p
    twice_area = np.abs(e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0])
    r = C.BAKE_BORDER_TEXELS
    added = 0
    for t in np.nonzero(twice_area <= C.UV_DEGENERATE_TEXELS2)[0]:
        lo = np.maximum(np.floor(p[t].min(axis=0) - r).astype(np.int64), 0)
        hi = np.minimum(np.ceil(p[t].max(axis=0) + r).astype(np.int64), [W - 1, H - 1])
        if np.any(hi < lo):
            continue
        jj, ii = np.mgrid[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
        i, j = ii.ravel(), jj.ravel()
        q = np.stack([i, j], axis=1).astype(np.float64)
        n = len(q)
        d = _segment_distance_2d(q, np.broadcast_to(p[t, 0], (n, 2)), np.broadcast_to(p[t, 1], (n, 2)),
                                 np.broadcast_to(p[t, 2], (n, 2)))
        near = d <= r
        i, j, d = i[near], j[near], d[near]
        free = tri_of[j, i] < 0
        tri_of[j[free], i[free]] = t
        bary[j[free], i[free]] = -1.0
        added += int(free.sum())
        dist[j, i] = np.minimum(dist[j, i], d)
    return added


def rasterize_full(coarse_vertices, coarse_faces, coarse_uvs, coarse_chart, full_vertices,
                   full_faces, full_uvs, full_chart, W: int, H: int, atlas_settings,
                   progress=None) -> BakedAtlas:
    """The atlas of the coarse mesh's UVs, every value a point of the full surface.

    Which texels are baked, and their coverage, follow the cage route (hbake/stages/atlas.py):
    texels within BAKE_BORDER_TEXELS of a coarse UV triangle are baked (alpha 1 where
    the centre lies inside one), the rest within the gutter filled by the same dilation
    (``fill_gutter``). A baked texel's value is the full-surface point whose UV is the
    texel centre: an embree ray along z through the centre against the full mesh laid
    out at (u, v, 0) in texel units gives its full triangle and barycentrics. A centre
    outside every full UV triangle of its chart (the border ring, where a lookup reads
    past the chart's outline) takes the full-surface point at the nearest UV of the
    chart: clamped, so it stays on the surface, at the chart's edge.
    """
    V = np.asarray(coarse_vertices, dtype=np.float64)
    F = np.asarray(coarse_faces, dtype=np.int64)
    FV = np.asarray(full_vertices, dtype=np.float64)
    FF = np.asarray(full_faces, dtype=np.int64)
    uv64 = np.asarray(coarse_uvs, dtype=np.float64)
    tri_of, bary, dist = assign_texels(uv64, W, H)
    degenerate_footprints(uv64, tri_of, bary, dist, W, H)
    baked = tri_of >= 0
    ys, xs = np.nonzero(baked)
    t_ids = tri_of[ys, xs]
    covered = np.zeros((H, W), dtype=bool)
    covered[ys, xs] = bary[ys, xs].min(axis=1) >= -C.INSIDE_EPS
    if not covered.any():
        raise BakeFailedError("no texel centre lies inside a UV triangle: the atlas is too "
                              "small for the coarse mesh (raise --atlas-size)")
    tri3 = V[F]
    area3 = 0.5 * np.linalg.norm(np.cross(tri3[:, 1] - tri3[:, 0], tri3[:, 2] - tri3[:, 0]), axis=1)
    px = texel_coordinates(uv64, W, H)
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    areat = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    texel_size = float(np.median(np.sqrt(area3 / np.maximum(areat, 1e-300))[tri_of[covered]]))

    # the full mesh laid out in texel units at z = 0
    fpx = texel_coordinates(np.asarray(full_uvs, dtype=np.float64), W, H)      # (M, 3, 2)
    layout_v = np.concatenate([fpx.reshape(-1, 2), np.zeros((3 * len(FF), 1))], axis=1)
    layout_f = np.arange(3 * len(FF)).reshape(-1, 3)
    caster = RayCaster(layout_v, layout_f)
    want = coarse_chart[t_ids]
    q = np.stack([xs, ys], axis=1).astype(np.float64)
    prim = np.full(len(q), -1, dtype=np.int64)
    chunk = 1 << 18
    for s in range(0, len(q), chunk):
        o = np.concatenate([q[s:s + chunk], np.ones((len(q[s:s + chunk]), 1))], axis=1)
        d = np.tile([0.0, 0.0, -1.0], (len(o), 1))
        _, p = caster.first_hit(o, d, 2.0)
        prim[s:s + chunk] = p
        if progress:
            progress(0.8 * min(1.0, (s + chunk) / len(q)))
    # a hit on another chart cannot happen (xatlas keeps charts padding texels apart);
    # it is treated as a miss all the same, so a value never comes from another chart
    hit = (prim >= 0) & (full_chart[np.maximum(prim, 0)] == want)
    prim[~hit] = -1
    b = np.zeros((len(q), 3))
    h = np.nonzero(hit)[0]
    if len(h):
        t = fpx[prim[h]]
        b[h] = barycentric_2d(q[h], t[:, 0], t[:, 1], t[:, 2])
    miss = np.nonzero(~hit)[0]
    for c in np.unique(want[miss]):
        sel = miss[want[miss] == c]
        members = np.nonzero(full_chart == c)[0]
        tri = np.concatenate([fpx[members], np.zeros((len(members), 3, 1))], axis=2)
        f, bb, _ = _nearest_faces(tri, np.concatenate([q[sel], np.zeros((len(sel), 1))], axis=1),
                                  C.PRESERVE_NEAREST_FACES)
        prim[sel] = members[f]
        b[sel] = bb
    # onto the triangle (embree's float32 may pick a neighbour a hair past its edge)
    b = np.clip(b, 0.0, 1.0)
    b /= b.sum(axis=1, keepdims=True)
    points = np.einsum("kc,kcd->kd", b, FV[FF[prim]])
    if progress:
        progress(0.9)

    image, triangle = texel_image(points, ys, xs, t_ids, covered)
    gutter = fill_gutter(image, covered, baked, dist, atlas_settings.gutter)

    # Discontinuities and off-surface chords between neighbours, counted as the cage
    # route counts them (no repair: every texel already is its own full-surface point).
    closest = ClosestPointQuery(FV, FF)
    edges = texel_edges(ys, xs, coarse_chart[t_ids], W, H)
    length, off = midpoint_offsets(points, prim, edges, texel_size, closest, FV[FF])
    cut_len = C.DISCONTINUITY_TEXELS * texel_size
    thr = C.JUMP_REPAIR_TEXELS * texel_size
    uncut = length <= cut_len
    cut, offn = int((~uncut).sum()), int((uncut & (off > thr)).sum())
    jumps = {"rule_texels": float(C.DISCONTINUITY_TEXELS),
             "repair_threshold_texels": float(C.JUMP_REPAIR_TEXELS), "edges": int(len(edges)),
             "cut_before": cut, "cut": cut, "off_before": offn, "off_after_walls": offn,
             "off_after": offn, "texels_relabelled": 0, "texels_moved": 0, "rounds": 0,
             "max_off_texels": float(off[uncut].max(initial=0.0) / texel_size)}

    used = dist[ys, xs] <= np.sqrt(2.0) + 1e-9
    sd = signed_distances(V, F, points[used])
    inside = covered[ys, xs]
    return BakedAtlas(image=image, triangle=triangle, covered=covered, baked=baked,
                      coverage=float(covered.mean()), gutter=gutter, texel_size=texel_size,
                      displacement_outward=float(max(sd.max(initial=0.0), 0.0)),
                      displacement_inward=float(max(-sd.min(initial=0.0), 0.0)),
                      rays=int(len(q)), fallbacks=int((~hit & inside).sum()),
                      border_fallbacks=int((~hit & ~inside).sum()), jumps=jumps)


# ------------------------------------------------------------------------------------
# the route
# ------------------------------------------------------------------------------------
def frame_scale(vertices, faces) -> float:
    """The factor that brings the bounding-box diagonal of the used vertices to
    PRESERVE_FRAME_DIAGONAL (1 for a mesh without extent)."""
    F = np.asarray(faces, dtype=np.int64)
    if len(F) == 0:
        return 1.0
    v = np.asarray(vertices, dtype=np.float64)[np.unique(F)]
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    return C.PRESERVE_FRAME_DIAGONAL / diag if diag > 0 else 1.0


def bake_preserve(full_vertices, full_faces, settings, *, input_name: str = "input",
                  input_closed: bool | None = None, stage=None, warn=None) -> PreserveResult:
    """Coarse mesh, its UVs and the atlas by the parameterization-preserving route.

    ``stage(name, total)`` is a progress context (hbake.progress.Progress.stage) or None.
    Raises TargetUnreachableError when the coarse mesh cannot reach
    ``simplify.target_faces`` with the chart borders locked.
    """
    import contextlib

    def _stage(name, total=None):
        return stage(name, total) if stage else contextlib.nullcontext(lambda f: None)

    ps = settings.preserve
    target = settings.simplify.target_faces
    FV = np.asarray(full_vertices, dtype=np.float64)
    FF = np.asarray(full_faces, dtype=np.int64)
    if input_closed is None:
        input_closed = is_closed(FF)
    proxy_faces = ps.proxy_faces or target
    # Every choice of the route (proxy, charts, their transfer, the collapse) is made on
    # the part scaled to PRESERVE_FRAME_DIAGONAL (constants say why: pymeshlab's collapse
    # and xatlas have absolute thresholds, so the same part given in cm and in m got other
    # proxies and charts) and rounded to float32 there: the same file in two units then
    # gives the same numbers (the float64 products differ by an ulp, float32 hides it),
    # hence the same coarse mesh. The atlas's values and the coarse vertices come from FV.
    k = frame_scale(FV, FF)
    FVk = (FV * k).astype(np.float32).astype(np.float64)
    with _stage("proxy"):
        proxy = simplify(FVk, FF, dataclasses.replace(settings.simplify, target_faces=proxy_faces),
                         input_closed=input_closed)
    with _stage("charts"):
        # xatlas's own charts, whole: the transfer fits the full mesh's seams to the chart
        # outlines, and slabs cut across a chart only add seams to fit (on the hammer the
        # worst full-to-coarse error went from 42 um to 0.70 mm with them).
        pparam = parameterize(proxy.vertices, proxy.faces,
                              dataclasses.replace(settings.parameterize, padding=ps.padding),
                              split_long=False)
        # texels per meter: a meter is k units of the scaled frame
        tpu_k = pparam.texels_per_unit
        pparam = dataclasses.replace(pparam, texels_per_unit=tpu_k * k)
        W, H = pparam.width, pparam.height
    with _stage("transfer"):
        full_uvs, full_chart = transfer_charts(FVk, FF, proxy.vertices, proxy.faces, pparam.uvs)
        sf, s_vert, s_chart = split_seams(FF, full_chart)
        n = len(s_vert)
        uv_split = np.zeros((n, 2))
        uv_split[sf.ravel()] = full_uvs.reshape(-1, 2)
        border = border_vertices(sf, n)
        if ps.seams == "locked":
            lock = border
        elif ps.seams == "free":
            lock = np.zeros(n, dtype=bool)
        else:
            pchart = chart_labels(proxy.faces, pparam.uvs)
            seg_chart, segments = chart_outlines(proxy.faces, pparam.uvs, pchart)
            uv_split, lock = fit_seams(sf, s_chart, uv_split, seg_chart, segments, border)
            full_uvs = uv_split[sf]
    with _stage("simplify"):
        # UVs as lengths on the surface in the frame (texels over texels per frame unit),
        # so the attribute weight compares like with like, whatever the part's unit
        scale = 1.0 / tpu_k if tpu_k > 0 else 1.0
        uv_k = uv_split * np.array([W, H]) * scale
        # meshoptimizer does not keep the topology: on the torus two seam edges of 2,000
        # came out shared by four triangles (a pinch). The full mesh's 1-rings of such
        # edges are locked and the collapse rerun, until none is left (deterministic; one
        # rerun on the torus).
        lock_all = lock.copy()
        rounds = 0
        chart_sign = chart_orientation(sf, uv_split, s_chart)
        for rounds in range(1, C.PRESERVE_PINCH_ROUNDS + 1):
            cf_split, err = simplify_preserving(FVk[s_vert], sf, uv_k, target, lock=lock_all,
                                                uv_weight=ps.uv_weight)
            pinched = pinched_vertices(s_vert[cf_split])
            if len(pinched) == 0:
                break
            # the pinch's 1-ring in the full mesh: its own two vertices alone move the
            # pinch to the next seam vertex (measured on the torus)
            lock_all |= np.isin(s_vert, np.unique(FF[np.isin(FF, pinched).any(axis=1)].ravel()))
        # meshoptimizer checks flips in 3D, not in UV: the coarse UV triangles folded
        # against their chart (16 of 2,000 on the torus; locking their vertices and
        # rerunning did not lower it) are counted for the manifest
        folded = int(uv_flipped(cf_split, uv_split, s_chart, chart_sign, strict=True).sum())
        cf_full = s_vert[cf_split]
        c_uvs = uv_split[cf_split]                                      # (K, 3, 2)
        c_chart = s_chart[cf_split[:, 0]]
        used, inv = np.unique(cf_full.ravel(), return_inverse=True)
        cv = FV[used].astype(np.float32).astype(np.float64)
        cf = inv.reshape(-1, 3)
        keep = ~degenerate_faces(cv, cf)
        cf, c_uvs, c_chart = cf[keep], c_uvs[keep], c_chart[keep]
        used2, inv2 = np.unique(cf.ravel(), return_inverse=True)
        cv, cf = cv[used2], inv2.reshape(-1, 3)
    if len(cf) > target:
        locked = int(lock.sum())
        raise TargetUnreachableError(
            f"{input_name}: the preserve route cannot reach {target} triangles (stopped at "
            f"{len(cf)}: {pparam.charts} charts keep their outlines, {locked} vertices locked); "
            f"raise --target-faces, set preserve.seams = 'free', or use --method cage")
    if len(cf) == 0:
        raise BakeFailedError(f"{input_name}: the preserve route's simplification left no triangles")
    closed = is_closed(cf)
    if input_closed and not closed:
        if warn:
            warn("the preserve route's coarse mesh is not closed although the input is")
    c_uvs32 = np.clip(c_uvs, 0.0, 1.0).astype(np.float32)
    coarse = CoarseMesh(vertices=cv, faces=cf, closed=closed,
                        pre_decimated_faces=proxy.pre_decimated_faces, placement="endpoint")
    with _stage("bake", 1.0) as update:
        baked = rasterize_full(cv, cf, c_uvs32, c_chart, FV, FF, full_uvs, full_chart, W, H,
                               settings.atlas, progress=update)
    # how far coarse UV triangles leave their chart's full UV triangles (folds; texels)
    out = uv_containment(c_uvs32, c_chart, full_uvs, full_chart, W, H,
                         C.PRESERVE_CONTAIN_SAMPLES, seed=0)
    charts_used = int(len(np.unique(c_chart)))
    param = Parameterization(uvs=c_uvs32, width=W, height=H, packed_width=pparam.packed_width,
                             packed_height=pparam.packed_height, charts=charts_used,
                             texels_per_unit=pparam.texels_per_unit,
                             utilization=pparam.utilization)
    area = face_areas(cv, cf).sum()
    stats = {"proxy_faces": int(len(proxy.faces)), "proxy_charts": int(pparam.charts),
             "seams": ps.seams, "split_vertices": int(n), "locked_vertices": int(lock_all.sum()),
             "pinch_rounds": int(rounds), "uv_folded": folded,
             "uv_outside_max_texels": float(out.max()),
             "uv_outside_fraction": float((out > C.PRESERVE_CONTAIN_TEXELS).mean()),
             "simplify_error": float(err), "triangles": int(len(cf)),
             "coarse_area_ratio": float(area / max(face_areas(FV, FF).sum(), 1e-300))}
    return PreserveResult(coarse=coarse, param=param, baked=baked, stats=stats,
                          coarse_chart=c_chart, full_uvs=full_uvs, full_chart=full_chart,
                          proxy_uvs=np.asarray(pparam.uvs, dtype=np.float64),
                          proxy_chart=chart_labels(proxy.faces, pparam.uvs))
