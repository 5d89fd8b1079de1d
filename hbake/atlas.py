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
  field past its edge (alpha 0). A bilinear lookup at a point inside a UV triangle
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
from hbake.geometry import closest_points, face_normals, vertex_normals
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
    displacement_outward: float  # m, max height of the baked surface above the coarse triangles
    displacement_inward: float   # m, max depth below
    rays: int                   # texels baked by ray casting
    fallbacks: int              # of which no hit within max distance: closest point used


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

    # Points on the coarse surface and interpolated normals (the cage's ray directions).
    vn = vertex_normals(V, F)
    fn = face_normals(V, F)
    corner = F[t_ids]                                         # (K, 3)
    origin = np.einsum("kc,kcd->kd", b, V[corner])
    normal = np.einsum("kc,kcd->kd", b, vn[corner])
    length = np.linalg.norm(normal, axis=1)
    weak = length < 1e-6                                       # opposite normals cancel
    normal[weak] = fn[t_ids[weak]]
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)

    points, hit = _cast(origin, normal, full_vertices, full_faces, cage.max_ray_distance * diag,
                        progress)
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

    # Heights of the baked points over their coarse triangle's plane (outward normal).
    h = np.einsum("kd,kd->k", points - origin, fn[t_ids])
    outward = float(max(h.max(), 0.0))
    inward = float(max(-h.min(), 0.0))

    # Texel size: 3D length of one texel step, sqrt(3D area / texel area) per triangle.
    tri3 = V[F]
    area3 = 0.5 * np.linalg.norm(np.cross(tri3[:, 1] - tri3[:, 0], tri3[:, 2] - tri3[:, 0]), axis=1)
    px = uvs * np.array([W, H])
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    areat = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    per_tri = np.sqrt(area3 / np.maximum(areat, 1e-300))
    cov_tris = triangle[covered]
    texel_size = float(np.median(per_tri[cov_tris]))

    return BakedAtlas(image=image, triangle=triangle, covered=covered, baked=baked,
                      coverage=float(covered.mean()), gutter=gutter, texel_size=texel_size,
                      displacement_outward=outward, displacement_inward=inward,
                      rays=int(len(t_ids)), fallbacks=int(len(misses)))


def assign_texels(uvs: np.ndarray, W: int, H: int, chunk: int = 1 << 20):
    """Triangle and barycentric coordinates of each texel to bake.

    Returns (tri (H, W) int64, -1 where none; bary (H, W, 3) float64; distance (H, W) in
    texels to that triangle, inf where none). A texel takes the
    triangle at the smallest UV distance (0 inside), ties to the lower triangle id, among
    those within BAKE_BORDER_TEXELS.
    """
    M = len(uvs)
    # continuous texel coordinates of the corners (texel centres at integers)
    p = np.empty((M, 3, 2))
    p[..., 0] = uvs[..., 0] * W - 0.5
    p[..., 1] = (1.0 - uvs[..., 1]) * H - 0.5
    r = C.BAKE_BORDER_TEXELS
    lo = np.floor(p.min(axis=1) - r).astype(np.int64)
    hi = np.ceil(p.max(axis=1) + r).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [W - 1, H - 1])
    nx = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    ny = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    count = nx * ny
    e = np.roll(p, -1, axis=1) - p                             # edges k -> k+1
    twice_area = np.abs(e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0])
    opposite = np.linalg.norm(np.roll(e, -1, axis=1), axis=2)  # edge opposite corner k
    altitude = twice_area[:, None] / np.maximum(opposite, 1e-300)

    best_d = np.full(H * W, np.inf)
    best_t = np.full(H * W, -1, dtype=np.int64)
    best_b = np.zeros((H * W, 3))
    # Process triangles in groups holding about `chunk` candidate texels each.
    cum = np.cumsum(count)
    edges = np.unique(np.r_[0, np.searchsorted(cum, np.arange(chunk, cum[-1] if M else 0, chunk)) + 1, M])
    for start, end in zip(edges[:-1], edges[1:]):
        sel = np.arange(start, end)
        cnt = count[sel]
        tot = int(cnt.sum())
        if tot == 0:
            continue
        t = np.repeat(sel, cnt)
        k = np.arange(tot) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        i = lo[t, 0] + k % nx[t]
        j = lo[t, 1] + k // nx[t]
        q = np.stack([i, j], axis=1).astype(np.float64)
        a, bb, cc = p[t, 0], p[t, 1], p[t, 2]
        bary = _barycentric_2d(q, a, bb, cc)
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
    best = np.full(len(q), np.inf)
    for s0, s1 in ((a, b), (b, c), (c, a)):
        e = s1 - s0
        w = q - s0
        t = np.clip(np.einsum("kd,kd->k", w, e) / np.maximum(np.einsum("kd,kd->k", e, e), 1e-300), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(w - t[:, None] * e, axis=1))
    return best


def _barycentric_2d(q, a, b, c):
    """Barycentric coordinates of 2D points q in triangles (a, b, c); may be negative."""
    v0, v1, v2 = b - a, c - a, q - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(den == 0, 1e-300, den)
    beta = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    gamma = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    return np.stack([1.0 - beta - gamma, beta, gamma], axis=1)


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

    def first_hit(self, origins: np.ndarray, directions: np.ndarray, max_distance: float):
        """(distance, triangle) of the first hit along each ray within max_distance;
        distance inf and triangle -1 on a miss."""
        o = (origins - self.center).astype(np.float32)
        d = directions.astype(np.float32)
        res = self.scene.run(o, d, dists=np.full(len(o), max_distance, dtype=np.float32), output=1)
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
    """Nearest surface point along +-normal within max_distance: (points, hit mask)."""
    caster = RayCaster(full_vertices, full_faces)
    n = len(origin)
    points = np.empty((n, 3))
    hit = np.zeros(n, dtype=bool)
    for s in range(0, n, C.RAY_CHUNK):
        sl = slice(s, min(n, s + C.RAY_CHUNK))
        o, d = origin[sl], normal[sl]
        t_pos, _ = caster.first_hit(o, d, max_distance)
        t_neg, _ = caster.first_hit(o, -d, max_distance)
        use_neg = t_neg < t_pos
        t = np.where(use_neg, -t_neg, t_pos)
        ok = np.isfinite(t)
        points[sl] = o + np.where(ok, t, 0.0)[:, None] * d
        hit[sl] = ok
        if progress is not None:
            progress(sl.stop / n)
    return points, hit
