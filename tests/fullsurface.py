"""Full-surface depth harness.

The real chain: meshes (procedural, or ../shared/models decimated and scaled) are baked
with ``hbake.routes.pipeline.bake``; ``hrt query --json`` runs at given poses and
resolutions; and for every contact patch the truth is cast on the two FULL-resolution
meshes (the meshes given to the bake) through the very texel centres of the patch
window, along the patch's n:

* ``h_A`` = the highest crossing (largest ``n . p``) of A's full mesh on the column,
  ``h_B`` = the lowest crossing of B's; ``delta_truth`` = max over the columns crossing
  both of ``h_A - h_B`` (the directional penetration depth of the two full meshes along
  n, sampled where the runtime samples).

Keep rule (decided from ray counts on the full meshes before anything is compared;
:func:`evaluate_patch`):
  a patch whose truth along n exceeds WRONG_WAY_DEPTH (5 mm: n goes through the
  bodies) is *wrong-way*: not compared, subject to the safety checks. Otherwise the
  columns that matter are those crossing both with ``h_A - h_B >= delta_truth - NEAR``
  (NEAR = 0.5 mm). On each of them A may have at most one crossing where the column
  LEAVES A (going along +n: outward normal . n > 0) at a height ``>= h_B - NEAR``, and
  B at most one where it ENTERS B (outward normal . n < 0) at ``<= h_A + NEAR``;
  crossings of faces steeper than STEEP (84 degrees from n, walls seen edge-on) are no
  layer. (The runtime's height fields are A's faces facing +n and B's facing -n, so
  back faces are no layer of either: a thin plate seen face-on is one layer.) A patch
  is kept when every column that matters is single. Patches with no column covered by
  both in hrt nor in the truth are *empty* (nothing to compare). Of the rest, at most
  ``MAX_LEFT_OUT`` may be left out; the fraction is reported.

The bound of a kept patch (:func:`patch_bound`), from the full meshes only, before
comparing:
  ``sum over X of ((t_X / 2) ds_X sqrt(1 + s_X^2) + e_X s_X) + ABS_TOL``
  t_X = X's ``atlas.texel_size``; s_X = the largest slope of X's full surface along n
  (|grad h| = tan of the angle between the hit triangle's normal and n) over the
  window's columns that matter (less rim columns, below); ds_X = the largest
  change of that gradient (vector difference) between a column and the columns
  offset by one atlas texel t_X along u, v, u+v and u-v (neighbouring atlas texels;
  an offset of t_X in the plane is at least one texel on the surface); e_X =
  ``LATERAL_TOLERANCE * min(window cell, t_X)``, the lateral tolerance of the
  runtime's per-texel correction (its author's stated figure). The first term is the
  bilinear interpolation error of the atlas between texels whose slopes differ by
  ds_X (heights along n: times sqrt(1 + s^2)); the second a lateral miss of e_X on a
  slope s_X.

Nothing here reads the error being measured to size a bound.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from hbake.lab import procedural as P

REPO = Path(__file__).resolve().parents[1]
# $HBAKE_MODELS, else ../shared/models beside the repository (hbake.lab.bench.shared_models_dir).
SHARED_MODELS = Path(os.environ["HBAKE_MODELS"]) if os.environ.get("HBAKE_MODELS") else REPO.parent / "shared" / "models"

RESOLUTIONS = (50, 128)
#: e = LATERAL_TOLERANCE * min(window cell, atlas texel): the tolerance to which the
#: corrected runtime places f(q) on the texel's column (the runtime engineer's figure).
LATERAL_TOLERANCE = 0.05
#: float32 heights of ~0.05 m carry ~4e-9 m of rounding; the runtime interpolates in
#: float32: 1e-7 m (0.001-0.003 texel here) covers it, as in test_bruteforce_depth.
ABS_TOL = 1e-7
#: On smooth relief (the gratings, the sphere) the bound is at most 0.25 texel.
SMOOTH_BOUND_TEXELS = 0.25
#: At most 10 % of the patches may be left out by the keep rule.
MAX_LEFT_OUT = 0.10
#: Columns that matter: those whose full surfaces are within NEAR of the deepest
#: column's overlap (h_A - h_B >= delta_truth - NEAR); layers are counted within NEAR
#: of the other surface. 0.5 mm exceeds every scene's press depth (0.2 mm) plus its
#: relief's peak to peak (0.4 mm at most): a column farther apart cannot hold delta.
NEAR = 0.5e-3
#: A patch whose truth along n is deeper than this is a wrong-way patch (every scene
#: here is pressed at most 0.2 mm plus its relief, well under 2 mm, so a right-way n
#: sees at most that; a wrong-way n sees through the bodies, centimetres).
WRONG_WAY_DEPTH = 5e-3
#: Crossings closer than this along a column are one crossing (a ray through a shared
#: edge); the next ray starts this far past the previous hit.
RAY_STEP = 1e-7
MAX_CROSSINGS = 48
MERGE_DIST = 1e-6
#: Steeper than this (84 degrees from n), a crossing is a wall seen edge-on: the end of
#: a height field, not its slope (see rim columns in evaluate_patch).
STEEP = 10.0

MM = 1e-3
IDENTITY = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]

# ----------------------------------------------------------------------------
# Meshes
# ----------------------------------------------------------------------------

# (a) Angled grating: ridges at 23 degrees, 5.3 wavelengths across, which 600 coarse
# faces follow only in part (asserted); slope A k = 0.42; cells fine enough that the
# mesh's own slope jumps between cells (A k^2 h sqrt 2 = 0.15) keep the bound under
# 0.25 texel on smooth relief.
GRATING_ANGLE = 23.0                 # degrees: not a multiple of 45
GRATING_L = 3 * MM                   # wavelength
GRATING_A = 0.2 * MM                 # amplitude (0.4 mm peak to peak)
GRATING_SIDE = 16 * MM
GRATING_THICK = 4 * MM               # mean top height
GRATING_CELLS = 134                  # 0.119 mm cells: 72,896 triangles

# (b), (c) Textured plate: a gentler grating (slope 0.16), 40 mm so that the sphere and
# the models (25 mm diagonal, centred over it) stay away from its rim.
PLATE_L = 6 * MM
PLATE_A = 0.15 * MM
PLATE_SIDE = 40 * MM
PLATE_THICK = 6 * MM
PLATE_CELLS = 150                    # 0.267 mm cells: 91,200 triangles

SPHERE_R = 8 * MM
SPHERE_BUMP_A = 0.1 * MM
SPHERE_BUMP_L = 4 * MM
SPHERE_SUBDIV = 5                    # 20,480 triangles, edges ~0.26 mm

BOX_SIZE = (60 * MM, 60 * MM, 10 * MM)

MODEL_DIAGONAL = 25 * MM             # shared models scaled to this bbox diagonal
MODEL_FACES = 30_000                 # decimated to at most this many triangles
#: Three shared models with thin parts: the rocker arm (its arm and bosses), the fandisk
#: (thin fins, creases), the Stanford bunny (a scan: ears). The armadillo and the hammer
#: scan were dropped: their folds (ears, fingers; the scan's handle) cross a column twice,
#: so 22 % (armadillo) and 6 of 24 (hammer, at N = 128) of their patches were left out by
#: the keep rule, which is allowed for at most 10 % of a group.
SHARED = ("rocker_arm.obj", "fandisk.obj", "stanford_bunny.obj")


def grating_height(x, y, L=None, A=None, H=None):
    L = GRATING_L if L is None else L
    A = GRATING_A if A is None else A
    H = GRATING_THICK if H is None else H
    a = math.radians(GRATING_ANGLE)
    s = np.asarray(x) * math.cos(a) + np.asarray(y) * math.sin(a)
    return H + A * np.sin(2 * np.pi * s / L)


def _grating_block(side, cells, L, A, H) -> trimesh.Trimesh:
    xs = np.linspace(0.0, side, cells + 1)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    mesh = P._heightfield_block(xs, xs, grating_height(X, Y, L, A, H), np.zeros_like(X))
    return P._finish(mesh)


def make_grating() -> trimesh.Trimesh:
    return _grating_block(GRATING_SIDE, GRATING_CELLS, GRATING_L, GRATING_A, GRATING_THICK)


def make_plate() -> trimesh.Trimesh:
    return _grating_block(PLATE_SIDE, PLATE_CELLS, PLATE_L, PLATE_A, PLATE_THICK)


def make_sphere() -> trimesh.Trimesh:
    """Sphere of radius 8 mm with smooth bumps: r = R + a cos(kx) cos(ky) cos(kz)."""
    ico = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIV, radius=1.0)
    d = np.asarray(ico.vertices)
    k = 2 * np.pi / SPHERE_BUMP_L
    p = SPHERE_R * d
    r = SPHERE_R + SPHERE_BUMP_A * np.cos(k * p[:, 0]) * np.cos(k * p[:, 1] + 0.7) * np.cos(k * p[:, 2] + 1.3)
    mesh = trimesh.Trimesh(d * r[:, None], np.asarray(ico.faces), process=False)
    return P._finish(mesh)


def make_box() -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=BOX_SIZE)
    b.apply_translation(np.array(BOX_SIZE) / 2)
    return P._finish(trimesh.Trimesh(b.vertices, b.faces, process=False))


def make_shared(name: str) -> trimesh.Trimesh:
    """A shared model, read in place, decimated (topology kept) and scaled to 25 mm."""
    src = SHARED_MODELS / name
    mesh = trimesh.load(src, force="mesh", process=True)
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    if len(f) > MODEL_FACES:
        import pymeshlab
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(v, f))
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=MODEL_FACES, preservetopology=True,
                                                    preservenormal=True, qualitythr=0.5)
        m = ms.current_mesh()
        v, f = m.vertex_matrix(), m.face_matrix()
    lo, hi = v.min(0), v.max(0)
    v = (v - 0.5 * (lo + hi)) * (MODEL_DIAGONAL / np.linalg.norm(hi - lo))
    out = trimesh.Trimesh(v, f, process=True)
    out.remove_unreferenced_vertices()
    if out.volume < 0:
        out.invert()
    return out


MESHES = {
    "grating": make_grating,
    "plate": make_plate,
    "sphere": make_sphere,
    "box": make_box,
    **{Path(n).stem: (lambda n=n: make_shared(n)) for n in SHARED},
}

BAKE_OVERRIDES = {"load.units": "m", "quality.samples": 20000}

# ----------------------------------------------------------------------------
# Bakes (cached: per session, or in $FULLSURFACE_CACHE across sessions)
# ----------------------------------------------------------------------------


#: The hbake sources that bake (default: this checkout's). FULLSURFACE_HBAKE_SRC=DIR
#: (a directory holding an `hbake` package, e.g. `git archive HEAD hbake | tar -x -C DIR`)
#: bakes with another baker, to measure the runtime alone while hbake is being changed.
HBAKE_SRC = Path(os.environ.get("FULLSURFACE_HBAKE_SRC") or REPO)


def _hbake_source_hash() -> str:
    h = hashlib.sha256()
    for p in sorted((HBAKE_SRC / "hbake").rglob("*.py")):
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


@dataclass
class Model:
    name: str
    mesh: trimesh.Trimesh
    bundle: Path
    manifest: dict
    coarse_vertices: np.ndarray
    coarse_faces: np.ndarray
    bake_s: float
    rays: "FullMeshRays" = None

    @property
    def texel(self) -> float:
        return float(self.manifest["atlas"]["texel_size"])

    @property
    def displacement(self) -> float:
        q = self.manifest["quality"]
        return float(q["displacement_outward"]) + float(q["displacement_inward"])


def bake_model(name: str, root: Path, make=None) -> Model:
    """Bake MESHES[name] (or ``make()``) with the `hbake bake` command (a child process: a
    native crash is a failed bake, not a dead pytest), or reuse the bundle of the same key."""
    from hbake.bundle import read_bundle

    mesh = (make or MESHES[name])()
    data = mesh.export(file_type="ply")
    key = hashlib.sha256(data + json.dumps(BAKE_OVERRIDES, sort_keys=True).encode()
                         + _hbake_source_hash().encode()).hexdigest()[:12]
    root.mkdir(parents=True, exist_ok=True)
    bundle = root / f"{name}-{key}.hbundle"
    t0 = time.perf_counter()
    if not (bundle / "manifest.json").is_file():
        src = root / f"{name}-{key}.ply"
        src.write_bytes(data)
        cmd = [str(REPO / ".venv" / "bin" / "python"), "-c", "import sys; from hbake.cli import main; "
               "sys.argv[0] = 'hbake'; main()", "bake", str(src), "-o", str(bundle), "-f", "-q"]
        for k, v in BAKE_OVERRIDES.items():
            cmd += ["--set", f"{k}={json.dumps(v)}"]
        env = dict(os.environ, PYTHONPATH=str(HBAKE_SRC))
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)
        if res.returncode != 0:
            raise AssertionError(f"{' '.join(cmd)}: exit {res.returncode}: {res.stderr[-2000:]}")
        src.unlink()
    bake_s = time.perf_counter() - t0
    b = read_bundle(bundle, verify=False)
    # The full mesh is the bake's input as written (float64 PLY, nothing to repair).
    return Model(name, mesh, bundle, b.manifest, np.asarray(b.coarse_vertices, float),
                 np.asarray(b.coarse_faces, np.int64), bake_s, FullMeshRays(mesh))


# ----------------------------------------------------------------------------
# Rays on the full meshes
# ----------------------------------------------------------------------------


class FullMeshRays:
    """All crossings of lines with one full-resolution mesh (embree, object frame).

    Embree traces in float32 around the mesh centre; every hit's distance is recomputed
    in float64 on the hit triangle's plane, and the next ray starts RAY_STEP past it."""

    def __init__(self, mesh: trimesh.Trimesh):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        v = np.asarray(mesh.vertices, float)
        f = np.asarray(mesh.faces, np.int64)
        self.centre = 0.5 * (v.min(0) + v.max(0))
        self.diag = float(np.linalg.norm(v.max(0) - v.min(0)))
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self.scene, vertices=(v - self.centre).astype(np.float32),
                     indices=f.astype(np.int32))
        tri = v[f]
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.normal = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
        self.anchor = tri[:, 0]

    def crossings(self, points, direction):
        """Crossings of the lines ``points + s direction`` (object frame, unit direction).

        Returns (s, prim): (K, M) arrays, s the signed distance from ``points`` along
        ``direction`` (NaN past the last crossing), prim the triangle (-1)."""
        d = np.asarray(direction, float)
        K = len(points)
        back = np.abs((points - self.centre) @ d) + self.diag
        start = points - back[:, None] * d
        S = np.full((K, MAX_CROSSINGS), np.nan)
        PR = np.full((K, MAX_CROSSINGS), -1, np.int64)
        cur = start.copy()
        last = np.full(K, -np.inf)
        active = np.arange(K)
        dirs32 = d.astype(np.float32)
        for k in range(MAX_CROSSINGS):
            if not len(active):
                break
            org = np.ascontiguousarray((cur[active] - self.centre).astype(np.float32))
            dirs = np.ascontiguousarray(np.broadcast_to(dirs32, org.shape))
            res = self.scene.run(org, dirs, output=1)
            prim = np.asarray(res["primID"], np.int64)
            hit = prim >= 0
            active, prim = active[hit], prim[hit]
            nrm = self.normal[prim]
            t = np.einsum("kd,kd->k", nrm, self.anchor[prim] - start[active]) / (nrm @ d)
            # float32 tracing can report the triangle just left: keep only progress.
            t = np.maximum(t, last[active] + RAY_STEP)
            S[active, k] = t - back[active]
            PR[active, k] = prim
            last[active] = t
            cur[active] = start[active] + (t + RAY_STEP)[:, None] * d
        if len(active):
            raise AssertionError(f"a column crosses the mesh more than {MAX_CROSSINGS} times")
        used = int(np.max(np.sum(PR >= 0, axis=1))) if K else 0
        S, PR = S[:, :max(used, 1)], PR[:, :max(used, 1)]
        # Crossings within MERGE_DIST of the previous one are one point of the surface:
        # the same side (a line through a shared edge): one crossing; opposite sides (a
        # line touching an edge): none.
        sign = np.where(PR >= 0, np.sign(self.normal[np.maximum(PR, 0)] @ d), 0)
        prev_s = S[:, 0].copy()
        prev_k = np.where(PR[:, 0] >= 0, 0, -1)
        rows = np.arange(K)
        for k in range(1, S.shape[1]):
            ok = PR[:, k] >= 0
            close = ok & (prev_k >= 0) & (S[:, k] - prev_s < MERGE_DIST)
            same = close & (sign[rows, np.maximum(prev_k, 0)] == sign[:, k])
            opp = close & ~same
            PR[same, k] = -1
            S[same, k] = np.nan
            kk = prev_k[opp]
            PR[opp, kk] = -1
            S[opp, kk] = np.nan
            PR[opp, k] = -1
            S[opp, k] = np.nan
            keep = ok & ~close
            prev_s = np.where(keep, S[:, k], np.where(opp, -np.inf, prev_s))
            prev_k = np.where(keep, k, np.where(opp, -1, prev_k))
        return S, PR


