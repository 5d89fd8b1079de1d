"""Procedural models and end-to-end bakes.

Part 1 checks the generators of hbake/lab/procedural.py: exact triangle counts
(Table 1), closed and outward meshes (checked by point-in-solid queries, not by
the winding alone), byte-identical output, and that the documented wavelength
and amplitude of each relief are what the mesh carries (measured by an FFT of
the vertices, independently of the formulas that made them).

Part 2 bakes every procedural model and every shared model and checks the
bundles (see the constants below for the bounds and why).
"""
from __future__ import annotations

import hashlib
import math
import os

import numpy as np
import pytest
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from hbake.lab import procedural as P


# ==========================================================================
# Part 1: the generators
# ==========================================================================

@pytest.fixture(scope="module")
def meshes():
    """Each registered model, made once per module (the CAD part takes seconds)."""
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = P.MODELS[name].make()
        return cache[name]

    return get


@pytest.mark.parametrize("name", list(P.MODELS))
def test_generator_counts_and_closed(name, meshes):
    mesh = meshes(name)
    info = P.MODELS[name]
    if info.triangles is not None:
        assert len(mesh.faces) == info.triangles
    else:  # the CAD part: "about 650k" (the paper's has 658,432)
        assert abs(len(mesh.faces) - 650_000) <= 0.02 * 650_000
    # Closed, edge-manifold (every edge shared by exactly two faces), one shell.
    edges = np.sort(mesh.edges, axis=1).astype(np.int64)
    _, counts = np.unique(edges[:, 0] * len(mesh.vertices) + edges[:, 1], return_counts=True)
    assert np.all(counts == 2), f"{name}: {np.sum(counts != 2)} edges not shared by two faces"
    # Consistent winding: each directed edge appears once (its twin runs the other way).
    directed = mesh.edges.astype(np.int64)
    assert len(np.unique(directed[:, 0] * len(mesh.vertices) + directed[:, 1])) == len(directed)
    # One shell.
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])),
                       shape=(len(mesh.vertices),) * 2)
    assert connected_components(graph, directed=False)[0] == 1
    # No degenerate faces (the baker would drop them and change the count).
    assert mesh.area_faces.min() > 0
    # Meters: hand-sized parts, 2 cm to 20 cm.
    assert 0.02 < mesh.extents.max() < 0.2


@pytest.mark.parametrize("name", list(P.MODELS))
def test_generator_outward(name, meshes):
    """Points just outside each face (along its normal) are outside the solid, just inside are inside.

    ``contains`` casts rays and counts crossings, so this checks orientation
    independently of the signed volume. 400 faces per model, fixed seed; the
    offset (2 um) is far below every feature size (>= 0.2 mm) but far above the
    float32 rounding of the coordinates (a few nm).
    """
    mesh = meshes(name)
    assert mesh.volume > 0
    rng = np.random.default_rng(7)
    faces = rng.choice(len(mesh.faces), 400, replace=False)
    c = mesh.triangles_center[faces]
    n = mesh.face_normals[faces]
    eps = 2e-6
    outside = mesh.contains(c + eps * n)
    inside = mesh.contains(c - eps * n)
    # Faces right next to a concave sharp edge may see the other face within
    # 2 um; none of the grid models has one, the CAD part a few.
    allowed = 4 if name == "cad_part" else 0
    assert np.sum(outside) <= allowed, f"{name}: {np.sum(outside)} offsets along +n are inside"
    assert np.sum(~inside) <= allowed, f"{name}: {np.sum(~inside)} offsets along -n are outside"


@pytest.mark.parametrize("name", ["ridged_block", "ridged_gear", "grating", "rasp", "cad_part"])
def test_generator_deterministic(name, tmp_path, meshes):
    """Two independent generations (the fixture's and generate()'s) give the same bytes."""
    path = tmp_path / "a.ply"
    P.generate(name, path)
    again = meshes(name).export(file_type="ply")
    assert hashlib.sha256(path.read_bytes()).hexdigest() == hashlib.sha256(again).hexdigest()
    back = trimesh.load(path, process=False)
    assert len(back.faces) == len(meshes(name).faces)


def _dominant(signal: np.ndarray, spacing: float) -> tuple[float, float]:
    """Wavelength and amplitude of the strongest non-constant Fourier component."""
    spec = np.fft.rfft(signal - signal.mean())
    k = int(np.argmax(np.abs(spec[1:]))) + 1
    return len(signal) * spacing / k, 2 * np.abs(spec[k]) / len(signal)


