"""Stage 5: convex decomposition of the coarse mesh and the piece <-> triangle map.

Collision detection runs on convex pieces of the coarse mesh (Sec. 6.1, after Kim et
al.). CoACD (approximate convex decomposition by collision-aware concavity and tree
search) covers the whole volume, unlike V-HACD, and takes an explicit seed, so the
result is reproducible.

Each piece CoACD returns is rounded to float32 (what the bundle stores) and re-hulled
with qhull, so every stored piece is exactly convex with outward faces; FCL's Convex
needs both the vertices and the faces.

The map is many-to-many: coarse triangle t belongs to piece p when t comes within
``map_tolerance`` of p's hull. The test is exact for the hull grown by the tolerance
along every face plane (a slight superset of the tolerance ball around the hull, which
errs on the safe side: the runtime renders a few more triangles, never fewer): a quick
bounding-box and separating-plane pass decides almost every pair, and the rest are
decided by clipping the triangle against the planes.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hbake.bundle import MAX_PIECE_VERTICES
from hbake.errors import BakeFailedError
from hbake.stages.geometry import is_closed
from hbake.stages.mass import convex_hull_mesh
from hbake.settings import DecomposeSettings


@dataclass
class Pieces:
    vertices: list[np.ndarray]       # per piece (k, 3) float64 holding float32 values
    faces: list[np.ndarray]          # per piece (f, 3) int64 local indices, outward
    coarse_faces: list[np.ndarray]   # per piece sorted unique coarse triangle ids
    map_tolerance: float             # m
    coacd_pieces: int                # pieces CoACD returned (before dropping flat ones)
    warnings: list[str] = field(default_factory=list)


def decompose(coarse_vertices: np.ndarray, coarse_faces: np.ndarray,
              settings: DecomposeSettings | None = None, seed: int = 0, warn=None,
              solid: tuple[np.ndarray, np.ndarray] | None = None) -> Pieces:
    """Convex pieces of ``solid`` (default: the coarse mesh; for an open coarse mesh the
    pipeline passes it with its holes capped) mapped onto the coarse triangles."""
    import coacd

    settings = settings or DecomposeSettings()
    warnings: list[str] = []

    def _warn(msg):
        warnings.append(msg)
        if warn is not None:
            warn(msg)

    V = np.asarray(coarse_vertices, dtype=np.float64)
    F = np.asarray(coarse_faces, dtype=np.int64)
    SV, SF = (V, F) if solid is None else (np.asarray(solid[0], dtype=np.float64),
                                           np.asarray(solid[1], dtype=np.int64))
    # CoACD needs a manifold: its "auto" also remeshes a closed mesh that merely has
    # self-intersecting triangles (quadric collapse makes a few on CAD parts), turning
    # 600 triangles into ~50k and the run 4-10 times slower; ours remeshes only a mesh
    # that is not closed (a voxel remesh of an open surface makes a thin shell).
    mode = settings.preprocess_mode
    if mode == "auto":
        mode = "off" if is_closed(SF) else "on"
    coacd.set_log_level("error")

    def run(decimate: bool):
        try:
            return coacd.run_coacd(
                coacd.Mesh(SV, SF),
                threshold=float(settings.threshold),
                max_convex_hull=int(settings.max_pieces),
                preprocess_mode=mode,
                preprocess_resolution=int(settings.preprocess_resolution),
                resolution=int(settings.resolution),
                mcts_nodes=int(settings.mcts_nodes),
                mcts_iterations=int(settings.mcts_iterations),
                mcts_max_depth=int(settings.mcts_max_depth),
                pca=False,
                merge=True,
                decimate=decimate,
                max_ch_vertex=MAX_PIECE_VERTICES,   # only applies with decimate=True
                extrude=False,
                apx_mode="ch",
                seed=int(seed),
            )
        except Exception as exc:  # CoACD raises RuntimeError on meshes it cannot process
            raise BakeFailedError(f"convex decomposition (CoACD) failed: {exc}") from None

    parts = run(decimate=False)
    pv, pf, dropped = _hulls(parts)
    if any(len(h) > MAX_PIECE_VERTICES for h in pv):
        # A bundle's piece has at most 1024 vertices (docs/input-contract.md). The voxel
        # remesh of an open or non-manifold coarse mesh can give hulls of thousands of
        # vertices; only then is CoACD rerun (same seed) with its hull decimation, so
        # every other bake keeps its bytes. hull_deviation is measured on the result.
        most = max(len(h) for h in pv)
        parts = run(decimate=True)
        pv, pf, dropped = _hulls(parts)
        if any(len(h) > MAX_PIECE_VERTICES for h in pv):
            raise BakeFailedError(
                f"convex decomposition (CoACD) gave a piece of {max(len(h) for h in pv)} "
                f"vertices, more than the limit {MAX_PIECE_VERTICES}, even with its hull "
                f"decimation (try --set decompose.threshold=0.1)")
        _warn(f"CoACD gave a convex piece of {most} vertices (the limit is "
              f"{MAX_PIECE_VERTICES}): the decomposition was redone with hull decimation")
    if dropped:
        _warn(f"{dropped} flat convex pieces from CoACD were dropped")
    if not pv:
        # Nothing usable: fall back to one piece, the hull of the coarse mesh.
        hv, hf = convex_hull_mesh(V.astype(np.float32).astype(np.float64))
        pv, pf = [hv], [hf]
        _warn("CoACD returned no usable piece: the convex hull of the coarse mesh is the "
              "only piece")

    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    tol = float(settings.map_tolerance) * diag
    mapping = map_triangles(V, F, pv, pf, tol)
    return Pieces(vertices=pv, faces=pf, coarse_faces=mapping, map_tolerance=tol,
                  coacd_pieces=len(parts), warnings=warnings)


def _hulls(parts):
    """qhull re-hull of each CoACD part, rounded to float32 as stored; flat ones dropped."""
    pv, pf = [], []
    dropped = 0
    for verts, _faces in parts:
        pts = np.asarray(verts, dtype=np.float32).astype(np.float64)
        try:
            hv, hf = convex_hull_mesh(pts)
        except BakeFailedError:
            dropped += 1
            continue
        if len(hv) < 4 or len(hf) < 4:
            dropped += 1
            continue
        pv.append(hv)
        pf.append(hf)
    return pv, pf, dropped


def hull_planes(vertices: np.ndarray, faces: np.ndarray):
    """Unit outward normals and offsets (n . x <= d inside) of a closed convex mesh."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    d = np.einsum("ij,ij->i", n, tri[:, 0])
    # a vertex may stick out of a nearly coplanar face by round-off: take the max
    d = np.maximum(d, (vertices @ n.T).max(axis=0))
    return n, d