def _pose(pose):
    return Rotation.from_quat(pose[3:]).as_matrix(), np.asarray(pose[:3], float)


@dataclass
class Column:
    """The crossing of one surface on each column that the depth uses, and its layers."""
    h: np.ndarray          # height n . p of the extreme crossing (A: highest, B: lowest); NaN: none
    grad: np.ndarray       # (K, 2) dh/du, dh/dv of the surface there
    layers: np.ndarray     # number of front-facing crossings inside the slab


def surface_columns(model: Model, pose, X, n, u, v, probe: bool, ref=None) -> Column:
    """Heights along n of ``model`` posed at ``pose`` on the world columns through X."""
    R, t = _pose(pose)
    n_o = R.T @ n
    P0 = (X - t) @ R  # object frame
    S, PR = model.rays.crossings(P0, n_o)
    h0 = P0 @ n_o + t @ n  # n . p of the column points (world heights)
    H = h0[:, None] + S
    ok = np.isfinite(H)
    Nw = model.rays.normal[np.where(ok, PR, 0)] @ R.T       # world normals (K, M, 3)
    facing = Nw @ n
    # Layers: crossings no steeper than STEEP (a wall seen edge-on is the end of a
    # height field, not a layer of it; see the rim columns in evaluate_patch).
    flat = np.abs(facing) >= 1 / math.sqrt(1 + STEEP * STEEP)
    ref = np.full(len(X), np.nan) if ref is None else np.asarray(ref, float)
    if probe:
        front = ok & flat & (facing > 0) & (H >= ref[:, None] - NEAR)
        Hx = np.where(ok, H, -np.inf)
        k = np.argmax(Hx, axis=1)
    else:
        front = ok & flat & (facing < 0) & (H <= ref[:, None] + NEAR)
        Hx = np.where(ok, H, np.inf)
        k = np.argmin(Hx, axis=1)
    rows = np.arange(len(X))
    h = Hx[rows, k]
    h = np.where(np.isfinite(h), h, np.nan)
    N = Nw[rows, k]
    nn = N @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        grad = -np.stack([N @ u, N @ v], 1) / nn[:, None]
    return Column(h, grad, front.sum(1))


