"""Stage 6: mass properties for a unit density (volume, centre of mass, inertia).

The runtime rotates objects about ``mass.center_of_mass`` (the force model of Sec. 4,
Eq. 5-7, applies torques about it) and uses the inertia for probe dynamics.

Which surface is integrated (``basis``, docs/bundle-format.md):

* ``full``: the full-resolution mesh when it is closed (every edge shared by two
  consistently oriented faces);
* ``coarse``: otherwise the coarse mesh when it is closed;
* ``hull``: otherwise the convex hull of the full mesh's vertices (always closed; an
  over-estimate of the volume, stated in the manifest and warned about).

The integrals are the exact polyhedral ones (divergence theorem; Eberly, "Polyhedral
Mass Properties (Revisited)", 2002), evaluated for all triangles at once, about the
bounding-box centre for precision.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hbake.errors import BakeFailedError


@dataclass
class MassProperties:
    basis: str                 # "full" | "coarse" | "hull"
    density: float
    volume: float              # m^3
    mass: float                # kg (= density * volume)
    center_of_mass: np.ndarray  # (3,) m, object frame
    inertia: np.ndarray        # (3, 3) kg m^2 about the centre of mass
    closed: bool               # whether the full-resolution mesh is closed (False: a fallback basis)

    def to_manifest(self) -> dict:
        return {"basis": self.basis, "density": self.density, "volume": self.volume,
                "center_of_mass": [float(x) for x in self.center_of_mass],
                "inertia": [[float(x) for x in row] for row in self.inertia],
                "closed": self.closed}


def polyhedron_mass_properties(vertices: np.ndarray, faces: np.ndarray, density: float = 1.0):
    """(volume, centre of mass (3,), inertia about the centre of mass (3, 3)) of the solid
    bounded by a closed, outward-oriented triangle mesh."""
    v = np.asarray(vertices, dtype=np.float64)
    origin = 0.5 * (v.min(axis=0) + v.max(axis=0))
    tri = v[np.asarray(faces, dtype=np.int64)] - origin        # (F, 3, 3)
    p0, p1, p2 = tri[:, 0], tri[:, 1], tri[:, 2]
    d = np.cross(p1 - p0, p2 - p0)                              # (F, 3) = 2 * area * normal

    w0, w1, w2 = p0, p1, p2                                     # per axis, columns x y z
    temp0 = w0 + w1
    f1 = temp0 + w2
    temp1 = w0 * w0
    temp2 = temp1 + w1 * temp0
    f2 = temp2 + w2 * f1
    f3 = w0 * temp1 + w1 * temp2 + w2 * f2
    g0 = f2 + w0 * (f1 + w0)
    g1 = f2 + w1 * (f1 + w1)
    g2 = f2 + w2 * (f1 + w2)

    x, y, z = 0, 1, 2
    intg = np.array([
        (d[:, x] * f1[:, x]).sum() / 6.0,                        # volume
        (d[:, x] * f2[:, x]).sum() / 24.0,                       # int x
        (d[:, y] * f2[:, y]).sum() / 24.0,                       # int y
        (d[:, z] * f2[:, z]).sum() / 24.0,                       # int z
        (d[:, x] * f3[:, x]).sum() / 60.0,                       # int x^2
        (d[:, y] * f3[:, y]).sum() / 60.0,                       # int y^2
        (d[:, z] * f3[:, z]).sum() / 60.0,                       # int z^2
        (d[:, x] * (p0[:, y] * g0[:, x] + p1[:, y] * g1[:, x] + p2[:, y] * g2[:, x])).sum() / 120.0,  # int xy
        (d[:, y] * (p0[:, z] * g0[:, y] + p1[:, z] * g1[:, y] + p2[:, z] * g2[:, y])).sum() / 120.0,  # int yz
        (d[:, z] * (p0[:, x] * g0[:, z] + p1[:, x] * g1[:, z] + p2[:, x] * g2[:, z])).sum() / 120.0,  # int zx
    ])
    volume = intg[0]
    if not volume > 0:
        raise BakeFailedError("mass properties: the closed surface encloses no volume "
                              "(inside-out or flat)")
    com = intg[1:4] / volume
    cx, cy, cz = com
    ixx = intg[5] + intg[6] - volume * (cy * cy + cz * cz)
    iyy = intg[4] + intg[6] - volume * (cz * cz + cx * cx)
    izz = intg[4] + intg[5] - volume * (cx * cx + cy * cy)
    ixy = -(intg[7] - volume * cx * cy)
    iyz = -(intg[8] - volume * cy * cz)
    ixz = -(intg[9] - volume * cz * cx)
    inertia = density * np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return float(volume), com + origin, inertia


def convex_hull_mesh(points: np.ndarray):
    """(vertices, faces) of the convex hull, faces wound outward (qhull's facet normals)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
    except QhullError as exc:
        raise BakeFailedError(f"convex hull failed (flat or degenerate input): "
                              f"{str(exc).splitlines()[0]}") from None
    used = hull.vertices
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    faces = remap[hull.simplices]
    verts = points[used]
    tri = verts[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", n, hull.equations[:, :3]) < 0
    faces[flip] = faces[flip][:, ::-1]
    return verts, faces


def mass_properties(full_vertices, full_faces, full_closed: bool,
                    coarse_vertices, coarse_faces, coarse_closed: bool,
                    density: float = 1.0) -> MassProperties:
    """Mass properties on the documented basis (full, else coarse, else hull)."""
    if full_closed:
        basis, v, f = "full", full_vertices, full_faces
    elif coarse_closed:
        basis, v, f = "coarse", coarse_vertices, coarse_faces
    else:
        basis = "hull"
        v, f = convex_hull_mesh(np.asarray(full_vertices, dtype=np.float64))
    volume, com, inertia = polyhedron_mass_properties(v, f, density)
    return MassProperties(basis=basis, density=float(density), volume=volume,
                          mass=density * volume, center_of_mass=com, inertia=inertia,
                          closed=bool(full_closed))
