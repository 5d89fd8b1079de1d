"""A bundle built by hand in memory (a cube), for the tests of the writer, the validator
and the runtime's loader."""
from __future__ import annotations

import numpy as np

from hbake.bundle import BundleData


def _fill_atlas(v, f, uv, w, h, gutter):
    """Atlas of a flat-faced mesh, computed independently of hbake: each texel whose
    centre is inside a UV triangle gets the barycentric interpolation of the
    triangle's 3D corners; gutters copy the nearest covered texel (Chebyshev <= gutter)."""
    from scipy.ndimage import distance_transform_edt

    atlas = np.zeros((h, w, 4), np.float32)
    jj, ii = np.mgrid[0:h, 0:w]
    uc = ((ii + 0.5) / w).ravel()
    vc = (1 - (jj + 0.5) / h).ravel()
    flat = atlas.reshape(-1, 4)
    for t in range(len(f)):
        a, b, c = uv[t].astype(np.float64)
        m = np.array([[b[0] - a[0], c[0] - a[0]], [b[1] - a[1], c[1] - a[1]]])
        l1, l2 = np.linalg.solve(m, np.stack([uc - a[0], vc - a[1]]))
        l0 = 1 - l1 - l2
        inside = np.flatnonzero((l0 >= 0) & (l1 >= 0) & (l2 >= 0))
        p = l0[:, None] * v[f[t, 0]] + l1[:, None] * v[f[t, 1]] + l2[:, None] * v[f[t, 2]]
        flat[inside, :3] = p[inside]
        flat[inside, 3] = 1
    cov = atlas[:, :, 3] == 1
    _, (nj, ni) = distance_transform_edt(~cov, return_indices=True)
    cheb = np.maximum(abs(nj - jj), abs(ni - ii))
    fill = ~cov & (cheb <= gutter)
    atlas[fill, :3] = atlas[nj[fill], ni[fill], :3]
    return atlas


def _manifest_fields(n_v, n_f, w, h, pieces, coverage, bbox_min, bbox_max):
    stats = {"samples": 100, "mean": 0.0, "p95": 0.0, "max": 0.0, "mean_rel": 0.0, "p95_rel": 0.0,
             "max_rel": 0.0}
    diag = float(np.linalg.norm(np.subtract(bbox_max, bbox_min)))
    return {
        "generator": {"name": "hbake", "version": "0.1.0"},
        "units": {"length": "m", "source_unit": "m", "scale_to_meters": 1.0},
        "source": {"name": "cube.stl", "sha256": "0" * 64, "vertices": n_v, "triangles": n_f,
                   "bodies": 1, "closed": True},
        "method": "cage",
        "settings": {"target_faces": n_f},
        "seeds": {"coacd": 0, "quality": 0},
        "libraries": {"numpy": np.__version__},
        "coarse": {"vertices": n_v, "triangles": n_f, "bbox_min": list(bbox_min),
                   "bbox_max": list(bbox_max), "area": 0.06},
        "pieces": {"count": pieces, "map_tolerance": 1e-4},
        "atlas": {"width": w, "height": h, "gutter": 4, "texel_size": 0.1 / (w / 3),
                  "coverage": coverage},
        "mass": {"basis": "full", "density": 1.0, "volume": 1e-3, "center_of_mass": [0.05] * 3,
                 "inertia": [[1e-6, 0, 0], [0, 1e-6, 0], [0, 0, 1e-6]], "closed": True},
        "quality": {"displacement_outward": 0.0, "displacement_inward": 0.0, "hull_deviation": 0.0,
                    "hull_volume_excess": 0.0, "min_wavelength": 2 * 0.1 / (w / 3),
                    "bbox_diagonal": diag,
                    "reconstruction": {"coarse_to_full": stats, "full_to_coarse": dict(stats)}},
        "warnings": [],
    }


def cube_data(w: int = 48, h: int = 32, size: float = 0.1) -> BundleData:
    """A cube of side ``size``: 12 triangles, each face's two triangles in one chart
    of a 3 x 2 grid of charts with 2-texel margins; two convex pieces (the two
    halves x < size/2 and x > size/2) that both map to every triangle they touch."""
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) * size
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces, uvs = [], []
    for k, (a, b, c, d) in enumerate(quads):
        col, row = k % 3, k // 3
        u0, u1 = (col * w / 3 + 2) / w, ((col + 1) * w / 3 - 2) / w
        v0, v1 = (row * h / 2 + 2) / h, ((row + 1) * h / 2 - 2) / h
        q = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]])
        faces += [(a, b, c), (a, c, d)]
        uvs += [q[[0, 1, 2]], q[[0, 2, 3]]]
    f = np.array(faces, np.int64)
    uv = np.array(uvs, np.float32)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flip = np.einsum("ij,ij->i", n, v[f[:, 0]] - v.mean(0)) < 0
    f[flip] = f[flip][:, ::-1]
    uv[flip] = uv[flip][:, ::-1]
    atlas = _fill_atlas(v, f, uv, w, h, gutter=4)

    import trimesh
    pv, pf, pmap = [], [], []
    for lo, hi in ((0.0, 0.5), (0.5, 1.0)):
        box = trimesh.creation.box(bounds=[[lo * size, 0, 0], [hi * size, size, size]])
        pv.append(np.asarray(box.vertices, float))
        pf.append(np.asarray(box.faces, np.uint32))
        touching = [t for t in range(len(f)) if (v[f[t], 0].min() <= hi * size + 1e-12)
                    and (v[f[t], 0].max() >= lo * size - 1e-12)]
        pmap.append(np.array(touching, np.uint32))
    manifest = _manifest_fields(8, 12, w, h, 2, float((atlas[:, :, 3] == 1).mean()),
                                v.min(0).tolist(), v.max(0).tolist())
    return BundleData(v, f.astype(np.uint32), uv, atlas, pv, pf, pmap, manifest)