def test_block_relief_matches_docs(meshes):
    mesh = meshes("ridged_block")
    v = mesh.vertices
    top = v[v[:, 2] > P.BLOCK_SIZE[2] / 2]
    # Height depends on y only (ridges parallel to x).
    rows = {}
    for y, z in zip(np.round(top[:, 1], 9), top[:, 2]):
        rows.setdefault(y, []).append(z)
    assert all(np.ptp(zs) < 1e-6 for zs in rows.values())
    ys = np.array(sorted(rows))
    zs = np.array([rows[y][0] for y in ys])
    wl, amp = _dominant(zs[:-1], ys[1] - ys[0])     # one full period count: drop the end row
    assert wl == pytest.approx(P.BLOCK_WAVELENGTH, rel=1e-6)
    assert amp == pytest.approx(P.BLOCK_AMPLITUDE, rel=1e-3)
    assert np.ptp(zs) == pytest.approx(2 * P.BLOCK_AMPLITUDE, rel=1e-3)
    # The documented exact profile is the mesh surface: vertical rays hit it.
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(1e-3, 49e-3, 300), rng.uniform(1e-3, 59e-3, 300)])
    origins = np.column_stack([pts, np.full(300, 0.05)])
    hits, ray_idx, _ = mesh.ray.intersects_location(origins, np.tile([0, 0, -1.0], (300, 1)),
                                                    multiple_hits=False)
    order = np.argsort(ray_idx)
    assert len(ray_idx) == 300
    z_hit = hits[order, 2]
    assert np.max(np.abs(z_hit - P.ridged_block_height(pts[:, 1]))) < 1e-6
    # ... and the smooth sine is within the documented 17 um of it.
    assert np.max(np.abs(P.ridged_block_height(pts[:, 1], exact=False) - z_hit)) <= \
        P.BLOCK_AMPLITUDE * (1 - math.cos(math.pi / 12)) + 1e-6


def test_gear_relief_matches_docs(meshes):
    v = meshes("ridged_gear").vertices
    rim = v[np.abs(v[:, 2] - 4 * P.GEAR_THICKNESS / P.GEAR_N_Z) < 1e-6]   # one rim row
    r = np.hypot(rim[:, 0], rim[:, 1])
    rim = rim[r > P.GEAR_RADIUS - 2 * P.GEAR_AMPLITUDE]
    th = np.arctan2(rim[:, 1], rim[:, 0])
    order = np.argsort(th)
    r = np.hypot(rim[order, 0], rim[order, 1])
    assert len(r) == P.GEAR_N_THETA
    wl, amp = _dominant(r, 2 * np.pi * P.GEAR_RADIUS / len(r))
    assert wl == pytest.approx(P.GEAR_WAVELENGTH, rel=1e-6)
    assert amp == pytest.approx(P.GEAR_AMPLITUDE, rel=1e-3)


def test_torus_relief_matches_docs(meshes):
    v = meshes("wrinkled_torus").vertices
    u = np.arctan2(v[:, 1], v[:, 0])
    ring = np.hypot(v[:, 0], v[:, 1])
    rho = np.hypot(ring - P.TORUS_R, v[:, 2])
    inner = np.abs(v[:, 2]) < 1e-9                       # v = 0 and v = pi rows
    for side, wl_expected in ((ring < P.TORUS_R, 2 * np.pi * (P.TORUS_R - P.TORUS_r) / 40),
                              (ring > P.TORUS_R, 2 * np.pi * (P.TORUS_R + P.TORUS_r) / 40)):
        sel = inner & side
        order = np.argsort(u[sel])
        radius = np.mean(ring[sel])
        wl, amp = _dominant(rho[sel][order], 2 * np.pi * radius / np.sum(sel))
        assert wl == pytest.approx(wl_expected, rel=0.03)
        assert amp == pytest.approx(P.TORUS_AMPLITUDE, rel=1e-3)
    # The registry's wavelength is the shortest one, across the helical crests on
    # the inner equator: wave numbers 40 / (R - r) along u and 8 / r along v.
    k = math.hypot(P.TORUS_WAVES_U / (P.TORUS_R - P.TORUS_r), P.TORUS_WAVES_V / P.TORUS_r)
    assert P.MODELS["wrinkled_torus"].wavelength == pytest.approx(2 * np.pi / k, rel=0.01)


