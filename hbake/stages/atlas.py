"""Stage 4: bake the haptic texture (the mapping f of Sec. 5.1) by casting rays.

For every texel near a UV triangle of the coarse mesh, the texel centre is mapped to
the coarse surface point ``c`` it parameterizes (barycentric coordinates of the UV
triangle applied to the 3D triangle), and a ray is cast from ``c`` both ways along
the interpolated vertex normal against the full-resolution mesh (embree through
embreex); the nearer hit within ``max_ray_distance`` gives ``f(c)``. Where no hit is
found the closest point of the full surface is used instead, as normal-map bakers do.
Interpolated (not face) normals make ``f`` continuous across coarse edges.

Which texels are baked, and from which triangle:

* a texel whose centre lies inside a UV triangle is *covered* (alpha 1) and baked from
  that triangle (on a shared edge the lower triangle id wins);
* a texel whose centre lies within ``BAKE_BORDER_TEXELS`` (1.5) of a UV triangle but in
  none is baked from the nearest triangle, extending that triangle's plane and normal
  field past its edge (alpha 0; the extension is capped at BORDER_STRETCH_TEXELS texel
  sizes per texel, so a needle UV triangle cannot throw it off the part). A bilinear lookup at a point inside a UV triangle
  reads only texels at Chebyshev distance < 1 from it, so every texel a lookup can
  read is a genuinely baked value of the same chart (xatlas keeps charts at least
  ``padding`` >= 2 texels apart), and lookups near chart borders interpolate the
  mapping instead of a copy;
* the remaining texels within ``gutter`` (Chebyshev) of a covered texel are filled by
  dilation: each takes the value of the nearest baked texel (Euclidean). The gutter is
  widened where needed so that it contains every texel a lookup can read: near the
  sharp tip of a sliver UV triangle such texels may lie farther than the requested
  gutter from any covered texel (docs/bundle-format.md promises filled texels within
  ``atlas.gutter`` of a covered texel, and the manifest records the effective width);
* all other texels are 0.

Each covered texel therefore comes from its own coarse triangle, and no lookup inside
a chart reads another chart's texels. Everything is vectorised: candidate texels per
triangle are generated with ``np.repeat`` and rays are traced in chunks.

Jumps (``repair_jumps``, before the gutter is filled). Texel values are ray hits, on the
full surface; a bilinear lookup between two neighbours that hit distant parts of it is
not. Two 4-neighbour texels of one chart more than DISCONTINUITY_TEXELS (4) texel sizes
apart are a *discontinuity*: the runtime interpolates no 2x2 quad with such an edge
(docs/bundle-format.md). Between neighbours closer than that, the chord's midpoint may
still leave the surface: where the coarse point lies between two walls less than 4
texels apart (meshing gear teeth of two bodies, a thin tooth) the nearer hit switches
walls, and where rays fan over a sharp crease they skip it. Texels at the end of an
edge whose midpoint is more than JUMP_REPAIR_TEXELS (0.5) texel sizes off the surface
are re-chosen among other points of the full surface: first the wall (the hit along
+normal or -normal) by a minimum cut over the texels around them, so that neighbours
land on the same wall; then, texel by texel, the other hit, the projection of the mean
of the neighbours, the own hit, or a slide along the own wall until the chord is longer
than the cut length (the jump becomes a discontinuity by the rule: *marked*), whichever
improves the texel's worst chord. Every texel value stays a point of the full surface;
the counts are recorded in the manifest (``atlas.discontinuities``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from hbake import constants as C
from hbake.errors import BakeFailedError
from hbake.stages.geometry import (ClosestPointQuery, closest_point_on_triangles, closest_points,
                            face_normals, signed_distances, vertex_normals)
from hbake.stages.parameterize import barycentric_2d, chart_labels, texel_candidates, texel_coordinates
from hbake.settings import AtlasSettings, CageSettings


@dataclass
class BakedAtlas:
    image: np.ndarray           # (H, W, 4) float32: RGB position (m), A coverage; row 0 = top
    triangle: np.ndarray        # (H, W) int64: coarse triangle a texel was baked from, -1 none
    covered: np.ndarray         # (H, W) bool: texel centre inside a UV triangle
    baked: np.ndarray           # (H, W) bool: texel baked by a ray (covered or border)
    coverage: float             # fraction of texels covered
    gutter: int                 # effective gutter (>= the setting; see the module doc)
    texel_size: float           # m, median over covered texels of one texel step on the coarse surface
    displacement_outward: float  # m, max distance of the baked surface outside the coarse surface
    displacement_inward: float   # m, max distance inside
    rays: int                   # texels baked by ray casting
    fallbacks: int              # covered texels whose rays found nothing: closest point used
    border_fallbacks: int       # the same for border texels (short rays, often expected)
    jumps: dict | None = None   # what repair_jumps did (manifest atlas.discontinuities)


def bake_atlas(coarse_vertices: np.ndarray, coarse_faces: np.ndarray, uvs: np.ndarray,
               width: int, height: int, full_vertices: np.ndarray, full_faces: np.ndarray,
               cage: CageSettings | None = None, atlas: AtlasSettings | None = None,
               *, progress=None) -> BakedAtlas:
    """Bake the (height, width, 4) atlas of the coarse mesh against the full mesh.

    ``progress(f)`` is called with the fraction of rays traced so far.
    """
    cage = cage or CageSettings()
    atlas = atlas or AtlasSettings()
    V = np.asarray(coarse_vertices, dtype=np.float64)
    F = np.asarray(coarse_faces, dtype=np.int64)
    coarse_uvs_f32 = np.asarray(uvs, dtype=np.float32)
    uvs = np.asarray(uvs, dtype=np.float64)
    W, H = int(width), int(height)
    diag = float(np.linalg.norm(full_vertices.max(axis=0) - full_vertices.min(axis=0)))

    tri_of, bary, dist = assign_texels(uvs, W, H)
    baked = tri_of >= 0
    ys, xs = np.nonzero(baked)
    t_ids = tri_of[ys, xs]
    b = bary[ys, xs]                                          # (K, 3), may be < 0 at borders
    covered = np.zeros((H, W), dtype=bool)
    covered[ys, xs] = b.min(axis=1) >= -C.INSIDE_EPS
    if not covered.any():
        raise BakeFailedError("no texel centre lies inside a UV triangle: the atlas is too "
                              "small for the coarse mesh (raise --atlas-size)")

    # Texel size: 3D length of one texel step, sqrt(3D area / texel area) per triangle.
    tri3 = V[F]
    area3 = 0.5 * np.linalg.norm(np.cross(tri3[:, 1] - tri3[:, 0], tri3[:, 2] - tri3[:, 0]), axis=1)
    px = uvs * np.array([W, H])
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    areat = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    per_tri = np.sqrt(area3 / np.maximum(areat, 1e-300))
    texel_size = float(np.median(per_tri[tri_of[covered]]))

    # Points on the coarse surface and interpolated normals (the cage's ray directions).
    vn = vertex_normals(V, F)
    fn = face_normals(V, F)
    corner = F[t_ids]                                         # (K, 3)
    inside = covered[ys, xs]
    origin, b_clamped = _origins(V[corner], b, inside, uvs, t_ids, xs, ys, W, H, texel_size)
    normal = np.einsum("kc,kcd->kd", b_clamped, vn[corner])
    length = np.linalg.norm(normal, axis=1)
    weak = length < 1e-6                                       # opposite normals cancel
    normal[weak] = fn[t_ids[weak]]
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)

    # Border texels extend their triangle past its edge; past a sharp coarse edge that
    # extension leaves the surface, so their rays are kept short (a few texels) and fall
    # back to the closest point, which keeps them next to the edge they continue.
    reach = np.full(len(t_ids), cage.max_ray_distance * diag)
    reach[~inside] = np.minimum(reach[~inside], C.BORDER_RAY_TEXELS * texel_size)
    points, hit, prim, alt, alt_prim, use_neg = _cast(origin, normal, full_vertices, full_faces, reach, progress)
    misses = np.nonzero(~hit)[0]
    if len(misses):
        points[misses] = closest_points(full_vertices, full_faces, origin[misses])[0]
        prim[misses] = -1

    # Jumps: neighbouring texels whose reconstruction leaves the surface (module doc).
    chart = chart_labels(F, np.asarray(coarse_uvs_f32))[t_ids]
    jumps = repair_jumps(points, prim, alt, alt_prim, use_neg, ys, xs, chart, W, H, texel_size,
                         full_vertices, full_faces)

    image, triangle = texel_image(points, ys, xs, t_ids, covered)
    gutter = fill_gutter(image, covered, baked, dist, atlas.gutter)

    # Displacement bounds: signed distance (outward positive) of every baked point that a
    # lookup can read to the coarse surface. (Not the height over the texel's own
    # triangle: near a sharp coarse edge the interpolated normal carries the ray onto the
    # neighbouring face, far from the own plane but on the coarse surface.)
    used = dist[ys, xs] <= math.sqrt(2.0) + 1e-9
    sd = signed_distances(V, F, points[used])
    outward = float(max(sd.max(initial=0.0), 0.0))
    inward = float(max(-sd.min(initial=0.0), 0.0))

    return BakedAtlas(image=image, triangle=triangle, covered=covered, baked=baked,
                      coverage=float(covered.mean()), gutter=gutter, texel_size=texel_size,
                      displacement_outward=outward, displacement_inward=inward,
                      rays=int(len(t_ids)), fallbacks=int((~hit & inside).sum()),
                      border_fallbacks=int((~hit & ~inside).sum()), jumps=jumps)


def texel_image(points: np.ndarray, ys: np.ndarray, xs: np.ndarray, t_ids: np.ndarray,
                covered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The atlas image (RGB the points of the covered texels (ys, xs), A the coverage) and
    the per-texel coarse triangle (-1 where uncovered), as both routes store them."""
    H, W = covered.shape
    image = np.zeros((H, W, 4), dtype=np.float32)
    image[ys, xs, :3] = points.astype(np.float32)
    image[..., 3] = covered.astype(np.float32)
    triangle = np.full((H, W), -1, dtype=np.int64)
    triangle[ys, xs] = t_ids
    return image, triangle


