"""Vectorised triangle-mesh geometry shared by the stages.

Exact closest points (``closest_points`` for large meshes, ``closest_point_on_triangles``
as the vectorised brute-force reference), area-uniform surface sampling, vertex normals, topology checks (closed, bodies) and winding numbers.
Everything is numpy/scipy; no per-element Python loops.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


# --------------------------------------------------------------------------------------------
# point-triangle closest point
# --------------------------------------------------------------------------------------------
def closest_point_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """Closest point of each triangle (a, b, c) to p; all arrays (..., 3), broadcast.

    Voronoi-region method (Ericson, Real-Time Collision Detection, 5.1.5), written with
    masks so it runs on whole arrays. Returns (points, barycentric (..., 3)).
    """
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("...i,...i", ab, ap)
    d2 = np.einsum("...i,...i", ac, ap)
    bp = p - b
    d3 = np.einsum("...i,...i", ab, bp)
    d4 = np.einsum("...i,...i", ac, bp)
    cp = p - c
    d5 = np.einsum("...i,...i", ab, cp)
    d6 = np.einsum("...i,...i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2

    shape = np.broadcast_shapes(d1.shape, d3.shape, d5.shape)
    v = np.zeros(shape)      # weight of b
    w = np.zeros(shape)      # weight of c
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        safe = np.where(denom != 0, denom, 1.0)
        v[...] = vb / safe
        w[...] = vc / safe
        # Regions are assigned from the last to the first, so the earlier (vertex and
        # edge) regions of Ericson's order win where several conditions hold.
        bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        t = (d4 - d3) / np.where(bc, (d4 - d3) + (d5 - d6), 1.0)
        v = np.where(bc, 1 - t, v)
        w = np.where(bc, t, w)
        ac_r = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = d2 / np.where(ac_r, d2 - d6, 1.0)
        v = np.where(ac_r, 0.0, v)
        w = np.where(ac_r, t, w)
        c_r = (d6 >= 0) & (d5 <= d6)
        v = np.where(c_r, 0.0, v)
        w = np.where(c_r, 1.0, w)
        ab_r = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = d1 / np.where(ab_r, d1 - d3, 1.0)
        v = np.where(ab_r, t, v)
        w = np.where(ab_r, 0.0, w)
        b_r = (d3 >= 0) & (d4 <= d3)
        v = np.where(b_r, 1.0, v)
        w = np.where(b_r, 0.0, w)
        a_r = (d1 <= 0) & (d2 <= 0)
        v = np.where(a_r, 0.0, v)
        w = np.where(a_r, 0.0, w)
    # A degenerate triangle that slipped through every region gives NaN: use vertex a.
    bad = ~(np.isfinite(v) & np.isfinite(w))
    if bad.any():
        v = np.where(bad, 0.0, v)
        w = np.where(bad, 0.0, w)
    point = a + v[..., None] * ab + w[..., None] * ac
    bary = np.stack([1 - v - w, v, w], axis=-1)
    return point, bary


def _mesh_and_points(vertices, faces, points):
    """A MeshSet with the mesh (id 0) and the points (id 1), and a search bound beyond
    any possible distance between them (MeshLab's filters skip points past their bound)."""
    import pymeshlab

    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    lo = np.minimum(vertices.min(axis=0), points.min(axis=0))
    hi = np.maximum(vertices.max(axis=0), points.max(axis=0))
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices,
                               face_matrix=np.ascontiguousarray(faces, dtype=np.int32)))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
    return ms, 2.0 * float(np.linalg.norm(hi - lo)) + 1.0


def closest_points(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray):
    """Exact closest points of a triangle mesh to ``points``: (closest (n, 3), distance (n,)).

    Uses MeshLab's vertex attribute transfer (a uniform-grid search in C++, about 0.5 s
    for 100k points on 650k triangles), with a search bound beyond any possible
    distance so every point is transferred. Agrees with the brute-force
    ``closest_point_on_triangles`` to round-off (tests/hbake/stages/test_stages.py).
    """
    import pymeshlab

    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    ms, bound = _mesh_and_points(vertices, faces, points)
    ms.transfer_attributes_per_vertex(sourcemesh=0, targetmesh=1, geomtransfer=True,
                                      colortransfer=False, normaltransfer=False,
                                      qualitytransfer=False, selectiontransfer=False,
                                      qualitydistance=False,
                                      upperbound=pymeshlab.PureValue(bound))
    closest = np.asarray(ms.mesh(1).vertex_matrix(), dtype=np.float64)
    if closest.shape != points.shape:
        raise RuntimeError("closest-point transfer changed the number of points")
    return closest, np.linalg.norm(closest - points, axis=1)


