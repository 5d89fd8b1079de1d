"""Stage 7: quality measures recorded in the manifest (docs/bundle-format.md).

* Reconstruction error, both ways, on ``samples`` area-uniform random points each
  (seeded, so the numbers are reproducible):

  - ``coarse_to_full``: points of the coarse surface mapped through the atlas (the
    bilinear lookup of the spec, ``hbake.bundle.atlas_lookup``, i.e. what the runtime
    computes, Eq. 8) against the full-resolution surface;
  - ``coarse_to_full_uncut`` (format 1.1): the same samples without those whose lookup
    quad has an edge longer than DISCONTINUITY_TEXELS texel sizes (a discontinuity, which
    the runtime does not interpolate across; ``cut_samples`` counts them);
  - ``full_to_coarse``: points of the full surface against the reconstructed surface,
    the image of the coarse surface under the atlas. That surface is triangulated from
    the texel grid: every 2x2 block of baked texels of one chart gives two triangles
    through the four stored positions (the bilinear patch to second order).

  Distances are exact closest-point distances (``hbake.stages.geometry.closest_points``).
  Each is reported as mean, p95 and max in meters and relative to the full mesh's
  bounding-box diagonal.
* ``displacement_outward``/``inward``: from the bake: the largest signed distance
  (outside positive, by the coarse face normals) of a baked texel that a lookup can
  read to the coarse surface.
* ``hull_deviation``: the largest distance of a piece vertex outside the coarse surface
  (outside = generalized winding number < 1/2; an open coarse mesh is taken with its
  holes capped, and where capping fails every vertex counts, so it is the largest
  unsigned distance).
* ``hull_volume_excess``: (volume of the union of the pieces - volume of the coarse
  mesh) / volume of the coarse mesh (capped where open), with manifold3d's exact
  boolean union; where no closed coarse mesh exists the mass basis volume stands in.
* ``min_wavelength``: ``2 * texel_size``, the shortest relief wavelength the atlas can
  represent (Sec. 7.2, Nyquist). A warning says when the relief is finer: the full
  surface strays from the reconstructed one by more than half a texel (p95) while the
  full mesh has edges shorter than the minimum wavelength.
"""
from __future__ import annotations

import numpy as np

from hbake import constants as C
from hbake.stages.geometry import closest_points, sample_surface, winding_numbers
from hbake.stages.parameterize import chart_labels


def error_stats(d: np.ndarray, diag: float) -> dict:
    mean, p95, mx = float(d.mean()), float(np.percentile(d, 95)), float(d.max())
    return {"samples": int(len(d)), "mean": mean, "p95": p95, "max": mx,
            "mean_rel": mean / diag, "p95_rel": p95 / diag, "max_rel": mx / diag}


def coarse_to_full(coarse_vertices, coarse_faces, uvs, image, full_vertices, full_faces,
                   samples: int, rng: np.random.Generator, texel_size: float | None = None):
    """Distances of atlas-mapped coarse-surface samples to the full surface; with
    ``texel_size``, also the mask of the samples whose lookup quad has a cut edge
    (``lookup_cut``)."""
    from hbake.bundle import atlas_lookup

    _, face, bary = sample_surface(coarse_vertices, coarse_faces, samples, rng)
    uv = np.einsum("nk,nkd->nd", bary, np.asarray(uvs, dtype=np.float64)[face])
    mapped = atlas_lookup(image, uv)[:, :3]
    d = closest_points(full_vertices, full_faces, mapped)[1]
    if texel_size is None:
        return d
    return d, lookup_cut(image, uv, texel_size)


def lookup_cut(image: np.ndarray, uv: np.ndarray, texel_size: float) -> np.ndarray:
    """True where the 2x2 quad that the bilinear lookup at ``uv`` reads has an edge whose
    two texels are more than DISCONTINUITY_TEXELS texel sizes apart: a discontinuity, which
    the runtime does not interpolate across (docs/bundle-format.md, atlas.discontinuities)."""
    from hbake.bundle import texel_coords

    h, w = image.shape[:2]
    xy = texel_coords(uv, w, h)
    i0 = np.floor(xy[:, 0]).astype(np.int64)
    j0 = np.floor(xy[:, 1]).astype(np.int64)
    i1, j1 = np.clip(i0 + 1, 0, w - 1), np.clip(j0 + 1, 0, h - 1)
    i0, j0 = np.clip(i0, 0, w - 1), np.clip(j0, 0, h - 1)
    p = image[..., :3].astype(np.float64)
    limit = C.DISCONTINUITY_TEXELS * texel_size
    cut = np.zeros(len(uv), dtype=bool)
    for (ja, ia), (jb, ib) in (((j0, i0), (j0, i1)), ((j1, i0), (j1, i1)),
                               ((j0, i0), (j1, i0)), ((j0, i1), (j1, i1))):
        cut |= np.linalg.norm(p[ja, ia] - p[jb, ib], axis=1) > limit
    return cut


def reconstructed_mesh(image: np.ndarray, triangle: np.ndarray, baked: np.ndarray,
                       chart_of_face: np.ndarray):
    """Triangle mesh through the baked texels: two triangles per 2x2 block of baked
    texels of one chart. Returns (vertices (K, 3), faces (L, 3))."""
    H, W = baked.shape
    chart = np.where(baked, chart_of_face[np.maximum(triangle, 0)], -1)
    c00, c10 = chart[:-1, :-1], chart[:-1, 1:]
    c01, c11 = chart[1:, :-1], chart[1:, 1:]
    ok = (c00 >= 0) & (c00 == c10) & (c00 == c01) & (c00 == c11)
    jj, ii = np.nonzero(ok)
    vid = np.full((H, W), -1, dtype=np.int64)
    ys, xs = np.nonzero(baked)
    vid[ys, xs] = np.arange(len(ys))
    v00, v10 = vid[jj, ii], vid[jj, ii + 1]
    v01, v11 = vid[jj + 1, ii], vid[jj + 1, ii + 1]
    faces = np.concatenate([np.stack([v00, v10, v11], axis=1), np.stack([v00, v11, v01], axis=1)])
    vertices = image[ys, xs, :3].astype(np.float64)
    return vertices, faces