def fill_gutter(image: np.ndarray, covered: np.ndarray, baked: np.ndarray, dist: np.ndarray,
                gutter_setting: int) -> int:
    """Gutter (both routes): texels within the gutter (Chebyshev) of a covered texel that
    were not baked take the value of the nearest baked texel, in place. The gutter is
    widened to hold every texel a lookup inside a UV triangle can read (``dist``: texels
    to the nearest UV triangle; such texels lie within sqrt(2) of it). Returns the
    effective gutter."""
    cheb = ndimage.distance_transform_cdt(~covered, metric="chessboard")
    readable = baked & (dist <= math.sqrt(2.0) + 1e-9)
    gutter = int(max(gutter_setting, cheb[readable].max(initial=0)))
    fill = (~baked) & (cheb <= gutter)
    if fill.any():
        idx = ndimage.distance_transform_edt(~baked, return_distances=False, return_indices=True)
        fy, fx = np.nonzero(fill)
        image[fy, fx, :3] = image[idx[0][fy, fx], idx[1][fy, fx], :3]
    return gutter


def _origins(corners3, bary, inside, uvs, t_ids, xs, ys, W, H, texel_size):
    """Coarse-surface points of the texels to bake, and the barycentric coordinates
    (clamped onto the triangle for border texels) that interpolate their normals.

    Covered texels use their barycentric coordinates as they are. A border texel lies
    outside its UV triangle: its point is the triangle's point nearest in UV, moved on by
    the triangle's affine map of the remaining UV offset, with that move capped at
    BORDER_STRETCH_TEXELS texel sizes per texel. The affine map of a needle UV triangle
    is huge across the needle, and the uncapped extrapolation lands far off the part.
    """
    origin = np.einsum("kc,kcd->kd", bary, corners3)
    clamped = bary.copy()
    out = np.nonzero(~inside)[0]
    if len(out) == 0:
        return origin, clamped
    # only the border texels need their UV triangle in texel units (a fraction of all)
    corners_px = texel_coordinates(uvs[t_ids[out]], W, H)
    q = np.stack([xs[out], ys[out]], axis=1).astype(np.float64)
    a, bb, cc = corners_px[:, 0], corners_px[:, 1], corners_px[:, 2]
    near = _closest_on_triangle_2d(q, a, bb, cc)
    bn = np.clip(barycentric_2d(near, a, bb, cc), 0.0, 1.0)
    bn /= np.maximum(bn.sum(axis=1, keepdims=True), 1e-300)
    base = np.einsum("kc,kcd->kd", bn, corners3[out])
    step = origin[out] - base
    length = np.linalg.norm(step, axis=1)
    cap = C.BORDER_STRETCH_TEXELS * texel_size * np.linalg.norm(q - near, axis=1)
    scale = np.where(length > cap, cap / np.maximum(length, 1e-300), 1.0)
    origin[out] = base + scale[:, None] * step
    clamped[out] = bn
    return origin, clamped