class ClosestPointQuery:
    """``closest_points`` against one mesh for many small batches of points: the MeshSet
    with the mesh is built once (building it is most of the cost of a small query).
    Same MeshLab filter and bound, so the same answers."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import pymeshlab

        self._pymeshlab = pymeshlab
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.lo, self.hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        self.ms = pymeshlab.MeshSet()
        self.ms.add_mesh(pymeshlab.Mesh(vertex_matrix=self.vertices,
                                        face_matrix=np.ascontiguousarray(faces, dtype=np.int32)))
        self.source = self.ms.current_mesh_id()

    def __call__(self, points: np.ndarray):
        """(closest (n, 3), distance (n,))."""
        pml = self._pymeshlab
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if len(points) == 0:
            return np.zeros((0, 3)), np.zeros(0)
        lo = np.minimum(self.lo, points.min(axis=0))
        hi = np.maximum(self.hi, points.max(axis=0))
        bound = 2.0 * float(np.linalg.norm(hi - lo)) + 1.0
        self.ms.add_mesh(pml.Mesh(vertex_matrix=points))
        target = self.ms.current_mesh_id()
        try:
            self.ms.transfer_attributes_per_vertex(sourcemesh=self.source, targetmesh=target,
                                                   geomtransfer=True, colortransfer=False,
                                                   normaltransfer=False, qualitytransfer=False,
                                                   selectiontransfer=False, qualitydistance=False,
                                                   upperbound=pml.PureValue(bound))
            closest = np.asarray(self.ms.mesh(target).vertex_matrix(), dtype=np.float64)
        finally:
            self.ms.set_current_mesh(target)
            self.ms.delete_current_mesh()
        if closest.shape != points.shape:
            raise RuntimeError("closest-point transfer changed the number of points")
        return closest, np.linalg.norm(closest - points, axis=1)


def signed_distances(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Signed distance of ``points`` to a triangle mesh: positive on the side its face
    normals point to (outside, for an outward mesh). MeshLab's distance filter: the sign
    comes from the normal of the closest face."""
    import pymeshlab

    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0)
    ms, bound = _mesh_and_points(vertices, faces, points)
    ms.compute_scalar_by_distance_from_another_mesh_per_vertex(
        measuremesh=1, refmesh=0, signeddist=True, maxdist=pymeshlab.PureValue(bound))
    d = np.asarray(ms.mesh(1).vertex_scalar_array(), dtype=np.float64)
    if d.shape != (len(points),):
        raise RuntimeError("signed distance changed the number of points")
    return d


