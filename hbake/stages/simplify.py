"""Stage 2: simplify the full-resolution mesh into the coarse mesh (Sec. 3.3, Table 1).

pymeshlab's quadric edge collapse (Garland-Heckbert, with topology preservation and
normal-flip and triangle-quality checks) gives the most faithful coarse mesh at a few
hundred triangles and keeps a closed mesh closed. It
costs about 25 us per input face, so inputs above ``pre_decimate_above`` faces are first
reduced to ``pre_decimate_faces`` with fast-simplification (same quadric metric, no topology
checks, ~1.5 us per face); the pre-decimated mesh is used only if it is as closed as
the input. Both are deterministic (no random choices, single-threaded).

Vertex placement: the quadric-optimal position (best on curved, organic surfaces) or
the better endpoint of the collapsed edge (keeps the corners of blocks whose faces
carry relief: on the ridged block at 16 triangles, optimal placement loses 29 % of the
volume, endpoint placement 0.3 %). With ``placement = "auto"`` both are computed and the
coarse mesh with the smaller two-sided mean distance to the (pre-decimated) input on
``SCORE_SAMPLES`` seeded samples per side is kept.

Both collapses have absolute thresholds, so a part smaller than SIMPLIFY_MIN_DIAGONAL is
collapsed scaled up by a power of two (``collapse_scale``) and scaled back, exactly.

The result is cleaned (degenerate, duplicate faces and unused vertices dropped),
rounded to float32 (the precision the bundle stores, so every later stage sees the
stored coarse mesh) and, when closed, oriented outward.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hbake import constants as C
from hbake.errors import BakeFailedError
from hbake.stages.geometry import face_components, is_closed, signed_volumes
from hbake.stages.load import degenerate_faces, repair_mesh
from hbake.settings import SimplifySettings


@dataclass
class CoarseMesh:
    vertices: np.ndarray     # (N, 3) float64 holding float32 values, meters
    faces: np.ndarray        # (M, 3) int64, CCW outward when closed
    closed: bool
    pre_decimated_faces: int  # face count after fast-simplification (0 if not used)
    placement: str = "none"   # "optimal" | "endpoint" | "none" (input kept)
    scores: dict = field(default_factory=dict)   # placement -> two-sided mean distance (m)
    warnings: list[str] = field(default_factory=list)


def simplify(vertices: np.ndarray, faces: np.ndarray, settings: SimplifySettings | None = None,
             *, input_closed: bool | None = None, warn=None) -> CoarseMesh:
    """Simplify to about ``settings.target_faces`` triangles."""
    settings = settings or SimplifySettings()
    warnings: list[str] = []

    def _warn(msg):
        warnings.append(msg)
        if warn is not None:
            warn(msg)

    if input_closed is None:
        input_closed = is_closed(faces)
    target = settings.target_faces
    pre = 0
    v, f = vertices, faces
    placement, scores = "none", {}
    scale = collapse_scale(vertices, faces)
    if len(faces) <= target:
        _warn(f"the input has {len(faces)} triangles, not more than the target {target}: "
              f"the coarse mesh is the input itself")
    else:
        if (settings.pre_decimate_above and len(faces) > settings.pre_decimate_above
                and settings.pre_decimate_faces > target):
            pv, pf = _fast_simplify(vertices, faces, settings.pre_decimate_faces, scale)
            if not input_closed or is_closed(pf):
                v, f, pre = pv, pf, len(pf)
        options = ("optimal", "endpoint") if settings.placement == "auto" else (settings.placement,)
        results = {p: _quadric_collapse(v, f, settings, optimal=(p == "optimal"), scale=scale)
                   for p in options}
        if len(results) > 1:
            scores = {p: _two_sided_mean(v, f, *r) for p, r in results.items()}
            placement = min(options, key=lambda p: (scores[p], options.index(p)))
        else:
            placement = options[0]
        v, f = results[placement]

    # float32 is what the bundle stores; clean what rounding or collapsing left behind
    v = v.astype(np.float32).astype(np.float64)
    v, f, _ = repair_mesh(v, f, cancel_fins=True)
    if len(f) == 0:
        raise BakeFailedError("simplification left no triangles; raise --target-faces")
    closed = is_closed(f)
    if input_closed and not closed:
        _warn("the coarse mesh is not closed although the input is; inside/outside tests "
              "and the mass fallback use the full mesh")
    if closed:
        n, labels = face_components(f, len(v))
        vol = np.bincount(labels, weights=signed_volumes(v, f), minlength=n)
        flip = (vol < 0)[labels]
        if flip.any():
            f = f.copy()
            f[flip] = f[flip][:, ::-1]
    if len(f) > 2 * target:
        _warn(f"simplification stopped at {len(f)} triangles (target {target}): the "
              f"topology or quality constraints prevent further collapses")
    return CoarseMesh(vertices=v, faces=f, closed=closed, pre_decimated_faces=pre,
                      placement=placement, scores=scores, warnings=warnings)


def _two_sided_mean(v_ref, f_ref, v, f) -> float:
    """Mean distance ref surface -> mesh plus mesh surface -> ref, on seeded samples."""
    from hbake.stages.geometry import closest_points, sample_surface

    rng = np.random.default_rng(C.SCORE_SEED)
    a, _, _ = sample_surface(v_ref, f_ref, C.SCORE_SAMPLES, rng)
    b, _, _ = sample_surface(v, f, C.SCORE_SAMPLES, rng)
    return float(closest_points(v, f, a)[1].mean() + closest_points(v_ref, f_ref, b)[1].mean())


def collapse_scale(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The power of two (>= 1) by which the collapses see the mesh: the least that brings
    the bounding-box diagonal of the used vertices to SIMPLIFY_MIN_DIAGONAL, 1 above it
    (constants.SIMPLIFY_MIN_DIAGONAL says why)."""
    if len(faces) == 0:
        return 1.0
    v = np.asarray(vertices, dtype=np.float64)[np.unique(faces)]
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    k = 0
    while 0 < diag and math.ldexp(diag, k) < C.SIMPLIFY_MIN_DIAGONAL:
        k += 1
    return math.ldexp(1.0, k)


