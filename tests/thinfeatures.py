"""Thin features against rays on the full meshes, per grid texel's footprint.

The real chain as in tests/fullsurface.py (``hbake bake``, then ``hrt query --json``),
on the shapes whose thin parts the depth query must not lose:

* ``pins``: a procedural block with pins (0.5 mm across, 2.5 mm tall) and fins
  (0.3 mm thick) standing at angles that are not multiples of 45 degrees, joined
  into one closed mesh with manifold3d;
* the armadillo of ../shared/models (ears, fingers, toes), decimated and scaled as
  fullsurface.make_shared does.

Each is pressed tip first (a thin part's outward normal turned to -z, then tilted and
spun by seeded random angles) onto the plain box and the textured plate.

The truth of a patch is Eq. 2 on the full meshes taken over each grid texel's
footprint: rays along n through SUB x SUB points per texel (finer than the grid),
A's highest crossing and B's lowest on each; per texel the highest of A's and the
lowest of B's; delta_truth = the largest difference over the texels both cover. A
height field that keeps each texel's highest point over its square (the mesh mode)
is exact against it up to the bound below; one that samples texel centres is not.

The bound per patch, fixed before comparing (from the geometry only): each side's
atlas texel t_X times its largest slope s_X over the window (the two triangles of an
atlas quad against the true surface between its corners: at most t_X s_X), plus
the subsampling's own miss (a feature between two rays of the truth: the ray spacing
cell / SUB times the slope), plus ABS_TOL for float rounding.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

import fullsurface as FS

MM = 1e-3
#: Rays per grid texel side for the footprint truth.
SUB = 5
#: Slope ceiling used in the bound (a crossing steeper than this is a wall seen edge-on:
#: its height span over one atlas texel is what the texel and the slope give, capped).
MAX_SLOPE = 10.0
ABS_TOL = 1e-7

PIN_R = 0.25 * MM
PIN_H = 2.5 * MM
FIN_T = 0.3 * MM
FIN_H = 2.0 * MM
FIN_L = 5.0 * MM
BASE = (20 * MM, 20 * MM, 3 * MM)
#: (x, y, tilt from +z in degrees, azimuth of the tilt in degrees)
PINS = ((-6, -6, 0, 0), (-2, -6, 23, 10), (2, -6, 37, 130), (6, -6, 61, 250), (-6, 6, 17, 300))
#: (x, y, yaw in degrees, tilt about the fin's long axis in degrees)
FINS = ((0, 1, 23, 0), (5, 4, 67, 31), (-3, 6, 113, 12))


def bake_models(tmp_path_factory) -> dict:
    """The box, the textured plate, the pins block and the armadillo, baked once per test
    session (or once per FULLSURFACE_CACHE folder). Without ../shared/models' armadillo:
    fails under CI, else skips."""
    import pytest

    if not (FS.SHARED_MODELS / "armadillo.obj").is_file():
        msg = f"../shared/models has no armadillo.obj ({FS.SHARED_MODELS})"
        if FS.CI:
            pytest.fail(msg)
        pytest.skip(msg)
    root = Path(os.environ.get("FULLSURFACE_CACHE") or tmp_path_factory.getbasetemp() / "fullsurface")
    return {n: FS.bake_model(n, root) for n in ("box", "plate", "pins", "armadillo")}


def make_pins() -> trimesh.Trimesh:
    """The block with pins and fins, one closed manifold (manifold3d union)."""
    import manifold3d as m3

    base = m3.Manifold.cube(list(BASE), True)
    parts = [base]
    top = BASE[2] / 2
    for x, y, tilt, az in PINS:
        pin = m3.Manifold.cylinder(PIN_H + 0.5 * MM, PIN_R, PIN_R, 24)  # along +z from 0
        pin = pin.translate([0, 0, -0.5 * MM]).rotate([0, tilt, 0]).rotate([0, 0, az])
        parts.append(pin.translate([x * MM, y * MM, top]))
    for x, y, yaw, tilt in FINS:
        fin = m3.Manifold.cube([FIN_L, FIN_T, FIN_H + 0.5 * MM], False).translate([-FIN_L / 2, -FIN_T / 2, -0.5 * MM])
        fin = fin.rotate([tilt, 0, 0]).rotate([0, 0, yaw])
        parts.append(fin.translate([x * MM, y * MM, top]))
    solid = m3.Manifold.batch_boolean(parts, m3.OpType.Add)
    mesh = solid.to_mesh()
    out = trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3].astype(float), np.asarray(mesh.tri_verts),
                          process=True)
    # Refined so that the bake's coarse mesh (a decimation of this) keeps a texel-fine
    # full surface to compare with: edges of at most ~0.25 mm.
    v, f = trimesh.remesh.subdivide_to_size(out.vertices, out.faces, max_edge=0.25 * MM, max_iter=12)
    out = trimesh.Trimesh(v, f, process=True)
    assert out.is_watertight and out.is_volume, "pins: not a closed volume"
    return out


FS.MESHES.setdefault("pins", make_pins)
FS.MESHES.setdefault("armadillo", lambda: FS.make_shared("armadillo.obj"))

#: The directions (object frame) of the pins' and fins' tips.
def pins_tips() -> list[np.ndarray]:
    out = []
    for _, _, tilt, az in PINS:
        d = Rotation.from_euler("zy", [az, tilt], degrees=True).apply([0, 0, 1.0])
        out.append(d)
    for _, _, yaw, tilt in FINS:
        out.append(Rotation.from_euler("zx", [yaw, tilt], degrees=True).apply([0, 0, 1.0]))
    return out


@dataclass
class Case:
    name: str
    a: str
    b: str
    pose_a: list
    pose_b: list


def tip_first_cases(models: dict, name: str, count: int, seed: int, max_tilt_deg: float = 25.0) -> list[Case]:
    """``count`` seeded poses of model ``name``, a thin part's tip pressed into the box
    and the textured plate (alternately) by 0.05-0.3 mm."""
    m = models[name]
    rng = np.random.default_rng(seed)
    tips = pins_tips() if name == "pins" else FS.thin_tips(m.mesh, max(count, 8), rng)
    out = []
    for k in range(count):
        tip = tips[k % len(tips)]
        r0, _ = Rotation.align_vectors([[0, 0, -1.0]], [tip])
        tilt_axis = rng.normal(size=3)
        tilt_axis[2] = 0
        tilt = Rotation.from_rotvec(tilt_axis / np.linalg.norm(tilt_axis) * math.radians(rng.uniform(3, max_tilt_deg)))
        spin = Rotation.from_euler("z", float(rng.uniform(0, 2 * np.pi)))
        R = (tilt * spin * r0).as_matrix()
        plate = "box" if k % 2 == 0 else "plate"
        centre = (FS.BOX_SIZE[0] / 2, FS.BOX_SIZE[1] / 2) if plate == "box" else (FS.PLATE_SIDE / 2,) * 2
        press = float(rng.uniform(0.05 * MM, 0.3 * MM))
        t = FS._rest_on(m.mesh, R, models[plate], FS.IDENTITY, centre, press)
        out.append(Case(f"{name}_{plate}_{k}", name, plate, [*t.tolist(), *FS._quat_from_matrix(R)], FS.IDENTITY))
    return out


@dataclass
class Footprint:
    delta: float          # truth over the texels' footprints (-inf: none covered by both)
    delta_centre: float   # truth at the texel centres only
    bound: float          # the bound fixed before comparing
    texel: float          # the pair's coarser atlas texel (m), the unit of the report

    @property
    def delta_raw_far(self) -> bool:
        """Wrong-way: the truth along n exceeds 5 mm (n goes through the bodies)."""
        return math.isfinite(self.delta) and self.delta > FS.WRONG_WAY_DEPTH


def footprint_truth(c: dict, a, b, pose_a, pose_b, sub: int = SUB) -> Footprint:
    SUB = sub  # rays per texel side (odd: the middle one is the texel centre)
    n, u, v = (np.asarray(c[k], float) for k in ("n", "u", "v"))
    w = c["window"]
    origin, cell, N = np.asarray(w["origin"], float), float(w["cell"]), int(w["resolution"])
    off = (np.arange(SUB) + 0.5) / SUB
    i = (np.arange(N)[:, None] + off[None, :]).ravel() * cell  # N * SUB positions along one axis
    gu, gv = np.meshgrid(i, i, indexing="xy")
    X = origin + gu.ravel()[:, None] * u + gv.ravel()[:, None] * v
    ca = FS.surface_columns(a, pose_a, X, n, u, v, True)
    cb = FS.surface_columns(b, pose_b, X, n, u, v, False)
    M = N * SUB

    def per_texel(h, fn):
        h = h.reshape(M, M).reshape(N, SUB, N, SUB).transpose(0, 2, 1, 3).reshape(N, N, SUB * SUB)
        with np.errstate(all="ignore"):
            import warnings
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                return fn(h, axis=2)

    ha, hb = per_texel(ca.h, np.nanmax), per_texel(cb.h, np.nanmin)
    d = ha - hb
    delta = float(np.nanmax(d)) if np.isfinite(d).any() else -math.inf
    # Texel centres: the middle subsample when SUB is odd.
    mid = SUB // 2
    hac = ca.h.reshape(M, M)[mid::SUB, mid::SUB]
    hbc = cb.h.reshape(M, M)[mid::SUB, mid::SUB]
    dc = hac - hbc
    delta_c = float(np.nanmax(dc)) if np.isfinite(dc).any() else -math.inf
    # Slopes over the columns that matter: those within FS.NEAR (0.5 mm) of the deepest
    # overlap (the geometry there, not the error), capped at MAX_SLOPE.
    with np.errstate(invalid="ignore"):
        near = np.isfinite(ca.h) & np.isfinite(cb.h) & (ca.h - cb.h >= delta - FS.NEAR)

    def slope(col):
        g = np.linalg.norm(col.grad[near], axis=1) if near.any() else np.zeros(1)
        g = np.where(np.isfinite(g), g, MAX_SLOPE)
        return min(float(np.max(g, initial=0.0)), MAX_SLOPE)

    sa, sb = slope(ca), slope(cb)
    # An atlas quad's two triangles against the surface between its corners: at most
    # the quad's diagonal (sqrt 2 texels) times the slope; the truth's rays miss up to
    # a ray spacing times the slope; float rounding.
    bound = math.sqrt(2) * (a.texel * sa + b.texel * sb) + (cell / SUB) * (sa + sb) + ABS_TOL
    # The unit of the report: the pair's coarser atlas texel (delta's error is the sum
    # of both reconstructions', each of its own texel's order).
    return Footprint(delta, delta_c, bound, max(a.texel, b.texel))