# ----------------------------------------------------------------------------
# hrt query
# ----------------------------------------------------------------------------


def hrt_query(hrt: str, a: Model, b: Model, pose_a, pose_b, N: int, heights: str | None = None,
              threads: int | None = None) -> dict:
    cmd = [hrt, "query", str(a.bundle), str(b.bundle), "--pose-a", *map(repr, map(float, pose_a)),
           "--pose-b", *map(repr, map(float, pose_b)), "--resolution", str(N), "--json"]
    if heights:
        cmd += ["--heights", heights]
    if threads is not None:
        cmd += ["--threads", str(threads)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, f"{' '.join(cmd)}: exit {res.returncode}: {res.stderr}"
    return json.loads(res.stdout)


def window_columns(c):
    n, u, v = (np.asarray(c[k], float) for k in ("n", "u", "v"))
    w = c["window"]
    origin, cell, N = np.asarray(w["origin"], float), float(w["cell"]), int(w["resolution"])
    i = (np.arange(N) + 0.5) * cell
    a, bb = (g.ravel() for g in np.meshgrid(i, i, indexing="xy"))
    return origin + a[:, None] * u + bb[:, None] * v, n, u, v, cell


# ----------------------------------------------------------------------------
# One patch
# ----------------------------------------------------------------------------


@dataclass
class PatchResult:
    scene: str
    N: int
    patch: int
    kept: bool
    reason: str = ""
    delta_rt: float = math.nan
    delta_truth: float = math.nan
    bound: float = math.nan
    texel: float = math.nan           # the larger atlas texel of A and B
    slope: tuple = ()
    dslope: tuple = ()
    cell: float = math.nan
    n: tuple = ()
    covered: bool = False
    rim_columns: tuple = (0, 0)       # rim columns of A, B left out of s and ds
    slab_columns: int = 0             # columns that matter (within NEAR of the deepest)
    wrong_way: bool = False           # the truth along n goes through the bodies
    empty: bool = False               # no column covered by both, in hrt nor in the truth
    problem: str = ""                 # set when the runtime has no depth where the truth has one
    safety: dict = field(default_factory=dict)

    @property
    def err(self) -> float:
        return self.delta_rt - self.delta_truth

    @property
    def err_texels(self) -> float:
        return self.err / self.texel

    @property
    def bound_texels(self) -> float:
        return self.bound / self.texel

    @property
    def within(self) -> bool:
        return (not self.problem) and abs(self.err) <= self.bound

    def line(self) -> str:
        if not self.kept:
            return (f"{self.scene} N={self.N} patch {self.patch}: "
                    f"{'wrong way' if self.wrong_way else 'left out'} ({self.reason}; "
                    f"hrt {self.delta_rt * 1e3:+.4f} mm, n {np.round(self.n, 3).tolist()})")
        return (f"{self.scene} N={self.N} patch {self.patch}: hrt {self.delta_rt * 1e3:+.4f} mm, "
                f"full meshes {self.delta_truth * 1e3:+.4f} mm, error {self.err_texels:+.3f} texel, "
                f"bound {self.bound_texels:.3f} texel (s {self.slope[0]:.2f}/{self.slope[1]:.2f}, "
                f"ds {self.dslope[0]:.3f}/{self.dslope[1]:.3f}, rim {self.rim_columns[0]}/{self.rim_columns[1]} "
                f"of {self.slab_columns}, cell {self.cell / self.texel:.1f} texel, "
                f"n {np.round(self.n, 3).tolist()})" + (f" [{self.problem}]" if self.problem else ""))


def patch_bound(cell, models, slopes, dslopes) -> float:
    """The issue's bound: sum over X of (t/2) ds sqrt(1+s^2) + e s, plus ABS_TOL."""
    total = ABS_TOL
    for m, s, ds in zip(models, slopes, dslopes):
        t = m.texel
        e = LATERAL_TOLERANCE * min(cell, t)
        total += 0.5 * t * ds * math.sqrt(1 + s * s) + e * s
    return total


def evaluate_patch(scene: str, N: int, c: dict, a: Model, b: Model, pose_a, pose_b) -> PatchResult:
    X, n, u, v, cell = window_columns(c)
    texel = max(a.texel, b.texel)
    res = PatchResult(scene, N, int(c["id"]), True, texel=texel, cell=cell, n=tuple(n),
                      covered=bool(c["covered"]))
    res.safety = {k: c[k] for k in SAFETY_MEMBERS if k in c}
    res.delta_rt = float(c["delta"])
    ca = surface_columns(a, pose_a, X, n, u, v, True)
    cb = surface_columns(b, pose_b, X, n, u, v, False)
    both = np.isfinite(ca.h) & np.isfinite(cb.h)
    F = np.where(both, ca.h - cb.h, -np.inf)
    k = int(np.argmax(F))
    if both.any():
        res.delta_truth = float(F[k])
    if res.delta_truth > WRONG_WAY_DEPTH:
        # Through the bodies: n is the wrong way. Not a depth to compare; the safety
        # checks (refused, no force) apply.
        res.kept = False
        res.wrong_way = True
        res.reason = f"wrong-way n: the full meshes overlap by {res.delta_truth * 1e3:.2f} mm along it"
        return res
    near = both & (F >= res.delta_truth - NEAR)
    idx = np.nonzero(near)[0]
    # Keep rule: decided from the ray counts alone, on the columns that matter.
    la = surface_columns(a, pose_a, X[idx], n, u, v, True, ref=cb.h[idx]).layers
    lb = surface_columns(b, pose_b, X[idx], n, u, v, False, ref=ca.h[idx]).layers
    multi = int(np.sum((la > 1) | (lb > 1)))
    if multi:
        res.kept = False
        res.reason = f"{multi} of {len(idx)} columns near contact cross a surface more than once"
        return res
    # Slopes and their change between neighbouring atlas texels, per surface, over
    # the columns that matter. Rim columns are left out of s and ds: those where X's
    # crossing, or that of one of its neighbours one atlas texel away (along u, v,
    # u+v, u-v), is missing, steeper than STEEP (a wall seen edge-on), or another
    # layer (a height step over the texel steeper than STEEP): there the height field
    # ends (a plate's edge, a silhouette), which is the coverage's business, not a
    # slope; they are counted.
    slopes, dslopes, rims = [], [], []
    for m, col, pose, probe in ((a, ca, pose_a, True), (b, cb, pose_b, False)):
        g = col.grad[idx]
        gn = np.linalg.norm(g, axis=1)
        rim = ~(gn <= STEEP)
        dmax = np.zeros(len(idx))
        for off in (u, v, (u + v), (u - v)):
            step = m.texel * off
            co = surface_columns(m, pose, X[idx] + step, n, u, v, probe)
            valid = (np.isfinite(co.h) & (np.linalg.norm(co.grad, axis=1) <= STEEP)
                     & (np.abs(co.h - col.h[idx]) <= STEEP * np.linalg.norm(step)))
            rim |= ~valid
            dg = np.linalg.norm(co.grad - g, axis=1)
            dmax = np.where(valid, np.maximum(dmax, dg), dmax)
        inner = ~rim
        slopes.append(float(gn[inner].max()) if inner.any() else 0.0)
        dslopes.append(float(dmax[inner].max()) if inner.any() else 0.0)
        rims.append(int(rim.sum()))
    res.rim_columns = tuple(rims)
    res.slab_columns = len(idx)
    res.slope, res.dslope = tuple(slopes), tuple(dslopes)
    res.bound = patch_bound(cell, (a, b), slopes, dslopes)
    if both.any() and any(r >= len(idx) for r in rims):
        # Every column that matters is a rim column of one surface (steeper than
        # STEEP, or a layer step, along n): that surface has no height field along
        # this n, so s and ds, and with them the bound, are undefined. Left out
        # (counted against MAX_LEFT_OUT), decided from the rays before comparing.
        res.kept = False
        res.reason = f"no height field along n: all {len(idx)} columns near contact are rim columns of a surface"
        return res
    if not both.any():
        res.delta_truth = -math.inf
        if c["covered"]:
            res.problem = "hrt covered, but no column crosses both full meshes (phantom contact)"
        else:
            res.kept = False
            res.empty = True
            res.reason = "neither hrt nor the full meshes have a column covered by both"
    elif not c["covered"]:
        res.problem = "hrt found no texel covered by both; the full meshes have columns crossing both"
    return res


# ----------------------------------------------------------------------------
# Scenes
# ----------------------------------------------------------------------------


@dataclass
class Scene:
    name: str
    group: str            # "gratings", "sphere", "models"
    a: str
    b: str
    pose_a: list
    pose_b: list
    smooth: bool          # smooth relief: the bound must come to at most 0.25 texel
    closed_form: float | None = None   # the gratings' closed-form depth (infinite plates)


def _quat_from_matrix(R):
    return Rotation.from_matrix(R).as_quat().tolist()


def grating_scenes() -> list[Scene]:
    """A = the grating turned face down about the ridge direction (so its ridges stay
    parallel to B's), centred over B, shifted across the ridges by a fraction of the
    wavelength (0: nested), pressed to a closed-form depth of 0.1 mm."""
    a = math.radians(GRATING_ANGLE)
    e = np.array([math.cos(a), math.sin(a), 0.0])      # across the ridges
    d = np.array([-math.sin(a), math.cos(a), 0.0])     # along the ridges
    q = [d[0], d[1], 0.0, 0.0]                         # 180 degrees about d
    R = Rotation.from_quat(q).as_matrix()
    c = np.array([GRATING_SIDE / 2, GRATING_SIDE / 2, GRATING_THICK / 2])
    base = c - R @ c                                   # A's centre over B's
    s_c = float((base @ e))                            # across-ridge shift of A's pattern
    out = []
    for frac in (0.0, 0.1, 0.25, 0.4, 0.5, 0.7):
        s_t = frac * GRATING_L                         # shift from the nested position
        extra = s_t - s_c + GRATING_L * round(s_c / GRATING_L)
        press = 0.1 * MM
        relief = 2 * GRATING_A * abs(math.sin(math.pi * s_t / GRATING_L))
        tz = 2 * GRATING_THICK + relief - press
        t = base + extra * e
        t[2] = tz
        out.append(Scene(f"gratings_offset{frac:.2f}L", "gratings", "grating", "grating",
                         [*t.tolist(), *q], IDENTITY, True, closed_form=press))
    return out


def _rest_on(model_mesh, R, plate: Model, plate_pose, xy, press, rng=None):
    """Translation putting the posed mesh's lowest point `press` below the plate's
    full surface under it, the mesh's bbox centre over ``xy``."""
    v = np.asarray(model_mesh.vertices) @ R.T
    lo, hi = v.min(0), v.max(0)
    shift = np.array([xy[0], xy[1], 0.0]) - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    k = int(np.argmin(v[:, 2]))
    p = v[k] + shift
    col = surface_columns(plate, plate_pose, p[None, :] * [1, 1, 0] + [0, 0, 1.0], np.array([0, 0, -1.0]),
                          np.array([1.0, 0, 0]), np.array([0, -1.0, 0]), False)
    top = -float(col.h[0])  # heights along -z
    shift[2] = top - press - v[k, 2]
    return shift


def thin_tips(mesh: trimesh.Trimesh, count: int, rng) -> list[np.ndarray]:
    """Outward normals at support points of thin parts: vertices extremal along their
    own normal whose thickness (ray inward along -normal) is under 8 % of the diagonal."""
    v = np.asarray(mesh.vertices)
    nv = np.asarray(mesh.vertex_normals)
    diag = float(np.linalg.norm(np.ptp(v, 0)))
    # Support test first (cheap): extremal within 1e-3 diagonal along the normal.
    cand = rng.choice(len(v), size=min(len(v), 4000), replace=False)
    sup = [i for i in cand if v[i] @ nv[i] >= np.max(v @ nv[i]) - 1e-3 * diag]
    if not sup:
        return []
    sup = np.array(sup)
    rays = FullMeshRays(mesh)
    out = []
    for i in sup:
        S, _ = rays.crossings(v[i][None, :] - 1e-6 * nv[i], -nv[i])
        s = S[0][np.isfinite(S[0])]
        s = s[s > 1e-6 * 2]
        if len(s) and s[0] < 0.08 * diag:
            out.append(nv[i])
    rng.shuffle(out)
    return out[:count]


def model_scenes(models: dict[str, Model], names, random_poses=3, thin_poses=1, seed=8) -> list[Scene]:
    out = []
    for name in names:
        m = models[name]
        rng = np.random.default_rng(seed + sum(map(ord, name)))
        tips = thin_tips(m.mesh, thin_poses, rng)
        rots = [(f"rand{i}", Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix())
                for i in range(random_poses)]
        for j, tip in enumerate(tips):
            # Turn the tip's normal to -z, then a seeded spin about z.
            r0, _ = Rotation.align_vectors([[0, 0, -1.0]], [tip])
            spin = Rotation.from_euler("z", float(rng.uniform(0, 2 * np.pi)))
            rots.append((f"thin{j}", (spin * r0).as_matrix()))
        for plate in ("plate", "box"):
            pm = models[plate]
            centre = (PLATE_SIDE / 2,) * 2 if plate == "plate" else (BOX_SIZE[0] / 2, BOX_SIZE[1] / 2)
            for tag, R in rots:
                press = float(rng.uniform(0.1 * MM, 0.2 * MM))
                t = _rest_on(m.mesh, R, pm, IDENTITY, centre, press)
                out.append(Scene(f"{name}_on_{plate}_{tag}", "models", name, plate,
                                 [*t.tolist(), *_quat_from_matrix(R)], IDENTITY, False))
    return out


def sphere_scenes(models: dict[str, Model], count=6, seed=5) -> list[Scene]:
    rng = np.random.default_rng(seed)
    m, pm = models["sphere"], models["plate"]
    out = []
    for i in range(count):
        R = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
        xy = PLATE_SIDE / 2 + rng.uniform(-3 * MM, 3 * MM, 2)
        press = float(rng.uniform(0.1 * MM, 0.2 * MM))
        t = _rest_on(m.mesh, R, pm, IDENTITY, xy, press)
        out.append(Scene(f"sphere_on_plate_{i}", "sphere", "sphere", "plate",
                         [*t.tolist(), *_quat_from_matrix(R)], IDENTITY, True))
    return out


# ----------------------------------------------------------------------------
# Running scenes and summarising
# ----------------------------------------------------------------------------


@dataclass
class SceneRun:
    scene: Scene
    N: int
    query: dict
    patches: list


def run_scene(hrt: str, models: dict[str, Model], sc: Scene, N: int) -> SceneRun:
    a, b = models[sc.a], models[sc.b]
    out = hrt_query(hrt, a, b, sc.pose_a, sc.pose_b, N)
    patches = [evaluate_patch(sc.name, N, c, a, b, sc.pose_a, sc.pose_b) for c in out["contacts"]]
    return SceneRun(sc, N, out, patches)


def refused(p: PatchResult) -> bool:
    return bool(p.safety.get("refused", False))


def summarize(label: str, runs: list[SceneRun]) -> dict:
    """Figures over the runs: candidates are the patches neither wrong-way nor refused."""
    pats = [p for r in runs for p in r.patches]
    wrong = [p for p in pats if p.wrong_way]
    cand = [p for p in pats if not p.wrong_way and not p.empty and not refused(p)]
    kept = [p for p in cand if p.kept]
    ok = [p for p in kept if not p.problem]
    errs = np.array([abs(p.err_texels) for p in ok])
    signed = np.array([p.err_texels for p in ok])
    return {
        "label": label,
        "patches": len(pats),
        "wrong_way": len(wrong),
        "wrong_way_with_force": sum(1 for r in runs for c, p in zip(r.query["contacts"], r.patches)
                                    if p.wrong_way and np.any(np.abs(c["force"]) > 0)),
        "refused": sum(1 for p in pats if refused(p)),
        "empty": sum(1 for p in pats if p.empty),
        "candidates": len(cand),
        "kept": len(kept),
        "kept_fraction": len(kept) / len(cand) if cand else math.nan,
        "problems": len(kept) - len(ok),
        "median_abs_texels": float(np.median(errs)) if len(errs) else math.nan,
        "worst_abs_texels": float(np.max(errs)) if len(errs) else math.nan,
        "worst_signed_texels": float(signed[np.argmax(np.abs(signed))]) if len(signed) else math.nan,
        "worst_abs_mm": float(max(abs(p.err) for p in ok) * 1e3) if ok else math.nan,
        "worst_bound_texels": float(max(p.bound_texels for p in kept)) if kept else math.nan,
        "outside_bound": sum(1 for p in kept if not p.within),
        "over_one_texel": int(np.sum(errs > 1)),
        "underestimates": int(np.sum(signed < 0)),
    }


def format_summary(s: dict) -> str:
    return (f"{s['label']}: {s['patches']} patches ({s['wrong_way']} wrong-way, "
            f"{s['wrong_way_with_force']} of them with force; {s['refused']} refused; {s['empty']} empty), "
            f"kept {s['kept']} of {s['candidates']} ({100 * s['kept_fraction']:.0f} %); error median "
            f"{s['median_abs_texels']:.3f} / worst {s['worst_abs_texels']:.3f} texel "
            f"(signed {s['worst_signed_texels']:+.3f}, {s['worst_abs_mm']:.4f} mm), "
            f"{s['over_one_texel']} over 1 texel, {s['underestimates']} underestimates; worst bound "
            f"{s['worst_bound_texels']:.3f} texel, {s['outside_bound']} outside it "
            f"({s['problems']} coverage problems)")


SAFETY_MEMBERS = ("refused", "clamped", "delta_bound", "delta_force")


def safety_members_missing(runs) -> list[str]:
    return sorted({k for r in runs for c in r.query["contacts"] for k in SAFETY_MEMBERS if k not in c})


def safety_failures(runs) -> list[str]:
    """Patch safety on every patch (needs the members; see safety_members_missing):
    a refused patch gives no force or torque and ``delta_force`` 0; one not refused has
    ``delta_force = min(delta, delta_bound)`` (``delta`` is the raw depth of Eq. 9; 0 when
    uncovered or apart) and is ``clamped`` exactly when ``delta > delta_bound``; a wrong-way
    patch (truth along n deeper than WRONG_WAY_DEPTH) is refused; delta_bound does not
    cut the truth of a kept patch (by more than its bound); the warnings count the
    refused and clamped patches."""
    failures = []
    for r in runs:
        cs = r.query["contacts"]
        for c, p in zip(cs, r.patches):
            tag = f"{r.scene.name} N={r.N} patch {c['id']}"
            if c["refused"]:
                if np.any(np.abs(c["force"]) > 0) or np.any(np.abs(c["torque"]) > 0):
                    failures.append(f"{tag}: refused but gives force {c['force']}")
                if c["delta_force"] != 0:
                    failures.append(f"{tag}: refused but delta_force {c['delta_force']}")
                continue
            if p.wrong_way:
                failures.append(f"{tag}: wrong-way n {np.round(c['n'], 3).tolist()} (full meshes "
                                f"{p.delta_truth * 1e3:.2f} mm through the bodies) not refused")
            over = c["delta"] > c["delta_bound"]
            if bool(c["clamped"]) != bool(over and c["covered"]):
                failures.append(f"{tag}: clamped {c['clamped']}, but delta {c['delta']} vs delta_bound "
                                f"{c['delta_bound']}")
            want = (0.0 if not c["covered"] else c["delta_bound"] if over else max(c["delta"], 0.0))
            if abs(c["delta_force"] - want) > ABS_TOL:
                failures.append(f"{tag}: delta_force {c['delta_force']}, min(delta, delta_bound) = {want}")
            if p.kept and not p.problem and math.isfinite(p.bound) and p.delta_truth > c["delta_bound"] + p.bound:
                failures.append(f"{tag}: delta_bound {c['delta_bound']} cuts the truth {p.delta_truth}")
        w = r.query["warnings"]
        for word in ("refused", "clamped"):
            keys = [k for k in w if word in k]
            if not keys:
                failures.append(f"{r.scene.name} N={r.N}: no warnings counter for {word} patches ({sorted(w)})")
                continue
            count = sum(1 for c in cs if c[word])
            if w[keys[0]] != count:
                failures.append(f"{r.scene.name} N={r.N}: warnings.{keys[0]} = {w[keys[0]]}, {count} {word} patches")
    return failures


# ----------------------------------------------------------------------------
# Session caches (shared by the test files and examples/depth_error_report.py)
# ----------------------------------------------------------------------------

GROUPS = ("gratings", "sphere", "models")
_MODELS: dict = {}
_GROUP_RUNS: dict = {}


def shared_present() -> bool:
    return all((SHARED_MODELS / n).is_file() for n in SHARED)


def model_names() -> list[str]:
    names = ["grating", "plate", "sphere", "box"]
    if shared_present():
        names += [Path(n).stem for n in SHARED]
    return names


def load_models(root: Path) -> dict:
    """Every bundle of the scenes, baked once per process (or reused from ``root``)."""
    for n in model_names():
        if n not in _MODELS:
            _MODELS[n] = bake_model(n, root)
    return dict(_MODELS)


def group_scenes(models: dict, group: str) -> list[Scene]:
    if group == "gratings":
        return grating_scenes()
    if group == "sphere":
        return sphere_scenes(models)
    return model_scenes(models, [Path(n).stem for n in SHARED])


def group_runs(hrt: str, models: dict, group: str, verbose: bool = True) -> list[SceneRun]:
    """The runs of one group at both resolutions, once per process."""
    if group not in _GROUP_RUNS:
        scenes = group_scenes(models, group)
        t0 = time.perf_counter()
        _GROUP_RUNS[group] = [run_scene(hrt, models, sc, N) for sc in scenes for N in RESOLUTIONS]
        if verbose:
            print(f"\n{group}: {len(scenes)} scenes x {len(RESOLUTIONS)} resolutions in "
                  f"{time.perf_counter() - t0:.1f} s")
    return _GROUP_RUNS[group]


README_COMMAND = (".venv/bin/python examples/depth_error_report.py "
                  "(or .venv/bin/python -m pytest -s tests/integration/test_fullsurface_depth.py)")


def readme_figure(runs: list[SceneRun]) -> str:
    """The README's line: the depth error against the full meshes over all scenes."""
    s = summarize("all", runs)
    groups = sorted({r.scene.group for r in runs}, key=lambda g: GROUPS.index(g) if g in GROUPS else 9)
    # Kept patches where hrt has no depth (uncovered) but the full meshes have columns
    # crossing both: not in the median, reported with their own worst.
    probs = [p for r in runs for p in r.patches if p.kept and p.problem and not refused(p) and not p.wrong_way]
    worst_prob = max((abs(p.err_texels) for p in probs if math.isfinite(p.err_texels)), default=0.0)
    extra = (f"; plus {len(probs)} coverage problems (hrt uncovered or phantom where the full meshes "
             f"say otherwise, worst {worst_prob:.2f} texel)" if probs else "")
    return (f"depth error against the full-resolution meshes, {' + '.join(groups)}, N = "
            f"{' and '.join(map(str, RESOLUTIONS))}: median {s['median_abs_texels']:.3f} atlas texel, worst "
            f"{s['worst_abs_texels']:.3f} texel ({s['worst_abs_mm']:.4f} mm) over {s['kept'] - s['problems']} "
            f"patches compared ({100 * s['kept_fraction']:.0f} % of {s['candidates']} kept), "
            f"{s['outside_bound']} outside their bound{extra}; command: {README_COMMAND}")


# ----------------------------------------------------------------------------
# Sampling: the truth sampled every 0.1 atlas texel over the window
# ----------------------------------------------------------------------------

#: Spacing of the continuous truth, in atlas texels (the smaller texel of A and B).
DENSE_SPACING = 0.1
#: Cells refined per level of the branch and bound (ranked by their sampled value).
DENSE_KEEP = 256


def continuous_truth(c: dict, a: Model, b: Model, pose_a, pose_b, p: PatchResult) -> tuple[float, int]:
    """max over the window of h_A - h_B on the full meshes, sampled every DENSE_SPACING
    atlas texel, by branch and bound from the patch's own grid: a square of side h whose
    centre has F = h_A - h_B holds no point above F + s h / sqrt(2) (s = s_A + s_B, the
    largest slope of F; the harness's s of the patch), so a square is refined (4 x 4
    sub-squares) only while its centre is within 2 s h / sqrt(2) (twice that: slack for
    the slopes being measured on the grid's columns) of the best sample so far, the best
    DENSE_KEEP squares per level, until h <= DENSE_SPACING texel. Returns (the maximum,
    samples cast)."""
    X, n, u, v, cell = window_columns(c)
    s = sum(p.slope)
    spacing = DENSE_SPACING * min(a.texel, b.texel)

    def F(P):
        ha = surface_columns(a, pose_a, P, n, u, v, True).h
        hb = surface_columns(b, pose_b, P, n, u, v, False).h
        return np.where(np.isfinite(ha) & np.isfinite(hb), ha - hb, -np.inf)

    cen, h = X, cell
    val = F(cen)
    best = float(val.max())
    cast = len(cen)
    while h > spacing:
        keep = np.nonzero(val >= best - 2 * s * h / math.sqrt(2))[0]
        if not len(keep):
            break
        keep = keep[np.argsort(-val[keep])][:DENSE_KEEP]
        sub = max(2, min(4, int(math.ceil(h / spacing))))
        g = (np.arange(sub) + 0.5) / sub - 0.5
        du, dv = (x.ravel() for x in np.meshgrid(g * h, g * h, indexing="xy"))
        off = du[:, None] * u + dv[:, None] * v
        cen = (cen[keep][:, None, :] + off[None, :, :]).reshape(-1, 3)
        h /= sub
        val = F(cen)
        cast += len(cen)
        best = max(best, float(val.max()))
    return best, cast


# ----------------------------------------------------------------------------
# Paths: one hrt query for many relative poses
# ----------------------------------------------------------------------------


def _translate(pose, d):
    return [*(np.asarray(pose[:3], float) + d).tolist(), *map(float, pose[3:])]


def path_query(hrt: str, a: Model, b: Model, pose_a, pose_b, offsets, N: int = 50, chunk: int = 60,
               heights: str | None = None) -> list[list[dict]]:
    """The contacts of A moved by each of ``offsets`` (world, m) relative to B.

    One `hrt query` holds many copies of B (every B is an independent object of the
    frame: contacts are between A and each B): copy k is B translated by -offsets[k],
    which is A translated by +offsets[k] relative to B. The runtime's window lattice and
    u are fixed to B (runtime/src/contact/cluster.cpp), so the frame depends on the
    relative pose only; loading a bundle per copy is what this costs (about 0.15 s),
    against 0.45 s per `hrt query`. Returns, per offset, its contacts with positions
    (p_a, p_b, window origin) moved into the frame in which B stays put."""
    out = []
    for lo in range(0, len(offsets), chunk):
        part = offsets[lo:lo + chunk]
        cmd = [hrt, "query", str(a.bundle), *[str(b.bundle)] * len(part), "--pose-a", *map(repr, map(float, pose_a))]
        for d in part:
            cmd += ["--pose-b", *map(repr, _translate(pose_b, -np.asarray(d, float)))]
        cmd += ["--resolution", str(N), "--max-patches", str(64 * len(part)), "--no-verify-hashes", "--json"]
        if heights:
            cmd += ["--heights", heights]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, f"{' '.join(cmd[:6])} ...: exit {res.returncode}: {res.stderr[-2000:]}"
        q = json.loads(res.stdout)
        assert q["warnings"]["patches_dropped"] == 0, q["warnings"]
        per = [[] for _ in part]
        for c in q["contacts"]:
            k = int(c["object_b"]) - 1
            d = np.asarray(part[k], float)
            c = dict(c)
            for key in ("p_a", "p_b"):
                c[key] = (np.asarray(c[key], float) + d).tolist()
            c["window"] = dict(c["window"], origin=(np.asarray(c["window"]["origin"], float) + d).tolist())
            per[k].append(c)
        out += per
    return out


# ----------------------------------------------------------------------------
# Session setup shared by the test files (test_fullsurface_depth, test_depth_*)
# ----------------------------------------------------------------------------

CI = bool(os.environ.get("CI"))


def require_shared():
    """A missing ../shared/models fails under CI (it must run the shared-model scenes)
    and skips the calling test elsewhere."""
    import pytest

    missing = [n for n in SHARED if not (SHARED_MODELS / n).is_file()]
    if missing:
        msg = f"../shared/models is missing {missing} ({SHARED_MODELS})"
        if CI:
            pytest.fail(msg + ": CI must run the shared-model scenes")
        pytest.skip(msg)


def session_models(tmp_path_factory) -> dict:
    """Every bundle the scenes use, baked once per session and shared by the test files
    (FULLSURFACE_CACHE keeps them between sessions). Under CI a missing ../shared fails."""
    if CI:
        require_shared()
    root = Path(os.environ.get("FULLSURFACE_CACHE") or tmp_path_factory.getbasetemp() / "fullsurface")
    fresh = not _MODELS
    out = load_models(root)
    if fresh:
        print("\nbakes: " + ", ".join(f"{n} {m.bake_s:.1f} s (texel {m.texel * 1e6:.1f} um)" for n, m in out.items()))
    return out