def _fast_simplify(vertices, faces, target, scale: float = 1.0):
    import fast_simplification

    # times and divided by a power of two: exact (float32 keeps its values)
    v, f = fast_simplification.simplify((vertices * scale).astype(np.float32),
                                        faces.astype(np.int32), target_count=int(target),
                                        agg=C.PRE_DECIMATE_AGGRESSIVENESS)
    v = np.asarray(v, dtype=np.float64) / scale
    f = np.asarray(f, dtype=np.int64)
    v, f, _ = repair_mesh(v, f, cancel_fins=True) if len(f) else (v, f, None)
    return v, f


def _quadric_collapse(vertices, faces, settings: SimplifySettings, optimal: bool = True,
                      scale: float = 1.0):
    """pymeshlab's collapse of the mesh scaled by ``scale`` (a power of two), scaled back."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(
                                   np.asarray(vertices, dtype=np.float64) * scale),
                               face_matrix=np.ascontiguousarray(faces, dtype=np.int32)))
    try:
        ms.meshing_decimation_quadric_edge_collapse(
            targetfacenum=int(settings.target_faces),
            qualitythr=float(settings.quality_threshold),
            preserveboundary=bool(settings.preserve_boundary),
            preservenormal=True,          # never flip a face (keeps the winding outward)
            preservetopology=bool(settings.preserve_topology),
            optimalplacement=bool(optimal),
            planarquadric=False,
            autoclean=True)
    except pymeshlab.PyMeshLabException as exc:
        raise BakeFailedError(f"simplification failed: {exc}") from None
    m = ms.current_mesh()
    return (np.asarray(m.vertex_matrix(), dtype=np.float64) / scale,
            np.asarray(m.face_matrix(), dtype=np.int64))


def cap_holes(vertices: np.ndarray, faces: np.ndarray):
    """The coarse mesh with every hole capped (MeshLab's hole filling; the original faces
    come first, unchanged), or None when the result is not closed. Used for the convex
    decomposition and the mass properties of open inputs, never stored in the bundle."""
    import pymeshlab

    from hbake.stages.geometry import boundary_edge_count

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(vertices, dtype=np.float64),
                               face_matrix=np.ascontiguousarray(faces, dtype=np.int32)))
    try:
        ms.meshing_close_holes(maxholesize=boundary_edge_count(faces) + 1, selfintersection=False)
    except pymeshlab.PyMeshLabException:
        return None
    m = ms.current_mesh()
    v = np.asarray(m.vertex_matrix(), dtype=np.float64)
    f = np.asarray(m.face_matrix(), dtype=np.int64)
    if (len(v) != len(vertices) or not np.array_equal(v, vertices)
            or not np.array_equal(f[:len(faces)], faces) or not is_closed(f)):
        return None
    # orient outward like the rest (the caps follow the surface's winding)
    if signed_volumes(v, f).sum() < 0:
        f = f[:, ::-1].copy()
    return v, f


def coarse_is_valid(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """The bundle's invariants on the coarse mesh (docs/bundle-format.md)."""
    return (len(vertices) >= 3 and len(faces) >= 1 and np.isfinite(vertices).all()
            and not degenerate_faces(vertices, faces).any())
