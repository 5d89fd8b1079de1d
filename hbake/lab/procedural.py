"""Procedural test models: the paper's benchmark shapes, made by code.

Every generator is deterministic (pure numpy, or manifold3d booleans, no random
numbers), returns a closed, edge-manifold :class:`trimesh.Trimesh` in **meters**
whose triangles are wound counter-clockwise seen from outside (positive signed
volume), and documents the wavelength and amplitude of its relief, so a test can
compare a bake against the analytic surface and a reader can compare the relief
with the atlas texel size (Sec. 7.2: relief finer than two texels is lost).

The models mirror Table 1 / Fig. 6 of the paper (Otaduy et al. 2004):

==================  =========  ===========================================
name                triangles  shape
==================  =========  ===========================================
``ridged_block``       65,536  block with parallel ridges on its top
``ridged_gear``        25,600  disc whose rim carries ridges along its axis
``wrinkled_torus``    128,000  torus with helical wrinkles
``grating``            66,560  block whose top is a grating turned 23 deg
``cad_part``         ~650,000  milled bracket with a knurled boss
``rasp``              285,152  file-like bar with cross-cut teeth
==================  =========  ===========================================

``generate(name, path)`` writes one model to a mesh file (any extension that
trimesh exports: ``.ply``, ``.stl``, ``.obj``, ``.off``); ``MODELS`` lists them.
Meshes carry no unit; bake them with ``--units m``.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh

__all__ = [
    "MODELS",
    "ModelInfo",
    "ridged_block",
    "ridged_block_height",
    "ridged_gear",
    "ridged_gear_radius",
    "wrinkled_torus",
    "wrinkled_torus_offset",
    "grating",
    "grating_height",
    "cad_part",
    "cad_texture",
    "rasp",
    "rasp_teeth",
    "generate",
]

MM = 1e-3

# --------------------------------------------------------------------------
# Parameters (one place; the docstrings of the generators refer to these).
# --------------------------------------------------------------------------

# Ridged block: ridges run along x, the height varies with y only.
# 112 x 144 top cells: 4*nx*ny + 4*(nx+ny) = 65,536 triangles exactly, the
# block of Table 1.
BLOCK_NX, BLOCK_NY = 112, 144
BLOCK_SIZE = (50 * MM, 60 * MM, 20 * MM)      # x, y, z (z = mean top height)
BLOCK_WAVELENGTH = 5 * MM                      # 12 ridges across y, 12 cells each
BLOCK_AMPLITUDE = 0.5 * MM                     # half of peak-to-peak (1 mm)

# Ridged gear: 800 angular samples, 9 rim rows, 4 rings per cap:
# 2*800*9 + 2*800*(2*4-1) = 25,600 triangles, the gear of Table 1.
GEAR_N_THETA, GEAR_N_Z, GEAR_N_RINGS = 800, 9, 4
GEAR_RIDGES = 50
GEAR_WAVELENGTH = 5 * MM                       # arc length between ridges at the mean radius
GEAR_RADIUS = GEAR_RIDGES * GEAR_WAVELENGTH / (2 * math.pi)   # 39.79 mm
GEAR_THICKNESS = 20 * MM
GEAR_AMPLITUDE = 0.5 * MM

# Wrinkled torus: 400 x 160 quads = 128,000 triangles, the torus of Table 1.
TORUS_NU, TORUS_NV = 400, 160
TORUS_R, TORUS_r = 50 * MM, 20 * MM
TORUS_WAVES_U, TORUS_WAVES_V = 40, 8           # helical wrinkles: sin(40 u + 8 v)
TORUS_AMPLITUDE = 0.6 * MM

# Grating: 128 x 128 top cells (66,560 triangles).
GRATING_N = 128
GRATING_SIZE = (60 * MM, 60 * MM, 20 * MM)
GRATING_WAVELENGTH = 5 * MM
GRATING_AMPLITUDE = 0.5 * MM

# CAD part: an L-bracket with a bored boss, refined to ~650k triangles.
CAD_WAVELENGTH = 2 * MM                        # face-milling arcs
CAD_AMPLITUDE = 0.08 * MM
CAD_KNURL_WAVELENGTH = 2 * MM                  # knurl pitch on the boss
CAD_KNURL_AMPLITUDE = 0.08 * MM

# Rasp: 800 x 88 cells, teeth on top and bottom: 285,152 triangles (the
# paper's file has 285,824).
RASP_NX, RASP_NY = 800, 88
RASP_SIZE = (160 * MM, 20 * MM, 6 * MM)
RASP_TOOTH_PITCH = 2 * MM
RASP_TOOTH_HEIGHT = 0.4 * MM
RASP_OVERCUT_DEG, RASP_UPCUT_DEG = 65.0, -45.0  # angles of the two cuts to the x axis


@dataclass(frozen=True)
class ModelInfo:
    """One registered model: how to make it and what its relief is."""

    name: str
    make: Callable[[], trimesh.Trimesh]
    triangles: int | None          # exact count, None where only approximate
    wavelength: float              # m, shortest characteristic wavelength of the relief
    amplitude: float               # m, half of the peak-to-peak relief height
    description: str


# --------------------------------------------------------------------------
# Building blocks
# --------------------------------------------------------------------------

def _grid_quads(nu: int, nv: int, offset: int, wrap_u: bool = False, wrap_v: bool = False,
                stride: int | None = None) -> np.ndarray:
    """Triangles of an nu x nv quad grid of vertices laid out ``offset + i*stride + j``.

    Quad (i, j) has corners a=(i, j), b=(i+1, j), c=(i+1, j+1), d=(i, j+1) and is
    split into (a, b, c), (a, c, d): counter-clockwise when i runs along the first
    tangent and j along the second tangent of a right-handed (t1, t2, n) frame.
    """
    ni = nu if wrap_u else nu + 1
    nj = nv if wrap_v else nv + 1
    stride = nj if stride is None else stride
    i = np.arange(nu)[:, None]
    j = np.arange(nv)[None, :]
    i1 = (i + 1) % ni
    j1 = (j + 1) % nj
    a = offset + i * stride + j
    b = offset + i1 * stride + j
    c = offset + i1 * stride + j1
    d = offset + i * stride + j1
    a, b, c, d = (np.broadcast_to(x, (nu, nv)).ravel() for x in (a, b, c, d))
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).reshape(2, -1, 3) \
        .transpose(1, 0, 2).reshape(-1, 3)


def _heightfield_block(xs: np.ndarray, ys: np.ndarray, top: np.ndarray,
                       bottom: np.ndarray) -> trimesh.Trimesh:
    """Closed block over the grid ``xs x ys`` between the height fields ``bottom`` and ``top``.

    ``top``/``bottom`` have shape (len(xs), len(ys)). The side walls are one row of
    quads joining the top and bottom boundary rings, so the triangle count is
    ``4*nx*ny + 4*(nx+ny)`` with ``nx = len(xs)-1``, ``ny = len(ys)-1``.
    """
    nx, ny = len(xs) - 1, len(ys) - 1
    if np.any(top <= bottom):
        raise ValueError("top height field must lie above the bottom one")
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    nv = (nx + 1) * (ny + 1)
    verts = np.concatenate([
        np.stack([X.ravel(), Y.ravel(), top.ravel()], 1),
        np.stack([X.ravel(), Y.ravel(), bottom.ravel()], 1),
    ])
    top_f = _grid_quads(nx, ny, 0)                 # (x, y, +z) is right-handed: outward up
    bot_f = _grid_quads(nx, ny, nv)[:, ::-1]       # reversed: outward down

    def vid(i, j):
        return i * (ny + 1) + j

    # Boundary ring counter-clockwise seen from +z.
    ring = ([vid(i, 0) for i in range(nx)] + [vid(nx, j) for j in range(ny)]
            + [vid(i, ny) for i in range(nx, 0, -1)] + [vid(0, j) for j in range(ny, 0, -1)])
    p = np.array(ring)
    q = np.roll(p, -1)
    bp, bq = p + nv, q + nv
    # Outward wall: for an edge p->q running counter-clockwise, (bp, bq, tq) faces out.
    walls = np.concatenate([np.stack([bp, bq, q], 1), np.stack([bp, q, p], 1)])
    faces = np.concatenate([top_f, bot_f, walls])
    return trimesh.Trimesh(verts, faces, process=False)


def _finish(mesh: trimesh.Trimesh, expected: int | None = None) -> trimesh.Trimesh:
    """Check the invariants every generator promises; a failure is a bug here."""
    if expected is not None and len(mesh.faces) != expected:
        raise AssertionError(f"{len(mesh.faces)} triangles, expected {expected}")
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise AssertionError("generated mesh is not closed and outward")
    return mesh


# --------------------------------------------------------------------------
# Ridged block (Table 1: 65,536 triangles; Fig. 6a/b)
# --------------------------------------------------------------------------

def _block_grid():
    lx, ly, _ = BLOCK_SIZE
    return np.linspace(0.0, lx, BLOCK_NX + 1), np.linspace(0.0, ly, BLOCK_NY + 1)


def ridged_block_height(y, exact: bool = True) -> np.ndarray:
    """Height (m) of the ridged block's top surface at ``y`` (m), for any x.

    Analytic profile: ``z(y) = H + A sin(2 pi y / L)`` with ``H`` = 20 mm,
    ``A`` = 0.5 mm, ``L`` = 5 mm (12 ridges across the 60 mm width, ridges along x).
    With ``exact`` (the default) returns the mesh's own surface: the piecewise-linear
    interpolant of that sine at the 145 grid rows (12 rows per wavelength), which
    differs from the sine by at most ``A (1 - cos(pi/12))`` = 17 um.
    """
    y = np.asarray(y, dtype=float)
    h = BLOCK_SIZE[2]

    def sine(t):
        return h + BLOCK_AMPLITUDE * np.sin(2 * np.pi * t / BLOCK_WAVELENGTH)

    if not exact:
        return sine(y)
    _, ys = _block_grid()
    return np.interp(y, ys, sine(ys))


def ridged_block() -> trimesh.Trimesh:
    """Block 50 x 60 mm, 20 mm tall, with 12 parallel sinusoidal ridges on its top.

    Ridges run along x; the top is ``z = ridged_block_height(y)``: wavelength
    5 mm, amplitude 0.5 mm (1 mm peak to peak), sampled by 12 grid rows per
    wavelength. Bottom at z = 0, corner at the origin. 65,536 triangles (Table 1).
    At coarse resolution it is a box (the paper's 16 triangles, one convex piece).
    """
    xs, ys = _block_grid()
    top = np.broadcast_to(ridged_block_height(ys)[None, :], (len(xs), len(ys)))
    mesh = _heightfield_block(xs, ys, top, np.zeros_like(top))
    return _finish(mesh, 65_536)


# --------------------------------------------------------------------------
# Ridged gear (Table 1: 25,600 triangles)
# --------------------------------------------------------------------------

def ridged_gear_radius(theta) -> np.ndarray:
    """Rim radius (m) of the ridged gear at polar angle ``theta`` (analytic profile)."""
    return GEAR_RADIUS + GEAR_AMPLITUDE * np.sin(GEAR_RIDGES * np.asarray(theta, dtype=float))


def ridged_gear() -> trimesh.Trimesh:
    """Disc of mean radius 39.8 mm and 20 mm thickness with 50 ridges along its axis (z).

    Rim: ``r(theta) = R + A sin(50 theta)``: wavelength 5 mm of arc at the mean
    radius (same as the ridged block, so the two interlock as in Fig. 6b),
    amplitude 0.5 mm, 16 samples per wavelength. Caps are flat (z = 0 and
    z = 20 mm), triangulated as a centre fan plus 3 rings. Centred on the z axis.
    25,600 triangles (Table 1); convex at coarse resolution.
    """
    nt, nz, nr = GEAR_N_THETA, GEAR_N_Z, GEAR_N_RINGS
    th = 2 * np.pi * np.arange(nt) / nt
    r = ridged_gear_radius(th)
    zs = np.linspace(0.0, GEAR_THICKNESS, nz + 1)
    c, s = np.cos(th), np.sin(th)
    # Rim vertices, layout z-row major: index k*nt + t (k = row, t = angle).
    rim = np.stack([np.tile(r * c, nz + 1), np.tile(r * s, nz + 1), np.repeat(zs, nt)], 1)
    # Rim quads: first tangent along theta (counter-clockwise about +z), second along +z:
    # (t_theta, t_z, n) is right-handed with n pointing outward.
    i = np.arange(nt)[:, None]
    k = np.arange(nz)[None, :]
    a = k * nt + i
    b = k * nt + (i + 1) % nt
    cc = (k + 1) * nt + (i + 1) % nt
    d = (k + 1) * nt + i
    a, b, cc, d = (np.broadcast_to(x, (nt, nz)).ravel() for x in (a, b, cc, d))
    rim_f = np.stack([np.stack([a, b, cc], 1), np.stack([a, cc, d], 1)], 1).reshape(-1, 3)
    verts = [rim]
    faces = [rim_f]
    n_rim = len(rim)
    # Caps: rings at fractions m/nr of the rim radius (m = 1..nr-1), plus the centre.
    base = n_rim
    for z, outer_row, up in ((0.0, 0, False), (GEAR_THICKNESS, nz, True)):
        ring_ids = []
        for m in range(1, nr):
            f = m / nr
            verts.append(np.stack([f * r * c, f * r * s, np.full(nt, z)], 1))
            ring_ids.append(base + np.arange(nt))
            base += nt
        verts.append(np.array([[0.0, 0.0, z]]))
        centre = base
        base += 1
        ring_ids.append(outer_row * nt + np.arange(nt))
        cap = []
        t0 = np.arange(nt)
        t1 = (t0 + 1) % nt
        inner = ring_ids[0]
        cap.append(np.stack([np.full(nt, centre), inner[t0], inner[t1]], 1))
        for lo, hi in zip(ring_ids[:-1], ring_ids[1:]):
            cap.append(np.stack([lo[t0], hi[t0], hi[t1]], 1))
            cap.append(np.stack([lo[t0], hi[t1], lo[t1]], 1))
        cap = np.concatenate(cap)          # counter-clockwise seen from +z
        faces.append(cap if up else cap[:, ::-1])
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)
    return _finish(mesh, 25_600)


# --------------------------------------------------------------------------
# Wrinkled torus (Table 1: 128,000 triangles)
# --------------------------------------------------------------------------

def wrinkled_torus_offset(u, v) -> np.ndarray:
    """Radial offset (m) of the torus tube at angles ``u`` (around z) and ``v`` (around the tube)."""
    return TORUS_AMPLITUDE * np.sin(TORUS_WAVES_U * np.asarray(u) + TORUS_WAVES_V * np.asarray(v))


def wrinkled_torus() -> trimesh.Trimesh:
    """Torus (major radius 50 mm, tube radius 20 mm, axis z) with helical wrinkles.

    Tube radius ``rho(u, v) = 20 mm + A sin(40 u + 8 v)``, A = 0.6 mm. The
    wrinkle wavelength is 4.5 mm on the inner equator and 9.0 mm on the outer
    one; 400 x 160 samples (10 per wavelength along u). 128,000 triangles
    (Table 1). Centred at the origin.
    """
    nu, nv = TORUS_NU, TORUS_NV
    u = 2 * np.pi * np.arange(nu) / nu
    v = 2 * np.pi * np.arange(nv) / nv
    U, V = np.meshgrid(u, v, indexing="ij")
    rho = TORUS_r + wrinkled_torus_offset(U, V)
    ring = TORUS_R + rho * np.cos(V)
    verts = np.stack([ring * np.cos(U), ring * np.sin(U), rho * np.sin(V)], -1).reshape(-1, 3)
    # (d/du, d/dv, n) is right-handed with n outward: at u = v = 0, d/du = +y,
    # d/dv = +z and their cross product +x points out of the tube.
    faces = _grid_quads(nu, nv, 0, wrap_u=True, wrap_v=True)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    return _finish(mesh, 128_000)


# --------------------------------------------------------------------------
# Grating turned at a non-axis angle
# --------------------------------------------------------------------------

def _grating_profile(t, profile: str) -> np.ndarray:
    """Unit-amplitude periodic profile of phase ``t`` (in wavelengths)."""
    if profile == "sine":
        return np.sin(2 * np.pi * t)
    if profile == "triangle":
        f = t - np.floor(t)
        return 1.0 - 4.0 * np.abs(f - 0.5)          # -1 at integers, +1 at half-integers
    raise ValueError(f"unknown grating profile {profile!r} (sine, triangle)")


def grating_height(x, y, angle_deg: float = 23.0, profile: str = "sine") -> np.ndarray:
    """Analytic top height (m) of :func:`grating` at ``(x, y)``.

    ``z = H + A p((x cos a + y sin a) / L)``: H = 20 mm, A = 0.5 mm, L = 5 mm,
    ``p`` the unit sine or triangle wave; the ridges run along the direction
    ``(-sin a, cos a)``. The mesh is this function's piecewise-linear interpolant
    on a 128 x 128 grid of 0.47 mm cells, whose lines are not aligned with the ridges.
    """
    a = math.radians(angle_deg)
    t = (np.asarray(x) * math.cos(a) + np.asarray(y) * math.sin(a)) / GRATING_WAVELENGTH
    return GRATING_SIZE[2] + GRATING_AMPLITUDE * _grating_profile(t, profile)


def grating(angle_deg: float = 23.0, profile: str = "sine") -> trimesh.Trimesh:
    """Block 60 x 60 mm, 20 mm tall, whose top is a grating turned ``angle_deg`` from the x axis.

    Wavelength 5 mm, amplitude 0.5 mm (see :func:`grating_height`); ``profile``
    is ``"sine"`` (default) or ``"triangle"``. 66,560 triangles. The non-axis
    angle means neither the grid nor the atlas texels line up with the ridges.
    """
    lx, ly, _ = GRATING_SIZE
    xs = np.linspace(0.0, lx, GRATING_N + 1)
    ys = np.linspace(0.0, ly, GRATING_N + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    top = grating_height(X, Y, angle_deg, profile)
    mesh = _heightfield_block(xs, ys, top, np.zeros_like(top))
    return _finish(mesh, 4 * GRATING_N * GRATING_N + 8 * GRATING_N)


# --------------------------------------------------------------------------
# Textured CAD part (Table 1: 658,432 triangles)
# --------------------------------------------------------------------------

# Boss of the bracket (m): axis at (BOSS_X, BOSS_Y), from the plate top upwards.
_BOSS_X, _BOSS_Y, _BOSS_R, _BOSS_Z0, _BOSS_H = 30 * MM, 26 * MM, 16 * MM, 12 * MM, 24 * MM
_MILL_CENTRE = (-40 * MM, 30 * MM)     # face-mill centre, off the part so the arcs curve


def _bracket(segments: int = 128):
    """Untextured L-bracket as a manifold3d solid (mm-sized features, in meters)."""
    import manifold3d as m3d

    M = m3d.Manifold
    base = M.cube([100 * MM, 60 * MM, 12 * MM])
    upright = M.cube([100 * MM, 12 * MM, 50 * MM]).translate([0, 48 * MM, 12 * MM])
    boss = M.cylinder(_BOSS_H, _BOSS_R, _BOSS_R, segments).translate([_BOSS_X, _BOSS_Y, _BOSS_Z0])
    bore = M.cylinder(60 * MM, 8 * MM, 8 * MM, segments).translate([_BOSS_X, _BOSS_Y, -5 * MM])
    hole1 = M.cylinder(30 * MM, 4 * MM, 4 * MM, segments // 2).translate([75 * MM, 15 * MM, -5 * MM])
    hole2 = M.cylinder(30 * MM, 4 * MM, 4 * MM, segments // 2).translate([75 * MM, 38 * MM, -5 * MM])
    window = M.cylinder(30 * MM, 7 * MM, 7 * MM, segments).rotate([-90, 0, 0]) \
        .translate([60 * MM, 40 * MM, 40 * MM])
    return (base + upright + boss) - bore - hole1 - hole2 - window


def cad_texture(points: np.ndarray) -> np.ndarray:
    """Displacement (m, along the outward normal) of the CAD part's texture at ``points``.

    Face-milling arcs everywhere: ``A sin(2 pi |p_xy - c| / L)`` with c 40 mm off
    the part's -x side, L = 2 mm, A = 0.08 mm. On the boss's cylindrical face a
    diamond knurl replaces them: ``A sin(k theta + 2 pi z / P) sin(k theta - 2 pi z / P)``
    with pitch P = 2 mm and k chosen so the circumferential pitch is also 2 mm.
    """
    p = np.asarray(points, dtype=float)
    rho = np.hypot(p[:, 0] - _MILL_CENTRE[0], p[:, 1] - _MILL_CENTRE[1])
    d = CAD_AMPLITUDE * np.sin(2 * np.pi * rho / CAD_WAVELENGTH)
    dx, dy = p[:, 0] - _BOSS_X, p[:, 1] - _BOSS_Y
    rb = np.hypot(dx, dy)
    on_boss = (np.abs(rb - _BOSS_R) < 0.05 * MM) & (p[:, 2] > _BOSS_Z0 + 1e-6) \
        & (p[:, 2] < _BOSS_Z0 + _BOSS_H - 1e-6)
    k = round(2 * np.pi * _BOSS_R / CAD_KNURL_WAVELENGTH)
    th = np.arctan2(dy, dx)
    w = 2 * np.pi * p[:, 2] / CAD_KNURL_WAVELENGTH
    knurl = CAD_KNURL_AMPLITUDE * np.sin(k * th + w) * np.sin(k * th - w)
    return np.where(on_boss, knurl, d)


def cad_part(target: int = 650_000) -> trimesh.Trimesh:
    """Textured CAD-like part of about ``target`` triangles (within 2 %).

    An L-bracket (plate 100 x 60 x 12 mm, upright 100 x 12 x 50 mm with a 14 mm
    window, a 32 mm boss with a 16 mm bore, two 8 mm mounting holes), made with
    manifold3d booleans, refined to edges of about ``sqrt(area / target)``, then
    every vertex displaced along its normal by :func:`cad_texture` (milling arcs,
    wavelength 2 mm, amplitude 0.08 mm; a knurl on the boss). Vertices on sharp
    edges (one of their faces' normals is more than ~30 deg from the vertex
    normal) are not displaced, so the texture cannot fold a concave edge over
    itself (the weight ramps from 1 at 26 deg to 0 at 32 deg). The refined
    booleans keep their long sliver triangles, as CAD tessellations do. The
    paper's CAD part has 658,432 triangles (Table 1).
    """
    if target < 50_000:
        raise ValueError("cad_part target must be at least 50,000 triangles")
    # Pre-split the big planar faces (two triangles each after the booleans) to
    # about 8 fine edge lengths, so that the count below varies smoothly with the
    # edge length (refining one 100 mm triangle jumps by whole rows of sub-triangles).
    bracket = _bracket()
    length = math.sqrt(4 * bracket.surface_area() / (math.sqrt(3) * target))
    part = bracket.refine_to_length(8 * length)
    # refine_to_length splits every edge longer than the length, so edges end up
    # between 1/2 and 1 of it: start 1.5 times longer than the equilateral estimate.
    length *= 1.5
    # Search the edge length: secant steps on log(count) against log(length)
    # (count ~ length^-2 for a uniform refinement; less with the pre-split), kept
    # inside the bracket of lengths known to give too many / too few triangles.
    best = None
    too_many, too_few = 0.0, math.inf
    prev = None
    for _ in range(16):
        refined = part.refine_to_length(length)
        n = refined.num_tri()
        if best is None or abs(n - target) < abs(best[1] - target):
            best = (refined, n)
        if abs(n - target) <= 0.005 * target:
            break
        if n > target:
            too_many = max(too_many, length)
        else:
            too_few = min(too_few, length)
        slope = 2.0
        if prev is not None and prev[1] != n and prev[0] != length:
            slope = -math.log(n / prev[1]) / math.log(length / prev[0])
            slope = min(max(slope, 0.5), 4.0)
        prev = (length, n)
        step = length * (n / target) ** (1.0 / slope)
        if not too_many < step < too_few:
            step = math.sqrt(too_many * too_few)
        length = step
    refined, n = best
    if abs(n - target) > 0.02 * target:
        raise AssertionError(f"cad_part: {n} triangles, target {target}")
    mm = refined.to_mesh64()       # double precision: float32 would fold the slivers
    verts = np.asarray(mm.vert_properties, dtype=np.float64)[:, :3].copy()
    faces = np.asarray(mm.tri_verts, dtype=np.int64)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    normals = mesh.vertex_normals
    # Flatness: smallest cosine between the vertex normal and its faces' normals.
    fn = mesh.face_normals
    cos = np.einsum("ij,ij->i", np.repeat(fn, 3, axis=0), normals[faces.ravel()])
    flat = np.ones(len(verts))
    np.minimum.at(flat, faces.ravel(), cos)
    weight = np.clip((flat - 0.85) / 0.05, 0.0, 1.0)
    verts = verts + normals * (weight * cad_texture(verts))[:, None]
    mesh = trimesh.Trimesh(verts, faces, process=False)
    return _finish(mesh)


# --------------------------------------------------------------------------
# Rasp (the paper's "file", Table 1: 285,824 triangles)
# --------------------------------------------------------------------------

def rasp_teeth(x, y) -> np.ndarray:
    """Tooth height (m, >= 0) of the rasp's double-cut faces at ``(x, y)``.

    Two families of sawtooth ridges of pitch 2 mm cross at 65 deg (overcut) and
    -45 deg (upcut) to the long axis x; the tooth is the lower of the two,
    ``h = T min(s(u / P), s(v / P))`` with T = 0.4 mm, so the face is covered by
    diamond-shaped, forward-leaning teeth. ``s`` rises over 80 % of a pitch and
    drops over the last 20 % (a cutting edge).
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)

    def saw(t):
        f = t - np.floor(t)
        return np.where(f < 0.8, f / 0.8, (1.0 - f) / 0.2)

    a, b = math.radians(RASP_OVERCUT_DEG), math.radians(RASP_UPCUT_DEG)
    u = -x * math.sin(a) + y * math.cos(a)      # across the overcut lines
    v = -x * math.sin(b) + y * math.cos(b)      # across the upcut lines
    return RASP_TOOTH_HEIGHT * np.minimum(saw(u / RASP_TOOTH_PITCH), saw(v / RASP_TOOTH_PITCH))