def test_grating_direction_and_wavelength(meshes):
    v = meshes("grating").vertices
    top = v[v[:, 2] > P.GRATING_SIZE[2] / 2]
    n = P.GRATING_N + 1
    order = np.lexsort((top[:, 1], top[:, 0]))
    z = top[order, 2].reshape(n, n)[:-1, :-1]
    h = P.GRATING_SIZE[0] / P.GRATING_N
    # Window the non-periodic patch, then find the 2D spectral peak.
    w = np.hanning(z.shape[0])
    spec = np.abs(np.fft.rfft2((z - z.mean()) * w[:, None] * w[None, :]))
    spec[0, 0] = 0
    i, j = np.unravel_index(np.argmax(spec), spec.shape)
    fx = np.fft.fftfreq(z.shape[0], h)[i]
    fy = np.fft.rfftfreq(z.shape[1], h)[j]
    # FFT bins are 1/60 mm^-1 wide, so the angle is good to a few degrees only.
    angle = math.degrees(math.atan2(abs(fy), abs(fx)))
    assert angle == pytest.approx(23.0, abs=4.0)
    assert 1 / math.hypot(fx, fy) == pytest.approx(P.GRATING_WAVELENGTH, rel=0.1)
    # Exact: the top vertices are the analytic grating (sampled on the grid).
    assert np.max(np.abs(top[:, 2] - P.grating_height(top[:, 0], top[:, 1]))) < 1e-9
    # A different angle turns the ridges.
    assert not np.allclose(P.grating(angle_deg=40).vertices, v)


def test_rasp_teeth(meshes):
    mesh = meshes("rasp")
    v = mesh.vertices
    half = P.RASP_SIZE[2] / 2
    top = v[v[:, 2] > 0]
    teeth = top[:, 2] - half
    assert teeth.min() >= -1e-12 and teeth.max() == pytest.approx(P.RASP_TOOTH_HEIGHT, rel=0.05)
    # Along the long axis the teeth repeat with pitch / sin(65 deg) and / sin(45 deg):
    # the spectrum of one row has its strongest line at one of the two.
    row = top[np.abs(top[:, 1]) < 1e-9]
    row = row[np.argsort(row[:, 0])]
    wl, _ = _dominant(row[:-1, 2], row[1, 0] - row[0, 0])
    pitches = [P.RASP_TOOTH_PITCH / math.sin(math.radians(a))
               for a in (P.RASP_OVERCUT_DEG, -P.RASP_UPCUT_DEG)]
    assert min(abs(wl - p) / p for p in pitches) < 0.05
    # Both broad faces are toothed.
    assert np.ptp(v[v[:, 2] < 0][:, 2]) == pytest.approx(P.RASP_TOOTH_HEIGHT, rel=0.05)


def test_cad_texture(meshes):
    mesh = meshes("cad_part")
    # Texture amplitude: vertices on the flat plate top (z = 12 mm, away from the
    # boss and the upright) deviate from the plane by the milling arcs only.
    v = mesh.vertices
    plate = v[(np.abs(v[:, 2] - 12e-3) < 0.2e-3) & (v[:, 0] > 55e-3) & (v[:, 0] < 95e-3)
              & (v[:, 1] > 22e-3) & (v[:, 1] < 30e-3)]
    assert len(plate) > 1000
    dz = plate[:, 2] - 12e-3
    assert np.max(np.abs(dz)) == pytest.approx(P.CAD_AMPLITUDE, rel=0.02)
    # ... and follow the arcs about the documented centre with the documented wavelength.
    rho = np.hypot(plate[:, 0] - P._MILL_CENTRE[0], plate[:, 1] - P._MILL_CENTRE[1])
    expected = P.CAD_AMPLITUDE * np.sin(2 * np.pi * rho / P.CAD_WAVELENGTH)
    assert np.max(np.abs(dz - expected)) < 1e-5
    # Genus 4 (bore, two mounting holes, window): Euler characteristic 2 - 2g = -6.
    assert mesh.euler_number == -6


# ==========================================================================
# Part 2: end-to-end bakes
# ==========================================================================

from pathlib import Path  # noqa: E402

from hbake import bake  # noqa: E402
from hbake.lab.bench import SHARED_MODELS, SHARED_OVERRIDES, shared_models_dir  # noqa: E402
from hbake.bundle import atlas_lookup, read_bundle, validate_bundle  # noqa: E402
from hbake.settings import BakeSettings  # noqa: E402

SHARED_DIR = shared_models_dir()  # $HBAKE_MODELS, else ../shared/models beside the repository

#: On the procedural models both directions of the reconstruction error
#: have p95 below half a texel. Why half a texel: the atlas samples the surface
#: once per texel, so a point mapped through it can be off by at most about
#: half a texel step where the relief is resolved (Sec. 7.2: wavelengths of
#: two texels and more); the procedural relief has wavelengths of 9-50 texels.
PROCEDURAL_P95_TEXELS = 0.5

#: Settings per procedural model: the coarse size of Table 1 where it matters
#: (the block bakes to a box, at most 16 triangles), defaults otherwise. The
#: CAD part is baked at 200k triangles here (same shape and texture as the
#: 650k benchmark part, a third of the time); the benchmark bakes the full one.
PROCEDURAL_BAKES = {
    "ridged_block": {"simplify.target_faces": 16},
    "ridged_gear": {},
    "wrinkled_torus": {},
    "grating": {},
    "rasp": {},
    "cad_part": {},
}
CAD_TEST_TRIANGLES = 200_000