# --------------------------------------------------------------------------------------------
# sampling and normals
# --------------------------------------------------------------------------------------------
def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator):
    """Area-uniform random points: (points (n, 3), face ids (n,), barycentric (n, 3))."""
    area = face_areas(vertices, faces)
    cdf = np.cumsum(area)
    face = np.searchsorted(cdf, rng.random(count) * cdf[-1], side="right")
    face = np.minimum(face, len(faces) - 1)
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)                       # uniform on the triangle (Osada et al. 2002)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    tri = vertices[faces[face]]
    return np.einsum("nk,nkd->nd", bary, tri), face, bary


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Angle-weighted vertex normals (Thuermer and Wuethrich), independent of tessellation."""
    tri = vertices[faces]
    fn = face_normals(vertices, faces)
    normals = np.zeros_like(vertices, dtype=np.float64)
    for k in range(3):
        e1 = tri[:, (k + 1) % 3] - tri[:, k]
        e2 = tri[:, (k + 2) % 3] - tri[:, k]
        cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        np.add.at(normals, faces[:, k], fn * ang[:, None])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.maximum(length, 1e-300)


# --------------------------------------------------------------------------------------------
# topology
# --------------------------------------------------------------------------------------------
def unique_rows(a: np.ndarray):
    """Unique rows of a 2-D array by sorting (much faster than np.unique(axis=0)).

    Returns (first, inverse): ``first`` the index of the first occurrence of each
    distinct row, ascending; ``inverse`` maps every row to its position in ``first``.
    """
    order = np.lexsort(a.T[::-1])
    sa = a[order]
    new = np.ones(len(a), dtype=bool)
    new[1:] = (sa[1:] != sa[:-1]).any(axis=1)
    starts = np.nonzero(new)[0]
    first_sorted = np.minimum.reduceat(order, starts) if len(a) else order
    group = np.cumsum(new) - 1
    # renumber groups by first occurrence so the result does not depend on sort order
    rank = np.zeros(len(starts), dtype=np.int64)
    by_first = np.argsort(first_sorted, kind="stable")
    rank[by_first] = np.arange(len(starts))
    inverse = np.zeros(len(a), dtype=np.int64)
    inverse[order] = rank[group]
    return first_sorted[by_first], inverse


def _edge_keys(faces: np.ndarray):
    d = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).astype(np.int64)
    n = int(d.max()) + 1 if len(d) else 1
    return d, n


def boundary_edge_count(faces: np.ndarray) -> int:
    """Undirected edges used by exactly one face."""
    d, n = _edge_keys(faces)
    key = np.sort(np.minimum(d[:, 0], d[:, 1]) * n + np.maximum(d[:, 0], d[:, 1]))
    starts = np.r_[0, np.nonzero(np.diff(key))[0] + 1]
    counts = np.diff(np.r_[starts, len(key)])
    return int((counts == 1).sum())


def is_closed(faces: np.ndarray) -> bool:
    """Closed and consistently oriented: every directed edge appears once and its
    reverse appears once (so every undirected edge has exactly two faces)."""
    if len(faces) < 4:
        return False
    d, n = _edge_keys(faces)
    key = d[:, 0] * n + d[:, 1]
    rkey = d[:, 1] * n + d[:, 0]
    key_sorted = np.sort(key)
    if (np.diff(key_sorted) == 0).any():          # a directed edge used twice
        return False
    pos = np.searchsorted(key_sorted, rkey)
    pos = np.minimum(pos, len(key_sorted) - 1)
    return bool((key_sorted[pos] == rkey).all())


def face_components(faces: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected bodies (sharing vertices): (count, label per face)."""
    f = faces.astype(np.int64)
    rows = np.concatenate([f[:, 0], f[:, 1]])
    cols = np.concatenate([f[:, 1], f[:, 2]])
    g = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    count, vlabel = connected_components(g, directed=False)
    # vertices not referenced by any face form their own components: renumber by faces
    flabel = vlabel[f[:, 0]]
    present = np.bincount(flabel, minlength=count) > 0
    renum = np.cumsum(present) - 1
    return int(present.sum()), renum[flabel]


def signed_volumes(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed volume of the tetrahedron (origin, face) per face; sums to the solid's
    volume for a closed outward mesh (divergence theorem)."""
    tri = vertices[faces]
    return np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0


def winding_numbers(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                    chunk: int = 2048) -> np.ndarray:
    """Generalized winding number of each point (1 inside, 0 outside a closed outward
    mesh), from the solid angles of the triangles (Van Oosterom and Strackee 1983).
    O(points x faces): meant for coarse meshes."""
    tri = vertices[faces]
    out = np.zeros(len(points))
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk]
        a = tri[None, :, 0] - p[:, None]
        b = tri[None, :, 1] - p[:, None]
        c = tri[None, :, 2] - p[:, None]
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc
               + np.einsum("pfi,pfi->pf", b, c) * la + np.einsum("pfi,pfi->pf", c, a) * lb)
        out[s:s + chunk] = np.arctan2(num, den).sum(axis=1) / (2 * np.pi)
    return out


def bbox_diagonal(vertices: np.ndarray) -> float:
    return float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