def full_to_coarse(full_vertices, full_faces, recon_vertices, recon_faces, samples: int,
                   rng: np.random.Generator) -> np.ndarray:
    pts, _, _ = sample_surface(full_vertices, full_faces, samples, rng)
    return closest_points(recon_vertices, recon_faces, pts)[1]


def hull_deviation(piece_vertices: list[np.ndarray], coarse_vertices, coarse_faces,
                   coarse_closed: bool) -> float:
    pts = np.concatenate(piece_vertices)
    d = closest_points(coarse_vertices, coarse_faces, pts)[1]
    if coarse_closed:
        outside = winding_numbers(pts, coarse_vertices, coarse_faces) < 0.5
        d = d[outside]
    return float(d.max()) if len(d) else 0.0


def union_volume(piece_vertices: list[np.ndarray], piece_faces: list[np.ndarray]) -> float:
    """Volume of the union of the (convex) pieces, by manifold3d's boolean union."""
    import manifold3d as m3d

    solids = [m3d.Manifold(m3d.Mesh(vert_properties=np.ascontiguousarray(v, dtype=np.float32),
                                    tri_verts=np.ascontiguousarray(f, dtype=np.uint32)))
              for v, f in zip(piece_vertices, piece_faces)]
    union = m3d.Manifold.batch_boolean(solids, m3d.OpType.Add) if len(solids) > 1 else solids[0]
    return float(union.volume())


def median_edge_length(vertices, faces) -> float:
    e = vertices[faces[:, [1, 2, 0]]] - vertices[faces]
    return float(np.median(np.linalg.norm(e, axis=2)))


def measure(*, full_vertices, full_faces, coarse_vertices,
            coarse_faces, coarse_closed: bool, uvs, baked, pieces, mass_volume: float,
            coarse_volume: float | None, samples: int, seed: int, progress=None,
            solid=None):
    """``solid``: the closed (capped) coarse mesh where the coarse mesh is open, or None."""
    """All quality measures: (manifest["quality"] dict, extra stats dict, warnings)."""
    warnings: list[str] = []
    diag = float(np.linalg.norm(full_vertices.max(axis=0) - full_vertices.min(axis=0)))
    # Independent, reproducible streams for the two directions.
    rng_c, rng_f = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))

    d_cf, cut_cf = coarse_to_full(coarse_vertices, coarse_faces, uvs, baked.image, full_vertices,
                                  full_faces, samples, rng_c, baked.texel_size)
    if progress:
        progress(1)
    charts = chart_labels(coarse_faces, np.asarray(uvs))
    rv, rf = reconstructed_mesh(baked.image, baked.triangle, baked.baked, charts)
    d_fc = full_to_coarse(full_vertices, full_faces, rv, rf, samples, rng_f)
    if progress:
        progress(2)

    if solid is not None:
        dev = hull_deviation(pieces.vertices, solid[0], solid[1], True)
    else:
        dev = hull_deviation(pieces.vertices, coarse_vertices, coarse_faces, coarse_closed)
    ref_volume = coarse_volume if coarse_volume else mass_volume
    excess = (union_volume(pieces.vertices, pieces.faces) - ref_volume) / ref_volume
    if progress:
        progress(3)

    min_wavelength = C.MIN_WAVELENGTH_TEXELS * baked.texel_size
    fc = error_stats(d_fc, diag)
    cf_stats = error_stats(d_cf, diag)
    edge = median_edge_length(full_vertices, full_faces)
    if fc["p95"] > C.RELIEF_WARN_P95_TEXELS * baked.texel_size and edge < min_wavelength:
        warnings.append(
            f"relief finer than the atlas can represent: the full surface strays from the "
            f"baked one by {fc['p95']:.3g} m (p95), more than half a texel "
            f"({baked.texel_size:.3g} m), and the mesh has detail down to {edge:.3g} m, below "
            f"the shortest representable wavelength {min_wavelength:.3g} m (two texels, "
            f"Sec. 7.2); raise --atlas-size")
    elif max(fc["p95"], cf_stats["p95"]) > C.RELIEF_WARN_P95_TEXELS * baked.texel_size:
        warnings.append(
            f"the baked surface strays from the full surface by more than half a texel "
            f"({baked.texel_size:.3g} m): p95 {cf_stats['p95']:.3g} m coarse->full, "
            f"{fc['p95']:.3g} m full->coarse; the coarse mesh may be too coarse for the "
            f"shape (raise --target-faces) or some surface is not reached by the rays")
    quality = {
        "displacement_outward": baked.displacement_outward,
        "displacement_inward": baked.displacement_inward,
        "hull_deviation": dev,
        "hull_volume_excess": float(excess),
        "min_wavelength": float(min_wavelength),
        "reconstruction": {
            "coarse_to_full": cf_stats, "full_to_coarse": fc,
            # the same samples less those whose lookup quad has a cut edge (what the
            # runtime interpolates); format 1.1
            "coarse_to_full_uncut": {**(error_stats(d_cf[~cut_cf], diag) if (~cut_cf).any()
                                        else {k: 0.0 for k in cf_stats} | {"samples": 0}),
                                     "cut_samples": int(cut_cf.sum())}},
        "bbox_diagonal": diag,
    }
    return quality, warnings