def _bake(src: Path, out: Path, overrides: dict) -> dict:
    settings = BakeSettings().with_overrides(overrides)
    return bake(src, out, settings, force=False)


def _independent_c2f(bundle, full: trimesh.Trimesh, count: int = 2000, seed: int = 11):
    """Coarse -> full error recomputed without the pipeline's sampler or closest-point code.

    Samples the coarse surface (trimesh), maps the samples through the atlas
    (bilinear lookup, docs/bundle-format.md) and measures their distance to the
    full mesh with trimesh's exact closest-point query.
    """
    coarse = trimesh.Trimesh(bundle.coarse_vertices, bundle.coarse_faces, process=False)
    pts, fid = trimesh.sample.sample_surface(coarse, count, seed=seed)
    bary = trimesh.triangles.points_to_barycentric(coarse.triangles[fid], pts)
    uv = np.einsum("nk,nkd->nd", bary, np.asarray(bundle.coarse_uvs, dtype=np.float64)[fid])
    mapped = atlas_lookup(bundle.atlas, uv)[:, :3]
    return _closest_distance(full, mapped)


def _point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """Exact distance from points p to triangles (a, b, c), row by row (Ericson,
    Real-Time Collision Detection 5.1.5: Voronoi regions of vertices, edges, face).
    Written here so the check does not share code with the pipeline (and because
    trimesh's closest_point uses absolute tolerances that fail on sub-mm triangles)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    q = np.zeros_like(p)
    done = np.zeros(len(p), dtype=bool)

    def put(mask, value):
        m = mask & ~done
        q[m] = value[m]
        done[m] = True

    with np.errstate(divide="ignore", invalid="ignore"):
        put((d1 <= 0) & (d2 <= 0), a)                                   # vertex a
        put((d3 >= 0) & (d4 <= d3), b)                                  # vertex b
        put((d6 >= 0) & (d5 <= d6), c)                                  # vertex c
        put((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + (d1 / (d1 - d3))[:, None] * ab)   # edge ab
        put((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + (d2 / (d2 - d6))[:, None] * ac)   # edge ac
        put((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
            b + ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None] * (c - b))           # edge bc
        den = va + vb + vc
        put(np.ones(len(p), dtype=bool),
            a + (vb / den)[:, None] * ab + (vc / den)[:, None] * ac)              # face
    return np.linalg.norm(p - q, axis=1)


def _closest_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Exact distance from each point to the mesh, by k-d trees and the point-triangle
    distance above (independent of the pipeline's pymeshlab query).

    The nearest vertex at distance d0 bounds the answer, and a triangle within d0 of
    the point has its centroid within d0 + R of it (R: the largest centroid-to-vertex
    distance), so those candidates contain the closest triangle.
    """
    from scipy.spatial import cKDTree

    tri = mesh.triangles
    cen = tri.mean(axis=1)
    reach = float(np.max(np.linalg.norm(tri - cen[:, None, :], axis=2)))
    d0, _ = cKDTree(mesh.vertices).query(points)
    cand = cKDTree(cen).query_ball_point(points, d0 * (1 + 1e-9) + reach)
    out = np.zeros(len(points))
    for i, c in enumerate(cand):
        t = tri[np.asarray(c, dtype=np.int64)]
        p = np.repeat(points[i:i + 1], len(t), axis=0)
        out[i] = np.min(_point_triangle_distance(p, t[:, 0], t[:, 1], t[:, 2]))
    return out


