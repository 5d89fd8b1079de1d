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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from hbake import constants as C
from hbake.errors import BakeFailedError
from hbake.geometry import closest_points, face_normals, signed_distances, vertex_normals
from hbake.parameterize import barycentric_2d, texel_candidates, texel_coordinates
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
    points, hit = _cast(origin, normal, full_vertices, full_faces, reach, progress)
    misses = np.nonzero(~hit)[0]
    if len(misses):
        points[misses] = closest_points(full_vertices, full_faces, origin[misses])[0]

    image = np.zeros((H, W, 4), dtype=np.float32)
    image[ys, xs, :3] = points.astype(np.float32)
    image[..., 3] = covered.astype(np.float32)
    triangle = np.full((H, W), -1, dtype=np.int64)
    triangle[ys, xs] = t_ids

    # Gutter: texels within `gutter` (Chebyshev) of a covered texel that no ray baked take
    # the value of the nearest baked texel.
    cheb = ndimage.distance_transform_cdt(~covered, metric="chessboard")
    # texels a bilinear lookup inside a triangle can read lie within sqrt(2) of it
    readable = baked & (dist <= math.sqrt(2.0) + 1e-9)
    gutter = int(max(atlas.gutter, cheb[readable].max(initial=0)))
    fill = (~baked) & (cheb <= gutter)
    if fill.any():
        idx = ndimage.distance_transform_edt(~baked, return_distances=False, return_indices=True)
        fy, fx = np.nonzero(fill)
        image[fy, fx, :3] = image[idx[0][fy, fx], idx[1][fy, fx], :3]

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
                      border_fallbacks=int((~hit & ~inside).sum()))


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
    point = np.empty_like(q)
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
    (points, hit mask)."""
    caster = RayCaster(full_vertices, full_faces)
    n = len(origin)
    points = np.empty((n, 3))
    hit = np.zeros(n, dtype=bool)
    for s in range(0, n, C.RAY_CHUNK):
        sl = slice(s, min(n, s + C.RAY_CHUNK))
        o, d, r = origin[sl], normal[sl], max_distance[sl]
        t_pos, _ = caster.first_hit(o, d, r)
        t_neg, _ = caster.first_hit(o, -d, r)
        use_neg = t_neg < t_pos
        t = np.where(use_neg, -t_neg, t_pos)
        ok = np.isfinite(t)
        points[sl] = o + np.where(ok, t, 0.0)[:, None] * d
        hit[sl] = ok
        if progress is not None:
            progress(sl.stop / n)
    return points, hit