def map_triangles(V: np.ndarray, F: np.ndarray, piece_vertices: list[np.ndarray],
                  piece_faces: list[np.ndarray], tol: float) -> list[np.ndarray]:
    """For each piece, the sorted ids of coarse triangles within ``tol`` of its hull."""
    tri = V[F]                                                   # (M, 3, 3)
    tmin, tmax = tri.min(axis=1), tri.max(axis=1)
    out = []
    for hv, hf in zip(piece_vertices, piece_faces):
        n, d = hull_planes(hv, hf)
        lo, hi = hv.min(axis=0) - tol, hv.max(axis=0) + tol
        cand = np.nonzero(((tmax >= lo) & (tmin <= hi)).all(axis=1))[0]
        if len(cand) == 0:
            out.append(np.zeros(0, dtype=np.int64))
            continue
        s = tri[cand] @ n.T - d - tol                            # (c, 3, k): > 0 outside plane
        separated = (s > 0).all(axis=1).any(axis=1)              # one plane has all 3 outside
        vertex_in = (s.max(axis=2) <= 0).any(axis=1)             # a corner inside the grown hull
        keep = vertex_in & ~separated
        unsure = np.nonzero(~vertex_in & ~separated)[0]
        for u in unsure:
            keep[u] = _clip_nonempty(tri[cand[u]], n, d + tol)
        out.append(np.sort(cand[keep]))
    return out


def _clip_nonempty(polygon: np.ndarray, n: np.ndarray, d: np.ndarray) -> bool:
    """Whether the convex polygon meets {x : n x <= d} (Sutherland-Hodgman clipping)."""
    poly = polygon
    for k in range(len(n)):
        s = poly @ n[k] - d[k]
        inside = s <= 0
        if inside.all():
            continue
        if not inside.any():
            return False
        nxt = np.roll(np.arange(len(poly)), -1)
        pts = []
        for i in range(len(poly)):
            j = nxt[i]
            if inside[i]:
                pts.append(poly[i])
            if inside[i] != inside[j]:
                t = s[i] / (s[i] - s[j])
                pts.append(poly[i] + t * (poly[j] - poly[i]))
        poly = np.asarray(pts)
        if len(poly) == 0:
            return False
    return True