def test_closest_distance_helper():
    """The checker itself, against dense sampling of random triangles (brute force)."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        t = rng.normal(size=(3, 3)) * 1e-4            # sub-mm triangles, like the models'
        p = rng.normal(size=(50, 3)) * 2e-4
        d = _point_triangle_distance(p, *(np.repeat(t[k:k + 1], 50, axis=0) for k in range(3)))
        u, v = np.meshgrid(np.linspace(0, 1, 301), np.linspace(0, 1, 301))
        keep = u + v <= 1
        s = t[0] + u[keep][:, None] * (t[1] - t[0]) + v[keep][:, None] * (t[2] - t[0])
        brute = np.min(np.linalg.norm(p[:, None, :] - s[None], axis=2), axis=1)
        # The grid is 1/300 of an edge: brute force overestimates by at most that.
        step = np.max(np.linalg.norm(t - np.roll(t, 1, axis=0), axis=1)) / 300
        assert np.all(d <= brute + 1e-15) and np.all(brute - d <= step)


@pytest.fixture(scope="module")
def procedural_bundles(tmp_path_factory):
    """name -> (bundle path, full mesh, bake report); each model baked once, lazily."""
    root = tmp_path_factory.mktemp("procedural")
    cache = {}

    def get(name):
        if name not in cache:
            mesh = P.cad_part(CAD_TEST_TRIANGLES) if name == "cad_part" else P.MODELS[name].make()
            src = root / f"{name}.ply"
            src.write_bytes(mesh.export(file_type="ply"))
            out = root / f"{name}.hbundle"
            report = _bake(src, out, {"load.units": "m", **PROCEDURAL_BAKES[name]})
            cache[name] = (out, mesh, report)
        return cache[name]

    return get


#: Known failures, measured, kept visible (strict: a fix makes them fail as XPASS).
KNOWN_PROCEDURAL: dict[str, str] = {}
KNOWN_SHARED: dict[str, str] = {}

#: Settings per shared model where the defaults do not suit it: hbake.lab.bench.SHARED_OVERRIDES
#: (the planetary gears; the measurements are there).
SHARED_BAKES = SHARED_OVERRIDES


#: Bakes measured at 25 s or more each on the 2-core machine (CoACD dominates; figures in
#: the bake benchmark of docs/guides/baking.md), and, to keep `make test` within its time, the bakes a
#: faster model of the same kind already covers there (fandisk for the shared scans and
#: CAD parts: armadillo, rocker arm, hammer; the ridged block and the grating for the
#: procedural reliefs: gear, torus, rasp; the armadillo is also baked by the
#: thin-feature tests): marked slow, as the project's rule asks. `make test-slow` runs them.
SLOW_BAKES = {"planetary_gears.stl", "stanford_bunny.obj", "mountain_terrain.obj", "cad_part",
              "armadillo.obj", "rocker_arm.obj", "hammer_scan.obj",
              "ridged_gear", "wrinkled_torus", "rasp"}


def _params(names, known):
    out = []
    for n in names:
        marks = [pytest.mark.xfail(reason=known[n], strict=True)] if n in known else []
        if n in SLOW_BAKES:
            marks.append(pytest.mark.slow)
        out.append(pytest.param(n, marks=marks))
    return out


@pytest.mark.parametrize("name", _params(PROCEDURAL_BAKES, KNOWN_PROCEDURAL))
def test_bake_procedural(name, procedural_bundles):
    path, mesh, report = procedural_bundles(name)
    assert validate_bundle(path) == []
    m = read_bundle(path).manifest
    texel = m["atlas"]["texel_size"]
    rec = m["quality"]["reconstruction"]
    c2f, f2c = rec["coarse_to_full"]["p95"] / texel, rec["full_to_coarse"]["p95"] / texel
    assert c2f < PROCEDURAL_P95_TEXELS and f2c < PROCEDURAL_P95_TEXELS, (
        f"{name}: p95 coarse->full {c2f:.3f}, full->coarse {f2c:.3f} texels "
        f"(texel {texel * 1e3:.4f} mm, coarse {m['coarse']['triangles']} triangles)")
    # The relief is resolved (Sec. 7.2): its wavelength spans more than two texels.
    assert P.MODELS[name].wavelength > m["quality"]["min_wavelength"]
    # The manifest's figure agrees with an independent measurement.
    d = _independent_c2f(read_bundle(path), mesh)
    assert np.percentile(d, 95) < PROCEDURAL_P95_TEXELS * texel
    assert m["source"]["triangles"] == len(mesh.faces)
    assert m["mass"]["basis"] == "full"
    assert m["mass"]["volume"] == pytest.approx(mesh.volume, rel=1e-5)


def test_ridged_block_profile(procedural_bundles):
    """Table 1: the 65,536-triangle block bakes to at most 16 coarse triangles, and the
    heights read back through the atlas along a line across the ridges are the
    analytic ridge profile to within half a texel."""
    path, _, _ = procedural_bundles("ridged_block")
    b = read_bundle(path)
    assert len(b.coarse_faces) <= 16
    texel = b.manifest["atlas"]["texel_size"]
    coarse = trimesh.Trimesh(b.coarse_vertices, b.coarse_faces, process=False)
    # A line across the ridges (along y) through the middle of the top, every 0.1 mm,
    # up to 1 mm (two ridge amplitudes) from the side walls, where a top point could
    # fairly map to the rounded-over edge; found on the coarse surface by vertical rays.
    lx, ly, _ = P.BLOCK_SIZE
    ys = np.arange(1e-3, ly - 1e-3 + 1e-9, 0.1e-3)
    origins = np.column_stack([np.full(len(ys), lx / 2), ys, np.full(len(ys), 0.1)])
    locs, ray_idx, tri = coarse.ray.intersects_location(
        origins, np.tile([0.0, 0.0, -1.0], (len(ys), 1)), multiple_hits=False)
    assert len(ray_idx) == len(ys)
    order = np.argsort(ray_idx)
    locs, tri = locs[order], tri[order]
    bary = trimesh.triangles.points_to_barycentric(coarse.triangles[tri], locs)
    uv = np.einsum("nk,nkd->nd", bary, np.asarray(b.coarse_uvs, dtype=np.float64)[tri])
    p = atlas_lookup(b.atlas, uv)[:, :3]
    # Every point read back lies on the analytic ridge surface ...
    err = p[:, 2] - P.ridged_block_height(p[:, 1])
    worst = int(np.argmax(np.abs(err)))
    bound = PROCEDURAL_P95_TEXELS * texel
    assert np.max(np.abs(err)) < bound, (
        f"{np.sum(np.abs(err) >= bound)} of {len(ys)} points off the ridge profile by more "
        f"than {bound * 1e6:.1f} um; worst: line y = {ys[worst] * 1e3:.1f} mm reads back "
        f"{np.round(p[worst] * 1e3, 3).tolist()} mm, {err[worst] * 1e6:.1f} um off")
    # ... on the top face (not a wall), and the line rises over the 11 crests it
    # fully crosses with their full height: the profile is reproduced, not a point.
    assert np.all(np.abs(p[:, 0] - lx / 2) < 5e-3)
    assert np.ptp(p[:, 2]) > 2 * P.BLOCK_AMPLITUDE - PROCEDURAL_P95_TEXELS * texel
    z = p[np.argsort(p[:, 1]), 2]
    crest = P.BLOCK_SIZE[2] + 0.9 * P.BLOCK_AMPLITUDE
    crossings = np.sum((z[1:] > crest) & (z[:-1] <= crest))
    assert crossings >= 11
    # The read-back points advance along the line (no fold-back in the mapping).
    assert np.all(np.diff(p[:, 1]) > 0)


# --------------------------------------------------------------------------
# The shared models (real scans and CAD parts, read-only at ../shared/models)
# --------------------------------------------------------------------------

#: Bound on the p95 reconstruction error of the shared models, both directions,
#: in texel sizes, set after measuring (default settings: 600 coarse triangles,
#: 1024x1024 atlas; hbake bench, 2026-11-22):
#:
#:   model                 texel mm  median edge  5% edge   p95 c->f  p95 f->c
#:   stanford_bunny.obj     0.306     4.8 tx      3.3 tx    0.027     0.028
#:   armadillo.obj          1.691     3.8 tx      2.1 tx    0.051     0.064
#:   fandisk.obj            0.099    10.2 tx      7.5 tx    0.001     0.001
#:   rocker_arm.obj         1.475     6.7 tx      3.2 tx    0.023     0.022
#:   hammer_scan.obj        0.187     4.2 tx      1.8 tx    0.014     0.014
#:   mountain_terrain.obj   0.538     4.8 tx      3.9 tx    0.025     0.024
#:   planetary_gears.stl    0.169     7.5 tx      2.3 tx    0.066     0.142
#:     (SHARED_BAKES: 1200 faces; at the default 600: 0.096 / 0.733)
#:
#: Why 0.25 texel: the worry was that scans carry relief finer than a texel.
#: Measured, they do not: 95 % of the edges of every shared mesh are longer
#: than about two texels (1.8 on the hammer scan), so their relief is within
#: what the atlas represents (Sec. 7.2), and the only error left is the bilinear interpolation across the
#: creases of a piecewise-linear surface, a small fraction of a texel (worst
#: p95 measured: 0.14, the gears' full->coarse; the others 0.07 or less). A quarter
#: texel is half the procedural bound, leaves a margin of 1.8x over the worst
#: measurement, and still fails a bake that is off by a quarter texel on 5 % of the
#: surface. (The maxima are larger, up to 16 texels on the armadillo's and the
#: bunny's thin parts and holes; p95 is the statistic the issue asks for.)
SHARED_P95_TEXELS = 0.25


@pytest.fixture(scope="module")
def shared_bundles(tmp_path_factory):
    root = tmp_path_factory.mktemp("shared")
    cache = {}

    def get(name):
        src = SHARED_DIR / name
        if not src.is_file():
            # With CI=true a missing ../shared is a failure, not a skip.
            (pytest.fail if os.environ.get("CI") else pytest.skip)(
                f"shared model {name} not found in {SHARED_DIR} "
                f"(the read-only third-party meshes live at ../shared/models)")
        if name not in cache:
            out = root / (Path(name).stem + ".hbundle")
            cache[name] = (out, _bake(src, out, {"load.units": SHARED_MODELS[name],
                                                 **SHARED_BAKES.get(name, {})}))
        return cache[name]

    return get


@pytest.mark.parametrize("name", _params(SHARED_MODELS, KNOWN_SHARED))
def test_bake_shared(name, shared_bundles):
    path, report = shared_bundles(name)
    assert validate_bundle(path) == []
    b = read_bundle(path)
    m = b.manifest
    texel = m["atlas"]["texel_size"]
    rec = m["quality"]["reconstruction"]
    c2f, f2c = rec["coarse_to_full"]["p95"] / texel, rec["full_to_coarse"]["p95"] / texel
    assert c2f < SHARED_P95_TEXELS and f2c < SHARED_P95_TEXELS, (
        f"{name}: p95 coarse->full {c2f:.3f}, full->coarse {f2c:.3f} texels "
        f"(texel {texel:.3g} m, coarse {m['coarse']['triangles']} triangles)")
    # The manifest's coarse->full figure agrees with an independent measurement.
    full = trimesh.load(SHARED_DIR / name, force="mesh", process=False)
    full.apply_scale({"mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254}[SHARED_MODELS[name]])
    d = _independent_c2f(b, full)
    assert np.percentile(d, 95) < SHARED_P95_TEXELS * texel
    # What the shared README says about the files, as the manifest records it.
    open_meshes = {"stanford_bunny.obj", "mountain_terrain.obj"}
    assert m["source"]["closed"] == (name not in open_meshes)
    if name in open_meshes:       # documented fallback, with a warning
        assert m["mass"]["basis"] != "full" and any("not closed" in w for w in m["warnings"])
    else:
        assert m["mass"]["basis"] == "full"
    if name == "planetary_gears.stl":
        assert m["source"]["bodies"] == 7


# --------------------------------------------------------------------------
# Outliers: every reconstructed point a lookup can read is on the surface
# --------------------------------------------------------------------------

#: Two 4-neighbour texels farther apart than this many texel sizes are a discontinuity
#: (docs/bundle-format.md, "Discontinuities"): no lookup interpolates across them.
RULE_TEXELS = 4.0
#: Bound on the off-surface distance (closest point on the full mesh) of every covered
#: texel's value and of the midpoint of every uncut edge to a 4-neighbour, in texel sizes.
#: Why 1 texel: texel values are ray hits or closest
#: points, on the surface up to float32 rounding; a chord between neighbours on the
#: surface strays from it by its sag, a small fraction of a texel where the relief is
#: resolved (wavelengths of two texels and more, Sec. 7.2), and by up to half its length
#: (2 texels under the rule) only where it spans a jump: a thin part, a gap between two
#: bodies, a wall switch of the rays. One texel is what the runtime's grid resolves, so a
#: point farther off is an outlier that a window's maximum (delta) would feel.
OUTLIER_TEXELS = 1.0
#: Open borders are left out: items (texel values, midpoints) within this many texel sizes
#: of a boundary edge of the full mesh. Why 2 (half the rule's length): past an open border
#: the rays find no surface and the texels take the closest point, on the border curve,
#: which neighbours reach at points up to the rule's length apart; the midpoint of such an
#: uncut edge lies within half of it, 2 texels, of the border, and nothing farther is
#: left out.
OPEN_BORDER_MARGIN_TEXELS = 2.0


def _boundary_samples(vertices: np.ndarray, faces: np.ndarray, spacing: float) -> np.ndarray:
    """Points every ``spacing`` (or closer) along the boundary edges (edges of one face)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    b = u[c == 1]
    if len(b) == 0:
        return np.zeros((0, 3))
    a, d = vertices[b[:, 0]], vertices[b[:, 1]]
    k = np.maximum(1, np.ceil(np.linalg.norm(d - a, axis=1) / spacing)).astype(np.int64)
    owner = np.repeat(np.arange(len(b)), k + 1)
    t = np.concatenate([np.arange(n + 1) / n for n in k])
    return a[owner] + t[:, None] * (d[owner] - a[owner])