def rasp() -> trimesh.Trimesh:
    """File-like bar 160 x 20 x 6 mm with cross-cut teeth on both broad faces.

    Teeth (see :func:`rasp_teeth`): pitch 2 mm, height 0.4 mm (amplitude 0.2 mm),
    sampled on 0.2 x 0.23 mm cells. The body is 6 mm thick to the roots of the
    teeth, the long axis is x, the bar is centred on the origin. 285,152
    triangles (the paper's file: 285,824). Used by the runtime benchmark
    (a file scraping the CAD part, Fig. 9).
    """
    lx, ly, lz = RASP_SIZE
    xs = np.linspace(-lx / 2, lx / 2, RASP_NX + 1)
    ys = np.linspace(-ly / 2, ly / 2, RASP_NY + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    teeth = rasp_teeth(X, Y)
    top = lz / 2 + teeth
    # Bottom face: the same teeth mirrored through the mid-plane (a double-sided file).
    bottom = -lz / 2 - rasp_teeth(X, -Y)
    mesh = _heightfield_block(xs, ys, top, bottom)
    return _finish(mesh, 4 * RASP_NX * RASP_NY + 4 * (RASP_NX + RASP_NY))


# --------------------------------------------------------------------------
# Registry and writer
# --------------------------------------------------------------------------

MODELS: dict[str, ModelInfo] = {
    m.name: m for m in (
        ModelInfo("ridged_block", ridged_block, 65_536, BLOCK_WAVELENGTH, BLOCK_AMPLITUDE,
                  "block with 12 parallel sinusoidal ridges on its top (Table 1 block)"),
        ModelInfo("ridged_gear", ridged_gear, 25_600, GEAR_WAVELENGTH, GEAR_AMPLITUDE,
                  "disc with 50 ridges along its axis on the rim (Table 1 gear)"),
        ModelInfo("wrinkled_torus", wrinkled_torus, 128_000, 4.5 * MM, TORUS_AMPLITUDE,
                  "torus with helical wrinkles (Table 1 torus)"),
        ModelInfo("grating", grating, 66_560, GRATING_WAVELENGTH, GRATING_AMPLITUDE,
                  "block with a sinusoidal grating turned 23 deg on its top"),
        ModelInfo("cad_part", cad_part, None, CAD_WAVELENGTH, CAD_AMPLITUDE,
                  "milled L-bracket with a knurled boss, ~650k triangles (Table 1 CAD part)"),
        ModelInfo("rasp", rasp, 285_152, RASP_TOOTH_PITCH, RASP_TOOTH_HEIGHT / 2,
                  "file-like bar with cross-cut teeth (Table 1 file)"),
    )
}


def generate(name: str, path: str | os.PathLike) -> trimesh.Trimesh:
    """Make model ``name`` and write it to ``path`` (format from the extension).

    Binary PLY (``.ply``) is the compact default. The file is written to a
    temporary sibling first and renamed, so an interrupted run leaves nothing.
    Returns the mesh.
    """
    if name not in MODELS:
        raise KeyError(f"unknown model {name!r}; known: {', '.join(MODELS)}")
    mesh = MODELS[name].make()
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    if not ext:
        raise ValueError(f"{path}: no file extension to choose the mesh format")
    data = mesh.export(file_type=ext)
    if isinstance(data, str):
        data = data.encode()
    tmp = os.path.join(os.path.dirname(path) or ".", f".{os.path.basename(path)}.tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return mesh