def _closest_on_triangle_2d(q, a, b, c):
    """Nearest point of the boundary of 2D triangles (a, b, c) to points q outside them."""
    best = np.full(len(q), np.inf)
    point = np.zeros_like(q)
    for s0, s1 in ((a, b), (b, c), (c, a)):
        e = s1 - s0
        t = np.clip(np.einsum("kd,kd->k", q - s0, e) / np.maximum(np.einsum("kd,kd->k", e, e), 1e-300), 0.0, 1.0)
        p = s0 + t[:, None] * e
        d = np.linalg.norm(q - p, axis=1)
        closer = d < best
        best[closer], point[closer] = d[closer], p[closer]
    return point


def assign_texels(uvs: np.ndarray, W: int, H: int, chunk: int = 1 << 18):
    """Triangle and barycentric coordinates of each texel to bake.

    Returns (tri (H, W) int64, -1 where none; bary (H, W, 3) float64; distance (H, W) in
    texels to that triangle, inf where none). A texel takes the
    triangle at the smallest UV distance (0 inside), ties to the lower triangle id, among
    those within BAKE_BORDER_TEXELS.
    """
    p = texel_coordinates(uvs, W, H)                           # corners, texel units
    r = C.BAKE_BORDER_TEXELS
    lo = np.maximum(np.floor(p.min(axis=1) - r).astype(np.int64), 0)
    hi = np.minimum(np.ceil(p.max(axis=1) + r).astype(np.int64), [W - 1, H - 1])
    e = np.roll(p, -1, axis=1) - p                             # edges k -> k+1
    twice_area = np.abs(e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0])
    # A UV triangle of no area covers nothing; its lookups read its neighbours' texels.
    hi[twice_area <= C.UV_DEGENERATE_TEXELS2] = lo[twice_area <= C.UV_DEGENERATE_TEXELS2] - 1
    opposite = np.linalg.norm(np.roll(e, -1, axis=1), axis=2)  # edge opposite corner k
    altitude = twice_area[:, None] / np.maximum(opposite, 1e-300)

    best_d = np.full(H * W, np.inf)
    best_t = np.full(H * W, -1, dtype=np.int64)
    best_b = np.zeros((H * W, 3))
    for t, i, j in texel_candidates(lo, hi, chunk):
        q = np.stack([i, j], axis=1).astype(np.float64)
        a, bb, cc = p[t, 0], p[t, 1], p[t, 2]
        bary = barycentric_2d(q, a, bb, cc)
        # Lower bound of the distance outside: the largest distance past an edge line
        # (barycentric k times the altitude from corner k), cheap for every candidate.
        alt = altitude[t]                                        # (tot, 3)
        past = np.max(-bary * alt, axis=1)
        d = np.where(bary.min(axis=1) >= -C.INSIDE_EPS, 0.0, np.inf)
        band = np.nonzero(np.isinf(d) & (past <= r))[0]
        if len(band):
            d[band] = _segment_distance_2d(q[band], a[band], bb[band], cc[band])
        ok = d <= r
        flat = (j * W + i)[ok]
        d, t, bary = d[ok], t[ok], bary[ok]
        # best candidate per texel within this group: sort by (texel, distance, triangle)
        order = np.lexsort((t, d, flat))
        flat, d, t, bary = flat[order], d[order], t[order], bary[order]
        first = np.r_[True, flat[1:] != flat[:-1]]
        flat, d, t, bary = flat[first], d[first], t[first], bary[first]
        better = (d < best_d[flat]) | ((d == best_d[flat]) & (t < best_t[flat]))
        f = flat[better]
        best_d[f], best_t[f], best_b[f] = d[better], t[better], bary[better]
    return best_t.reshape(H, W), best_b.reshape(H, W, 3), best_d.reshape(H, W)