def reconstruction_offsets(bundle, full_vertices, full_faces):
    """Off-surface distances (m) of what a lookup can read, per item: every covered
    texel's value, and the midpoint of every edge from a covered texel to a 4-neighbour
    (all baked: a 4-neighbour of a covered texel lies within a texel of its UV triangle)
    that the rule does not cut. Returns (points, distances, description of each item).

    Distances are exact closest-point distances (hbake.stages.geometry.closest_points) for the
    texels; a midpoint is within d(p) + |p - q| / 2 of the surface (triangle inequality),
    so only the midpoints where that bound passes OUTLIER_TEXELS are queried; the others
    carry the bound, which is below the test's limit."""
    from hbake.stages.geometry import closest_points

    tx = bundle.manifest["atlas"]["texel_size"]
    img = bundle.atlas.astype(np.float64)
    P, cov = img[..., :3], img[..., 3] == 1
    H, W = cov.shape
    ys, xs = np.nonzero(cov)
    d_tex = closest_points(full_vertices, full_faces, P[ys, xs])[1]
    dist = np.full((H, W), np.nan)
    dist[ys, xs] = d_tex
    pts, ds, what = [P[ys, xs]], [d_tex], [np.stack([ys, xs, ys, xs], axis=1)]
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        y2, x2 = ys + dy, xs + dx
        ok = (y2 >= 0) & (y2 < H) & (x2 >= 0) & (x2 < W)
        if (dy, dx) in ((0, -1), (-1, 0)):                 # covered pairs once
            ok[ok] &= ~cov[y2[ok], x2[ok]]
        y1, x1, y2, x2 = ys[ok], xs[ok], y2[ok], x2[ok]
        length = np.linalg.norm(P[y1, x1] - P[y2, x2], axis=1)
        keep = length <= RULE_TEXELS * tx
        y1, x1, y2, x2, length = y1[keep], x1[keep], y2[keep], x2[keep], length[keep]
        mid = 0.5 * (P[y1, x1] + P[y2, x2])
        d = dist[y1, x1] + 0.5 * length
        query = np.nonzero(d > OUTLIER_TEXELS * tx)[0]
        if len(query):
            d[query] = closest_points(full_vertices, full_faces, mid[query])[1]
        pts.append(mid)
        ds.append(d)
        what.append(np.stack([y1, x1, y2, x2], axis=1))
    return np.concatenate(pts), np.concatenate(ds), np.concatenate(what)