def _segment_distance_2d(q, a, b, c):
    """Distance of 2D points q to the boundary of triangles (a, b, c)."""
    return np.linalg.norm(q - _closest_on_triangle_2d(q, a, b, c), axis=1)


class RayCaster:
    """Nearest-hit ray queries against a triangle mesh with embree (embreex).

    Embree works in float32; the mesh and ray origins are shifted to the mesh's bbox
    centre first so precision follows the part's size, not its distance from the origin.
    Hits are then recomputed in float64 on the hit triangle's plane."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.center = 0.5 * (self.vertices.min(axis=0) + self.vertices.max(axis=0))
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self.scene,
                     vertices=(self.vertices - self.center).astype(np.float32),
                     indices=self.faces.astype(np.int32))
        tri = self.vertices[self.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.normals = n
        self.anchor = tri[:, 0]

    def first_hit(self, origins: np.ndarray, directions: np.ndarray, max_distance):
        """(distance, triangle) of the first hit along each ray within max_distance (a
        scalar or one per ray); distance inf and triangle -1 on a miss."""
        o = (origins - self.center).astype(np.float32)
        d = directions.astype(np.float32)
        reach = np.broadcast_to(np.asarray(max_distance, dtype=np.float32), (len(o),)).copy()
        res = self.scene.run(o, d, dists=reach, output=1)
        prim = np.asarray(res["primID"], dtype=np.int64)
        hit = prim >= 0
        dist = np.full(len(o), np.inf)
        if hit.any():
            # exact distance to the hit triangle's plane, in float64
            n = self.normals[prim[hit]]
            num = np.einsum("kd,kd->k", n, self.anchor[prim[hit]] - origins[hit])
            den = np.einsum("kd,kd->k", n, directions[hit])
            t = np.asarray(res["tfar"], dtype=np.float64)[hit]
            ok = np.abs(den) > 1e-12 * np.linalg.norm(n, axis=1)
            t[ok] = num[ok] / den[ok]
            dist[hit] = np.abs(t)
        return dist, np.where(hit, prim, -1)


def _cast(origin, normal, full_vertices, full_faces, max_distance, progress):
    """Nearest surface point along +-normal within max_distance (one per ray):
    (points, hit mask, hit triangle of the full mesh or -1, and the same hit the other
    way along the normal: points (NaN where none) and triangles, and whether the hit
    used is the one along -normal)."""
    caster = RayCaster(full_vertices, full_faces)
    n = len(origin)
    points = np.zeros((n, 3))
    hit = np.zeros(n, dtype=bool)
    prim = np.full(n, -1, dtype=np.int64)
    alt = np.full((n, 3), np.nan)
    alt_prim = np.full(n, -1, dtype=np.int64)
    neg = np.zeros(n, dtype=bool)
    for s in range(0, n, C.RAY_CHUNK):
        sl = slice(s, min(n, s + C.RAY_CHUNK))
        o, d, r = origin[sl], normal[sl], max_distance[sl]
        t_pos, p_pos = caster.first_hit(o, d, r)
        t_neg, p_neg = caster.first_hit(o, -d, r)
        use_neg = t_neg < t_pos
        t = np.where(use_neg, -t_neg, t_pos)
        ok = np.isfinite(t)
        points[sl] = o + np.where(ok, t, 0.0)[:, None] * d
        hit[sl] = ok
        prim[sl] = np.where(use_neg, p_neg, p_pos)
        t_alt = np.where(use_neg, t_pos, -t_neg)
        has = np.isfinite(t_alt)
        alt[sl] = np.where(has[:, None], o + np.where(has, t_alt, 0.0)[:, None] * d, np.nan)
        alt_prim[sl] = np.where(use_neg, p_pos, p_neg)
        neg[sl] = use_neg & ok
        if progress is not None:
            progress(sl.stop / n)
    return points, hit, prim, alt, alt_prim, neg


# --------------------------------------------------------------------------------------------
# Jumps: 4-neighbour texels whose reconstruction leaves the full surface
# --------------------------------------------------------------------------------------------
def texel_edges(ys, xs, chart, W: int, H: int):
    """4-neighbour pairs (a, b) of the texels (ys, xs) of one chart: indices into them,
    horizontal pairs first, each in row-major order (deterministic)."""
    idx = np.full((H, W), -1, dtype=np.int64)
    idx[ys, xs] = np.arange(len(ys))
    pairs = []
    for a, b in ((idx[:, :-1], idx[:, 1:]), (idx[:-1, :], idx[1:, :])):
        a, b = a.ravel(), b.ravel()
        ok = (a >= 0) & (b >= 0)
        a, b = a[ok], b[ok]
        ok = chart[a] == chart[b]
        pairs.append(np.stack([a[ok], b[ok]], axis=1))
    return np.concatenate(pairs)


def midpoint_offsets(points, prim, edges, texel_size, closest, tris):
    """(length, off) per edge: the distance between its two points and an upper bound of the
    distance of its midpoint to the full surface, exact where it exceeds
    JUMP_REPAIR_TEXELS texel sizes.

    The bound avoids a closest-point query per edge: the midpoint lies within half the
    length of either point, and within its distance of either point's hit triangle
    (``prim``, -1 where unknown; ``tris`` the full mesh's triangles); only edges whose
    bound is above the threshold are queried exactly (``closest``, a
    hbake.stages.geometry.ClosestPointQuery), a few in ten thousand on the shared models."""
    thr = C.JUMP_REPAIR_TEXELS * texel_size
    p, q = points[edges[:, 0]], points[edges[:, 1]]
    length = np.linalg.norm(p - q, axis=1)
    off = 0.5 * length
    mid = 0.5 * (p + q)
    need = np.nonzero(off > thr)[0]
    for end in (0, 1):
        t = prim[edges[need, end]]
        known = np.nonzero(t >= 0)[0]
        if len(known):
            tri = tris[t[known]]
            m = mid[need[known]]
            c, _ = closest_point_on_triangles(m, tri[:, 0], tri[:, 1], tri[:, 2])
            off[need[known]] = np.minimum(off[need[known]], np.linalg.norm(c - m, axis=1))
        need = need[off[need] > thr]
    if len(need):
        off[need] = closest(mid[need])[1]
    return length, off


def _label_walls(points, prim, pos, pos_prim, neg, neg_prim, edges, length, off, tx,
                 closest, tris, H_W_ys_xs):
    """Choose, for the texels around off edges, the hit along +normal or along -normal so
    that neighbours land on the same wall (a minimum s-t cut; see repair_jumps). Changes
    ``points`` and ``prim`` in place and returns the texels whose hit changed."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, maximum_flow

    H, W, ys, xs = H_W_ys_xs
    thr = C.JUMP_REPAIR_TEXELS * tx
    cut_len = C.DISCONTINUITY_TEXELS * tx
    n = len(points)
    bad = (length <= cut_len) & (off > thr)
    seed = np.zeros((H, W), dtype=bool)
    seed[ys[edges[bad].ravel()], xs[edges[bad].ravel()]] = True
    if not seed.any():
        return np.zeros(0, dtype=np.int64)
    grid = ndimage.binary_dilation(seed, iterations=C.JUMP_LABEL_RINGS)
    both = np.all(np.isfinite(pos), axis=1) & np.all(np.isfinite(neg), axis=1)
    region = grid[ys, xs] & both
    node = np.full(n, -1, dtype=np.int64)
    members = np.nonzero(region)[0]
    m = len(members)
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    node[members] = np.arange(m)
    hits = (pos, neg)
    hit_prims = (pos_prim, neg_prim)
    cur_neg = np.all(points == neg, axis=1) & both
    # unary: extra ray length over the nearer hit (a tie-break), plus the edges to fixed texels
    dist = [np.linalg.norm(h[members] - points[members], axis=1) for h in hits]
    near = np.minimum(dist[0], dist[1])
    unary = [np.ceil(C.JUMP_LABEL_UNARY * (d - near) / tx) for d in dist]

    # every chord the labelling can make, evaluated in one batch: (first point, its
    # triangle, second point, its triangle)
    a, b = edges[:, 0], edges[:, 1]
    ina, inb = region[a], region[b]
    chords = []
    for x, y in ((a, b), (b, a)):                     # region texel x, fixed neighbour y
        sel = np.nonzero(region[x] & ~region[y])[0]
        for lab in (0, 1):
            chords.append((hits[lab][x[sel]], hit_prims[lab][x[sel]], points[y[sel]], prim[y[sel]]))
    inner = np.nonzero(ina & inb)[0]
    ea, eb = a[inner], b[inner]
    chords.append((pos[ea], pos_prim[ea], neg[eb], neg_prim[eb]))      # a +, b -
    chords.append((neg[ea], neg_prim[ea], pos[eb], pos_prim[eb]))      # a -, b +
    sizes = [len(c[0]) for c in chords]
    pa = np.concatenate([c[0] for c in chords])
    total = len(pa)
    pts = np.concatenate([pa, np.concatenate([c[2] for c in chords])])
    prm = np.concatenate([np.concatenate([c[1] for c in chords]), np.concatenate([c[3] for c in chords])])
    lng, of = midpoint_offsets(pts, prm, np.stack([np.arange(total), total + np.arange(total)], axis=1),
                               tx, closest, tris)
    bad_chord = np.split((lng <= cut_len) & (of > thr), np.cumsum(sizes)[:-1])
    for q, (x, y) in enumerate(((a, b), (b, a))):
        sel = np.nonzero(region[x] & ~region[y])[0]
        for lab in (0, 1):
            np.add.at(unary[lab], node[x[sel]], C.JUMP_LABEL_EDGE * bad_chord[2 * q + lab])
    rows, cols, caps = [], [], []
    s_node, t_node = m, m + 1
    # source side = label 0 (+normal hit): cutting s->k costs label 1, k->t label 0
    rows += [np.full(m, s_node), np.arange(m)]
    cols += [np.arange(m), np.full(m, t_node)]
    caps += [unary[1], unary[0]]
    if len(inner):
        rows += [node[ea], node[eb]]
        cols += [node[eb], node[ea]]
        caps += [C.JUMP_LABEL_EDGE * bad_chord[4], C.JUMP_LABEL_EDGE * bad_chord[5]]
    r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(caps).astype(np.int64)
    keep = v > 0
    cap = coo_matrix((v[keep].astype(np.int32), (r[keep], c[keep])), shape=(m + 2, m + 2)).tocsr()
    flow = maximum_flow(cap, s_node, t_node, method="dinic").flow
    residual = (cap - flow).tocsr()
    residual.data = np.where(residual.data > 0, 1, 0).astype(np.int32)
    residual.eliminate_zeros()
    source_side = np.zeros(m + 2, dtype=bool)
    source_side[breadth_first_order(residual, s_node, directed=True, return_predecessors=False)] = True
    want_neg = ~source_side[:m]
    change = want_neg != cur_neg[members]
    k = members[change]
    wn = want_neg[change]
    points[k] = np.where(wn[:, None], neg[k], pos[k])
    prim[k] = np.where(wn, neg_prim[k], pos_prim[k])
    return k


def _push_apart(points, prim, act, slot, j, e, length, off, cut_len, tris):
    """For each texel ``act``, the surface point reached by sliding it along its own hit
    triangle's plane away from the neighbour of its worst uncut edge until the two are
    5 % more than the cut length apart (closest point of the full surface to that
    target): the candidate that turns a chord across a gap into a discontinuity by the
    rule while the texel stays on its own wall: the targets (to be projected onto the
    surface), NaN where there is no such move."""
    m = len(act)
    out = np.full((m, 3), np.nan)
    worst = np.where(length[e] <= cut_len, off[e], -np.inf)
    order = np.lexsort((-worst, slot))               # per slot, the worst edge first
    first = order[np.r_[True, slot[order][1:] != slot[order][:-1]]]
    k_slot, partner = slot[first], j[first]
    ok = np.isfinite(worst[first]) & (prim[act[k_slot]] >= 0)
    if not ok.any():
        return out
    ks, pj = k_slot[ok], partner[ok]
    p = points[act[ks]]
    t = tris[prim[act[ks]]]
    nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    g = p - points[pj]
    gn = np.einsum("kd,kd->k", g, nrm)
    gt = g - gn[:, None] * nrm
    lt = np.linalg.norm(gt, axis=1)
    need = 1.05 * cut_len
    fine = (np.abs(gn) < need) & (lt > 1e-9 * cut_len)
    if not fine.any():
        return out
    delta = np.sqrt(need ** 2 - gn[fine] ** 2) - lt[fine]
    target = p[fine] + (delta / lt[fine])[:, None] * gt[fine]
    out[ks[fine]] = target
    return out


def repair_jumps(points, prim, alt, alt_prim, use_neg, ys, xs, chart, W: int, H: int,
                 texel_size: float, full_vertices, full_faces) -> dict:
    """Re-choose the baked points of texels whose reconstruction leaves the surface, in place.

    An edge between 4-neighbour texels of one chart is *cut* (a discontinuity: the
    runtime interpolates no 2x2 quad that has it) when its points are more than
    DISCONTINUITY_TEXELS texel sizes apart; an uncut edge is *off* when its midpoint (what
    a bilinear lookup on it reads) lies more than JUMP_REPAIR_TEXELS texel sizes from the
    full surface. Measured on the shared models, nearly all off edges join the two hits of
    a coarse point that lies between two walls closer than the cut length (meshing teeth
    of two gears, a thin tooth, the two sides of a thin part): the nearest hit switches
    walls along the medial line, and the chord between the walls is in the air. The rest
    are rays fanning over a sharp crease that the coarse surface bevels.

    Repair, for the texels at the ends of off edges: each tries its other hit along the
    normal (the other wall), the closest point of the full surface to the mean of its
    uncut neighbours (a projected Laplacian step, which walks points onto a skipped
    crease) and its own ray hit, and takes the best that improves its score: first the
    worst midpoint offset of its uncut edges (the threshold as the floor), then the
    number of its cut edges. So a wall switch moves to where the walls are within a texel
    (the chord stays on the surface) or farther apart than the cut length (a
    discontinuity by the rule), and every kept move improves. The two colours of the
    checkerboard move in turn (a texel's 4-neighbours are of the other colour, so each
    move is judged against fixed neighbours), for at most JUMP_REPAIR_ITERATIONS rounds.
    Deterministic: no randomness, fixed orders. Every point stays on the full surface.

    Returns the counts for the manifest (atlas.discontinuities).
    """
    tx = float(texel_size)
    thr = C.JUMP_REPAIR_TEXELS * tx
    gain = C.JUMP_REPAIR_GAIN_TEXELS * tx
    cut_len = C.DISCONTINUITY_TEXELS * tx
    full_vertices = np.asarray(full_vertices, dtype=np.float64)
    full_faces = np.asarray(full_faces, dtype=np.int64)
    tris = full_vertices[full_faces]
    closest = ClosestPointQuery(full_vertices, full_faces)
    edges = texel_edges(ys, xs, chart, W, H)
    n = len(points)
    own, own_prim = points.copy(), prim.copy()
    length, off = midpoint_offsets(points, prim, edges, tx, closest, tris)
    off_before = int(((length <= cut_len) & (off > thr)).sum())
    cut_before = int((length > cut_len).sum())
    # 1. the wall each texel's ray lands on, consistently with its neighbours
    un = use_neg[:, None]
    pos, neg = np.where(un, alt, points), np.where(un, points, alt)
    pos_prim, neg_prim = np.where(use_neg, alt_prim, prim), np.where(use_neg, prim, alt_prim)
    relabelled = _label_walls(points, prim, pos, pos_prim, neg, neg_prim, edges, length, off,
                              tx, closest, tris, (H, W, ys, xs))
    if len(relabelled):
        touched = np.zeros(n, dtype=bool)
        touched[relabelled] = True
        sel = np.nonzero(touched[edges[:, 0]] | touched[edges[:, 1]])[0]
        length[sel], off[sel] = midpoint_offsets(points, prim, edges[sel], tx, closest, tris)
    off_walls = int(((length <= cut_len) & (off > thr)).sum())
    # incidence: the edges of each texel (sorted by texel), and the texel at their other end
    ends = np.concatenate([edges[:, 0], edges[:, 1]])
    other = np.concatenate([edges[:, 1], edges[:, 0]])
    eid = np.concatenate([np.arange(len(edges)), np.arange(len(edges))])
    order = np.argsort(ends, kind="stable")
    ends, other, eid = ends[order], other[order], eid[order]
    start = np.searchsorted(ends, np.arange(n + 1))
    colour = (ys + xs) % 2
    rounds = 0

    def incident(act):
        cnt = start[act + 1] - start[act]
        slot = np.repeat(np.arange(len(act)), cnt)
        pos = np.repeat(start[act], cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        return slot, other[pos], eid[pos]

    def score(slot, m, lng, of):
        cut = lng > cut_len
        cuts = np.bincount(slot, weights=cut.astype(float), minlength=m)
        worst = np.full(m, thr)
        np.maximum.at(worst, slot, np.where(cut, thr, of))
        return worst, cuts

    for rounds in range(1, C.JUMP_REPAIR_ITERATIONS + 1):
        kept_any = False
        for c in (0, 1):
            bad_e = np.nonzero((length <= cut_len) & (off > thr))[0]
            if len(bad_e) == 0:
                break
            act = np.unique(edges[bad_e].ravel())
            act = act[colour[act] == c]
            if len(act) == 0:
                continue
            slot, j, e = incident(act)
            best_w, best_c = score(slot, len(act), length[e], off[e])
            # candidates: the other hit, the projected neighbour mean, the texel's own hit,
            # the slide along its own wall; the two projections in one query
            uncut = length[e] <= cut_len
            cnt = np.bincount(slot[uncut], minlength=len(act))
            mean = np.stack([np.bincount(slot[uncut], weights=points[j[uncut], d], minlength=len(act))
                             for d in range(3)], axis=1) / np.maximum(cnt, 1)[:, None]
            mean[cnt == 0] = np.nan
            push = _push_apart(points, prim, act, slot, j, e, length, off, cut_len, tris)
            targets = np.concatenate([mean, push])
            fin = np.all(np.isfinite(targets), axis=1)
            proj = np.full_like(targets, np.nan)
            proj[fin] = closest(targets[fin])[0]
            none = np.full(len(act), -1)
            cands = [(alt[act], alt_prim[act]), (proj[:len(act)], none), (own[act], own_prim[act]),
                     (proj[len(act):], none)]
            # all candidates' chords in one batch
            trials, tprims, oks = [], [], []
            for cand, cprim in cands:
                ok = np.all(np.isfinite(cand), axis=1) & np.any(cand != points[act], axis=1)
                trials.append(np.where(ok[:, None], cand, points[act]))
                tprims.append(np.where(ok, cprim, prim[act]))
                oks.append(ok)
            ne = len(slot)
            q = np.concatenate([t[slot] for t in trials])
            pr = np.concatenate([t[slot] for t in tprims])
            nq = len(q)
            jj = np.tile(j, len(cands))
            lng_all, of_all = midpoint_offsets(np.concatenate([q, points[jj]]),
                                               np.concatenate([pr, prim[jj]]),
                                               np.stack([np.arange(nq), nq + np.arange(nq)], axis=1),
                                               tx, closest, tris)
            choice = np.full(len(act), -1)
            for ci in range(len(cands)):
                lng, of = lng_all[ci * ne:(ci + 1) * ne], of_all[ci * ne:(ci + 1) * ne]
                w1, c1 = score(slot, len(act), lng, of)
                better = oks[ci] & ((w1 < best_w - gain) | ((w1 <= best_w + gain) & (c1 < best_c)))
                best_w = np.where(better, w1, best_w)
                best_c = np.where(better, c1, best_c)
                choice[better] = ci
            change = choice >= 0
            if not change.any():
                continue
            kept_any = True
            kk = np.nonzero(change)[0]
            ch = choice[kk]
            points[act[kk]] = np.stack(trials)[ch, kk]
            prim[act[kk]] = np.stack(tprims)[ch, kk]
            upd = np.nonzero(change[slot])[0]
            pick = choice[slot[upd]] * ne + upd
            length[e[upd]], off[e[upd]] = lng_all[pick], of_all[pick]
        if not kept_any:
            break
    moved = np.any(points != own, axis=1)
    uncut = length <= cut_len
    left = uncut & (off > thr)
    return {"rule_texels": float(C.DISCONTINUITY_TEXELS),
            "repair_threshold_texels": float(C.JUMP_REPAIR_TEXELS),
            "edges": int(len(edges)),
            "cut_before": cut_before, "cut": int((~uncut).sum()),
            "off_before": off_before, "off_after_walls": off_walls, "off_after": int(left.sum()),
            "texels_relabelled": int(len(relabelled)),
            "texels_moved": int(moved.sum()), "rounds": int(rounds),
            "max_off_texels": float(off[uncut].max(initial=0.0) / tx)}