@pytest.mark.parametrize("name", _params(SHARED_MODELS, KNOWN_SHARED))
def test_atlas_outliers(name, shared_bundles):
    """Outliers: the off-surface distance of every covered texel's value and of
    every uncut edge midpoint (what a runtime lookup that follows the discontinuity rule
    can read) is at most OUTLIER_TEXELS, away from open borders (OPEN_BORDER_MARGIN_TEXELS).
    Reuses the bakes of test_bake_shared; the manifest records the bake's repair."""
    from scipy.spatial import cKDTree

    from hbake.stages.load import load_mesh
    from hbake.settings import LoadSettings

    path, _ = shared_bundles(name)
    b = read_bundle(path)
    m = b.manifest
    tx = m["atlas"]["texel_size"]
    full = load_mesh(SHARED_DIR / name, LoadSettings(units=SHARED_MODELS[name]))
    pts, d, what = reconstruction_offsets(b, full.vertices, full.faces)
    border = _boundary_samples(full.vertices, full.faces, 0.25 * tx)
    if len(border):
        # sampled every quarter texel: a distance read off the samples exceeds the true one
        # by at most an eighth of a texel, so no point nearer than the margin is missed
        near = cKDTree(border).query(pts, distance_upper_bound=OPEN_BORDER_MARGIN_TEXELS * tx)[0]
        judged = ~np.isfinite(near) | (near > OPEN_BORDER_MARGIN_TEXELS * tx)
    else:
        judged = np.ones(len(pts), dtype=bool)
    assert judged.mean() > 0.9, f"{name}: the open-border margin leaves out {1 - judged.mean():.1%}"
    off = d[judged] / tx
    worst = int(np.argmax(off))
    w = what[judged][worst]
    bad = int(np.sum(off > OUTLIER_TEXELS))
    assert bad == 0, (
        f"{name}: {bad} of {len(off)} reconstructed points lie more than {OUTLIER_TEXELS} texel "
        f"off the full surface; worst {off[worst]:.3f} texel ({off[worst] * tx * 1e6:.1f} um) at "
        f"texel (row {w[0]}, col {w[1]}) -> (row {w[2]}, col {w[3]}), "
        f"{np.round(pts[judged][worst] * 1e3, 3).tolist()} mm")
    # The bake says what it did (format 1.1's fields; bundles are written as 1.3).
    assert m["format_version"] == "1.3"
    disc = m["atlas"]["discontinuities"]
    assert disc["rule_texels"] == RULE_TEXELS
    assert disc["off_after"] <= disc["off_before"]
    rec = m["quality"]["reconstruction"]["coarse_to_full_uncut"]
    assert rec["samples"] + rec["cut_samples"] == m["quality"]["reconstruction"]["coarse_to_full"]["samples"]
    assert rec["max"] <= m["quality"]["reconstruction"]["coarse_to_full"]["max"]
