"""Haptic texture synthesis: give a smooth mesh a surface relief.

``hbake texture INPUT -o OUTPUT --pattern P --amplitude A --wavelength L`` refines the
mesh where the relief goes (MeshLab's conforming midpoint refinement of the edges longer
than ``L / samples``: only where needed, and the mesh stays closed where it was) and
moves each vertex along a smoothed normal field (or, with ``--along axis``, along
``--axis``: a height field) by the pattern's height ``w(p) A f(p)`` (``f`` of unit
amplitude, ``w`` the region's weight: 1 inside, fading to 0 over ``--fade``, one
wavelength by default, at its border so that no step is made there; with ``--fade 0``
the relief is full up to the border and spills over 4 A onto the faces beyond it,
which are remeshed isotropically first so that no sliver folds).

Lengths (amplitude, wavelength, box corners, origin) are in the input file's own
units; the output is written in the same units, so bake it with the same ``--units``
as the input would have been.

Patterns (``f`` of unit amplitude; ``u, v`` the mapping's surface coordinates, ``s``
their phase ``u / L``):

* ``ridges``: ``f = profile(u / L)``, ridges running along ``v``; profile ``sine``,
  ``trapezoid`` (flat tops and bottoms joined by straight flanks, each ``--flank`` of
  the wavelength: 0.25, four equal quarters, by default) or ``triangle``;
* ``grooves``: a flat surface with narrow V grooves cut in (a quarter of the
  wavelength wide), ``f = -1`` at the bottom of a groove and 0 between grooves;
* ``knurl``: a diamond knurl, the sum of two families of V ridges at +/-45 degrees;
* ``bumps``: a square lattice of smooth bumps (raised cosines), period ``L``;
* ``noise``: band-limited noise: 16 sinusoids of wavelength ``L`` with directions and
  phases drawn from ``--seed`` (numpy's PCG64), a solid (3D) texture needing no mapping,
  scaled so its RMS is that of a sinusoid of amplitude ``A``;
* ``image:FILE``: a grayscale image (PNG, JPEG, ... through Pillow), tiled, one image
  width per wavelength along ``u``; black is ``-1``, white ``+1``, bilinear between
  pixels.

Mappings: ``planar`` (``u`` along ``--direction`` projected on the plane normal to
``--axis``, ``v`` across it) and ``cylindrical`` (about the line through ``--origin``
along ``--axis``: ``u`` the arc length at the region's mean radius, rounded so that a
whole number of wavelengths goes around; ``v`` along the axis).

Errors are one line, ``hbake: error: FILE: what``; bad texture parameters (a negative
amplitude, a wavelength whose refinement would exceed ``--max-triangles``, a region
with no face, an amplitude that would fold faces over) exit with
``EXIT_TEXTURE_PARAMETERS``; the output is written to a temporary sibling and renamed,
so a failed run leaves none.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from hbake.errors import HbakeError, InputInvalidError, InputMissingError, OutputExistsError, \
    OutputUnwritableError, EXIT_TEXTURE_PARAMETERS
from hbake.fileio import write_atomic

PATTERNS = ("ridges", "grooves", "knurl", "bumps", "noise")
PROFILES = ("sine", "trapezoid", "triangle")
MAPPINGS = ("planar", "cylindrical")
ALONG = ("normal", "axis")
OUTPUT_EXTENSIONS = (".ply", ".obj", ".stl", ".off")

#: Edges per wavelength after refinement: 8 samples a sine within A (1 - cos(pi/8)) =
#: 7.6 % of its amplitude and keeps a trapezoid's flat quarter-wavelength plateaus two
#: edges wide.
DEFAULT_SAMPLES = 8
#: The refinement limit: a run that would make more triangles than this is refused
#: (4M triangles are ~200 MB as PLY and minutes of baking on a laptop).
DEFAULT_MAX_TRIANGLES = 4_000_000
#: Rounds of normal averaging over the one-ring (the normal field is smooth across
#: creases over about this many edges, i.e. a fraction of a wavelength).
DEFAULT_NORMAL_SMOOTHING = 4
#: Noise: the number of sinusoids summed.
NOISE_WAVES = 16
#: Midpoint rounds at most (each halves the longest edges): 2^-24 of the input's size.
MAX_ROUNDS = 24


class TextureParameterError(HbakeError):
    """A texture parameter that cannot be honoured (exit EXIT_TEXTURE_PARAMETERS)."""

    exit_code = EXIT_TEXTURE_PARAMETERS


@dataclass(frozen=True)
class Region:
    """Where the relief goes: every face whose centroid is in every box and whose normal
    is within every cone (no box and no cone: the whole mesh)."""

    boxes: tuple = ()      # ((x0, y0, z0), (x1, y1, z1)) each
    cones: tuple = ()      # ((nx, ny, nz) unit, max angle in rad) each

    @staticmethod
    def parse(texts, source="--region") -> "Region":
        boxes, cones = [], []
        for text in texts:
            kind, _, rest = text.partition(":")
            try:
                vals = [float(x) for x in rest.split(",")] if rest else []
            except ValueError:
                raise TextureParameterError(f"{source} {text}: expected numbers after '{kind}:'") from None
            if not all(math.isfinite(v) for v in vals):
                raise TextureParameterError(f"{source} {text}: numbers must be finite")
            if kind == "all" and not vals:
                continue
            if kind == "box" and len(vals) == 6:
                lo, hi = np.array(vals[:3]), np.array(vals[3:])
                if np.any(hi <= lo):
                    raise TextureParameterError(f"{source} {text}: each max must exceed its min")
                boxes.append((tuple(lo), tuple(hi)))
            elif kind == "facing" and len(vals) in (3, 4):
                n = np.array(vals[:3])
                if np.linalg.norm(n) == 0:
                    raise TextureParameterError(f"{source} {text}: the direction is zero")
                deg = vals[3] if len(vals) == 4 else 30.0
                if not 0 < deg <= 180:
                    raise TextureParameterError(f"{source} {text}: the angle must be in (0, 180] degrees")
                cones.append((tuple(n / np.linalg.norm(n)), math.radians(deg)))
            else:
                raise TextureParameterError(
                    f"{source} {text}: expected all, box:X0,Y0,Z0,X1,Y1,Z1 or facing:NX,NY,NZ[,DEG]")
        return Region(tuple(boxes), tuple(cones))

    def faces(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Boolean mask of the faces in the region."""
        tri = vertices[faces]
        c = tri.mean(axis=1)
        keep = np.ones(len(faces), bool)
        for lo, hi in self.boxes:
            keep &= np.all((c >= lo) & (c <= hi), axis=1)
        if self.cones:
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            norm = np.linalg.norm(n, axis=1)
            n = n / np.where(norm > 0, norm, 1.0)[:, None]
            for d, ang in self.cones:
                keep &= n @ np.asarray(d) >= math.cos(ang) - 1e-12
        return keep

    def describe(self) -> str:
        parts = [f"box {lo}..{hi}" for lo, hi in self.boxes]
        parts += [f"facing {d} within {math.degrees(a):g} deg" for d, a in self.cones]
        return " and ".join(parts) or "all"


@dataclass(frozen=True)
class TextureSettings:
    """Options of ``hbake texture`` (one field per command-line option)."""

    pattern: str                         # one of PATTERNS, or "image:FILE"
    amplitude: float                     # half the peak-to-peak relief, input units
    wavelength: float                    # period of the relief, input units
    profile: str = "sine"                # ridges only: PROFILES
    flank: float = 0.25                  # trapezoid: fraction of the wavelength each flank takes, (0, 0.5)
    along: str = "normal"                # displace along the smoothed normals, or along --axis
    fade: float | None = None            # width of the fade at the region's border (default: one wavelength)
    mapping: str = "planar"              # MAPPINGS
    axis: tuple = (0.0, 0.0, 1.0)        # planar: the plane's normal; cylindrical: the axis
    direction: tuple = (1.0, 0.0, 0.0)   # planar: the direction of u (projected on the plane)
    origin: tuple | None = None          # a point of the mapping (default: the region's centroid)
    region: Region = field(default_factory=Region)
    samples: int = DEFAULT_SAMPLES       # edges per wavelength after refinement
    normal_smoothing: int = DEFAULT_NORMAL_SMOOTHING
    max_triangles: int = DEFAULT_MAX_TRIANGLES
    seed: int = 0                        # noise only


@dataclass
class TextureResult:
    vertices: np.ndarray
    faces: np.ndarray
    triangles_in: int
    triangles_out: int
    region_faces_in: int
    edge_target: float
    rounds: int
    displaced_vertices: int
    max_displacement: float
    seconds: float

    def summary(self, src, dst) -> str:
        return (f"{dst}: {self.triangles_out:,} triangles ({src}: {self.triangles_in:,}; "
                f"{self.region_faces_in:,} faces in the region refined in {self.rounds} rounds to edges "
                f"<= {self.edge_target:.4g}); {self.displaced_vertices:,} vertices displaced, "
                f"at most {self.max_displacement:.4g}; {self.seconds:.1f} s")


# ----------------------------------------------------------------------------
# Patterns: unit-amplitude heights of surface coordinates
# ----------------------------------------------------------------------------


def profile_value(t: np.ndarray, profile: str, flank: float = 0.25) -> np.ndarray:
    """The ridge profile of phase ``t`` (in wavelengths), in [-1, 1]: -1 at whole
    numbers (sine: 0 there, rising)."""
    f = t - np.floor(t)
    if profile == "sine":
        return np.sin(2 * np.pi * t)
    if profile == "triangle":
        return 1.0 - 4.0 * np.abs(f - 0.5)          # -1 at integers, +1 at half-integers
    if profile == "trapezoid":
        # e: the distance to the nearest whole number, in [0, 1/2]. The low plateau is
        # centred on whole numbers, the high one on halves, each (1 - 2 flank) / 2 wide,
        # joined by straight flanks `flank` wide (0.25: four equal quarters).
        e = 0.5 - np.abs(f - 0.5)
        p = (1.0 - 2.0 * flank) / 2.0
        return np.clip((e - p / 2.0) / flank * 2.0 - 1.0, -1.0, 1.0)
    raise ValueError(profile)


def _vee(t: np.ndarray) -> np.ndarray:
    """0 on a ridge line (t integer) falling linearly to 1 half a period away."""
    return 2.0 * np.abs(t - np.round(t))


def _image_height(path: Path, u: np.ndarray, v: np.ndarray, L: float) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    import io

    from hbake.constants import MAX_INPUT_BYTES
    from hbake.fileio import FileTooLargeError, NotRegularFileError, read_regular

    try:
        # hbake's one input reader: a regular file within the input limit (Pillow would
        # block on a FIFO and read /dev/zero until memory runs out).
        data = read_regular(path, MAX_INPUT_BYTES)
        with Image.open(io.BytesIO(data)) as im:
            g = np.asarray(im.convert("F"), dtype=np.float64)
    except FileNotFoundError:
        raise InputMissingError(f"{path}: no such image file") from None
    except (NotRegularFileError, FileTooLargeError, IsADirectoryError) as exc:
        raise InputMissingError(f"{path}: {exc.strerror}") from None
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise InputInvalidError(f"{path}: not a readable image ({exc})") from None
    hgt, wid = g.shape
    if wid < 2 or hgt < 2:
        raise InputInvalidError(f"{path}: the image must be at least 2 x 2 pixels, got {wid} x {hgt}")
    lo, hi = float(g.min()), float(g.max())
    g = (g - lo) / (hi - lo) * 2.0 - 1.0 if hi > lo else np.zeros_like(g)
    # One image width per wavelength along u, the same pixel pitch along v (tiled).
    x = (u / L) * wid
    y = (v / L) * wid
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    i0, j0 = x0.astype(np.int64) % wid, y0.astype(np.int64) % hgt
    i1, j1 = (i0 + 1) % wid, (j0 + 1) % hgt
    return ((1 - fx) * (1 - fy) * g[j0, i0] + fx * (1 - fy) * g[j0, i1]
            + (1 - fx) * fy * g[j1, i0] + fx * fy * g[j1, i1])


def pattern_height(s: TextureSettings, points: np.ndarray, uv) -> np.ndarray:
    """The unit-amplitude height f at ``points`` (surface coordinates ``uv``)."""
    L = s.wavelength
    u, v = uv
    if s.pattern == "ridges":
        return profile_value(u / L, s.profile, s.flank)
    if s.pattern == "grooves":
        # V grooves a quarter wavelength wide: depth 1 at the groove's centre line.
        return -np.clip(1.0 - 8.0 * np.abs(u / L - np.round(u / L)), 0.0, None)
    if s.pattern == "knurl":
        # Two V-ridge families at +/-45 degrees, each of period L across its ridges; the
        # sum ranges over [-2, 2] and is halved to unit amplitude (diamond pyramids).
        a = (u + v) / (math.sqrt(2) * L)
        b = (u - v) / (math.sqrt(2) * L)
        return 1.0 - (_vee(a) + _vee(b))
    if s.pattern == "bumps":
        return 2.0 * (0.5 + 0.5 * np.cos(2 * np.pi * u / L)) * (0.5 + 0.5 * np.cos(2 * np.pi * v / L)) - 1.0
    if s.pattern == "noise":
        rng = np.random.Generator(np.random.PCG64(s.seed))
        d = rng.normal(size=(NOISE_WAVES, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        phase = rng.uniform(0, 2 * np.pi, NOISE_WAVES)
        # RMS of a sum of K unit cosines with independent phases is sqrt(K / 2); that of
        # a unit sine sqrt(1 / 2): divide by sqrt(K) to match it.
        arg = 2 * np.pi * (points @ d.T) / L + phase
        return np.cos(arg).sum(axis=1) / math.sqrt(NOISE_WAVES)
    if s.pattern.startswith("image:"):
        return _image_height(Path(s.pattern[len("image:"):]), u, v, L)
    raise TextureParameterError(f"--pattern {s.pattern}: unknown (one of {', '.join(PATTERNS)}, image:FILE)")


def _unit(v, what) -> np.ndarray:
    v = np.asarray(v, float)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0:
        raise TextureParameterError(f"{what}: must be a nonzero vector")
    return v / n


def surface_coordinates(s: TextureSettings, points: np.ndarray, origin: np.ndarray, radius: float):
    """(u, v) of the mapping at ``points`` (input units)."""
    a = _unit(s.axis, "--axis")
    p = points - origin
    if s.mapping == "planar":
        d = np.asarray(s.direction, float)
        d = d - a * (d @ a)
        if np.linalg.norm(d) < 1e-9:
            raise TextureParameterError("--direction: parallel to --axis (no direction in the plane)")
        d = d / np.linalg.norm(d)
        e = np.cross(a, d)
        return p @ d, p @ e
    # Cylindrical: an orthonormal frame (b1, b2, a); u the arc length at `radius`.
    ref = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    b1 = _unit(ref - a * (ref @ a), "axis frame")
    b2 = np.cross(a, b1)
    theta = np.arctan2(p @ b2, p @ b1)
    return theta * radius, p @ a


# ----------------------------------------------------------------------------
# Refinement, normals, displacement
# ----------------------------------------------------------------------------


def _edge_lengths(vertices, faces):
    tri = vertices[faces]
    return np.stack([np.linalg.norm(tri[:, (k + 1) % 3] - tri[:, k], axis=1) for k in range(3)], 1)


def refine(vertices, faces, region: Region, h: float, spill: float = 0.0, cancel=None):
    """Split every edge of a region face longer than ``h`` (MeshLab's midpoint refinement
    of selected faces, conforming: the neighbours of a split edge are split with it, so a
    closed mesh stays closed), and of the faces with a vertex within ``spill`` of the
    region (where the relief spills over; long slivers there would fold). Returns
    (vertices, faces, rounds)."""
    import pymeshlab
    from scipy.spatial import cKDTree

    rounds = 0
    while True:
        inside = region.faces(vertices, faces)
        if spill > 0:
            in_v = np.unique(faces[inside].ravel())
            d, _ = cKDTree(vertices[in_v]).query(vertices, distance_upper_bound=spill)
            inside = inside | np.isfinite(d)[faces].any(axis=1)
        # A relative slack of 1e-5: MeshLab compares in its own arithmetic, and an edge
        # that ends up h to round-off (the diagonal of a square split in halves) would
        # be "long" here and never split there.
        long_ = inside & (_edge_lengths(vertices, faces).max(axis=1) > h * (1 + 1e-5))
        if not long_.any():
            return vertices, faces, rounds
        if rounds >= MAX_ROUNDS:
            raise TextureParameterError(f"refinement did not reach edges <= {h:.4g} in {MAX_ROUNDS} rounds "
                                        f"({int(long_.sum())} faces of the region still have a longer edge)")
        # MeshLab splits an edge of the selection only when both of its faces are
        # selected: add the faces across each edge of a long-edged region face, so that
        # the region's border edges are split too (their outside neighbours are split
        # conformingly with them).
        sel = long_.copy()
        adj = trimesh.graph.face_adjacency(faces)
        if len(adj):
            hit = long_[adj[:, 0]] | long_[adj[:, 1]]
            sel[adj[hit].ravel()] = True
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces,
                                   f_scalar_array=sel.astype(np.float64)))
        ms.compute_selection_by_condition_per_face(condselect="fq > 0.5")
        # threshold: only edges above h are split (MeshLab's RefineE), one round at a time
        # so the region is re-evaluated on the new faces.
        ms.meshing_surface_subdivision_midpoint(iterations=1, threshold=pymeshlab.PureValue(h),
                                                selected=True)
        m = ms.current_mesh()
        vertices = np.asarray(m.vertex_matrix(), np.float64)
        faces = np.asarray(m.face_matrix(), np.int64)
        rounds += 1
        if cancel is not None:
            cancel()


def remesh_spill(vertices, faces, region: Region, h: float, spill: float):
    """Isotropic remeshing (MeshLab's, edges about 3/4 h, sharp edges kept) of the faces
    outside the region within ``spill`` of it. The midpoint splits leave slivers there
    (a block's side wall under its top: 0.25 x 0.02 mm), and a relief that varies
    along a sliver folds it; on well-shaped triangles the spilled displacement, whose
    map has a Jacobian of at least 1 - 1.5 / 4 (the smoothstep over 4 A), folds none."""
    import pymeshlab
    from scipy.spatial import cKDTree

    inside = region.faces(vertices, faces)
    in_v = np.unique(faces[inside].ravel())
    d, _ = cKDTree(vertices[in_v]).query(vertices, distance_upper_bound=spill)
    zone = ~inside & np.isfinite(d)[faces].any(axis=1)
    if not zone.any():
        return vertices, faces
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces,
                               f_scalar_array=zone.astype(np.float64)))
    ms.compute_selection_by_condition_per_face(condselect="fq > 0.5")
    ms.meshing_isotropic_explicit_remeshing(iterations=4, targetlen=pymeshlab.PureValue(0.75 * h),
                                            featuredeg=30, selectedonly=True)
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), np.float64), np.asarray(m.face_matrix(), np.int64)


def _vertex_adjacency(faces, n):
    import scipy.sparse as sp

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A.data[:] = 1.0
    return A


def smooth_normals(vertices, faces, rounds: int) -> np.ndarray:
    """Area-weighted vertex normals (trimesh), then ``rounds`` of averaging over each
    vertex and its one-ring: a normal field that turns gradually across creases, so
    that displaced neighbours on the two sides of a sharp edge do not cross."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    n = np.array(mesh.vertex_normals, dtype=np.float64)
    if rounds > 0:
        A = _vertex_adjacency(faces, len(vertices))
        for _ in range(rounds):
            n = n + A @ n
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return n


def region_weight(vertices, faces, inside, fade: float, spill: float = 0.0) -> np.ndarray:
    """Weight of the relief per vertex. With ``fade`` > 0: 1 at vertices of region faces
    farther than ``fade`` from its border, a smoothstep of that distance nearer, 0
    outside (no step at the border). With ``fade`` 0: 1 on every vertex of a region
    face (the relief is full up to the border) and, outside, 1 - smoothstep of the
    distance to the border over ``spill``, so that the faces next to the border (a
    block's side walls under its textured top) follow the border's motion gradually
    instead of folding under it."""
    from scipy.spatial import cKDTree

    nv = len(vertices)
    in_v = np.zeros(nv, bool)
    in_v[faces[inside].ravel()] = True
    out_v = np.zeros(nv, bool)
    out_v[faces[~inside].ravel()] = True
    w = in_v.astype(float)
    border = in_v & out_v
    if not border.any():
        return w
    tree = cKDTree(vertices[border])
    if fade > 0:
        d, _ = tree.query(vertices[in_v])
        t = np.clip(d / fade, 0.0, 1.0)
        w[in_v] = t * t * (3 - 2 * t)
    elif spill > 0:
        outside = ~in_v
        d, _ = tree.query(vertices[outside], distance_upper_bound=spill)
        t = np.clip(np.where(np.isfinite(d), d, spill) / spill, 0.0, 1.0)
        w[outside] = 1.0 - t * t * (3 - 2 * t)
    return w


def texture_mesh(vertices: np.ndarray, faces: np.ndarray, s: TextureSettings,
                 source: str = "input", cancel=None) -> TextureResult:
    """Refine and displace (vertices, faces); raises TextureParameterError on a bad
    parameter (naming ``source``)."""
    t0 = time.perf_counter()
    if not (math.isfinite(s.amplitude) and s.amplitude > 0):
        raise TextureParameterError(f"{source}: --amplitude must be a positive length, got {s.amplitude:g}")
    if not (math.isfinite(s.wavelength) and s.wavelength > 0):
        raise TextureParameterError(f"{source}: --wavelength must be a positive length, got {s.wavelength:g}")
    if s.samples < 2:
        raise TextureParameterError(f"{source}: --samples must be at least 2 per wavelength, got {s.samples}")
    if s.profile not in PROFILES:
        raise TextureParameterError(f"{source}: --profile {s.profile}: one of {', '.join(PROFILES)}")
    if s.pattern not in PATTERNS and not s.pattern.startswith("image:"):
        raise TextureParameterError(f"{source}: --pattern {s.pattern}: one of {', '.join(PATTERNS)}, image:FILE")
    if not 0 < s.flank < 0.5:
        raise TextureParameterError(f"{source}: --flank must be in (0, 0.5), got {s.flank:g}")
    if s.along not in ALONG:
        raise TextureParameterError(f"{source}: --along {s.along}: one of {', '.join(ALONG)}")
    if s.fade is not None and not (math.isfinite(s.fade) and s.fade >= 0):
        raise TextureParameterError(f"{source}: --fade must be a length >= 0, got {s.fade:g}")
    if s.mapping not in MAPPINGS:
        raise TextureParameterError(f"{source}: --mapping {s.mapping}: one of {', '.join(MAPPINGS)}")
    inside = s.region.faces(vertices, faces)
    if not inside.any():
        raise TextureParameterError(f"{source}: --region {s.region.describe()}: no face of the mesh is in it")
    size = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    # A wavelength longer than the part leaves less than one period on it: next to no
    # relief (1e308 gave a mesh with none at all and exit 0).
    if s.wavelength > size:
        raise TextureParameterError(f"{source}: --wavelength {s.wavelength:g} is longer than the part "
                                    f"({size:.4g} along its bounding-box diagonal): no relief would be made")
    if s.amplitude >= 0.25 * size:
        raise TextureParameterError(f"{source}: --amplitude {s.amplitude:g} is a quarter of the part's size "
                                    f"({size:.4g}) or more: not a surface texture")

    # The refinement limit, checked before refining: edges of h = L / samples over the
    # region's area take at most area / (sqrt(3) / 16 h^2) triangles (midpoint rounds
    # leave edges in (h / 2, h]; the count of equilateral triangles of edge h / 2).
    h = s.wavelength / s.samples
    tri = vertices[faces]
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    area = float(areas[inside].sum())
    per_tri = math.sqrt(3) / 16 * h * h
    estimate = int((~inside).sum()) + int(area / per_tri)
    if estimate > s.max_triangles:
        l_min = s.samples * math.sqrt(area / (s.max_triangles - int((~inside).sum())) / (math.sqrt(3) / 16)) \
            if s.max_triangles > (~inside).sum() else float("inf")
        raise TextureParameterError(
            f"{source}: --wavelength {s.wavelength:g} is below the refinement limit: edges of "
            f"{h:.4g} over the region's area {area:.4g} make up to {estimate:,} triangles, more than "
            f"--max-triangles {s.max_triangles:,} (the limit here is a wavelength of {l_min:.4g})")

    fade = s.wavelength if s.fade is None else s.fade
    # With no fade the relief spills over 4 amplitudes past the border: the spilled
    # faces' height changes by at most A f over 4 A of their extent (a slope of 1/4).
    spill = 4 * s.amplitude if fade == 0 and (s.region.boxes or s.region.cones) else 0.0
    v, f, rounds = refine(vertices, faces, s.region, h, spill, cancel)
    if spill > 0:
        v, f = remesh_spill(v, f, s.region, h, spill)
    inside = s.region.faces(v, f)
    w = region_weight(v, f, inside, fade if s.region.boxes or s.region.cones else 0.0, spill)
    normals = smooth_normals(v, f, s.normal_smoothing)
    # The fold check below compares with the smoothed field either way.
    direction = normals if s.along == "normal" else np.broadcast_to(_unit(s.axis, "--axis"), v.shape)
    sel = w > 0
    pts = v[sel]
    origin = np.asarray(s.origin, float) if s.origin is not None else pts.mean(axis=0)
    radius = 0.0
    if s.mapping == "cylindrical":
        a = _unit(s.axis, "--axis")
        p = pts - origin
        r = np.linalg.norm(p - np.outer(p @ a, a), axis=1)
        waves = max(1, int(round(2 * np.pi * float(r.mean()) / s.wavelength)))
        radius = waves * s.wavelength / (2 * np.pi)     # a whole number of periods around
    uv = surface_coordinates(s, pts, origin, radius)
    height = s.amplitude * w[sel] * pattern_height(s, pts, uv)
    out = v.copy()
    out[sel] += height[:, None] * direction[sel]

    # A relief too deep for the mesh's curvature folds faces over: refuse it.
    def fnormals(x):
        t = x[f]
        return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n0, n1 = fnormals(v), fnormals(out)
    # Faces that already face against the smoothed field (a raw scan's small creases
    # folded back on themselves) are the input's; only faces that agree with it count.
    agree = np.einsum("ij,ij->i", n0, normals[f].sum(axis=1)) > 0
    flipped = int(np.sum(agree & (np.einsum("ij,ij->i", n0, n1) <= 0)))
    if flipped:
        raise TextureParameterError(
            f"{source}: --amplitude {s.amplitude:g} folds {flipped:,} faces over (the relief is too deep "
            f"for the mesh's curvature or for --wavelength {s.wavelength:g}); lower it")
    return TextureResult(out, f, len(faces), len(f), int(np.sum(s.region.faces(vertices, faces))), h,
                         rounds, int(sel.sum()), float(np.abs(height).max()), time.perf_counter() - t0)


def _load(path: Path):
    """The input mesh in its own units (hbake.stages.load's checks and repairs, no scaling)."""
    from hbake.stages.load import load_mesh
    from hbake.settings import LoadSettings

    m = load_mesh(path, LoadSettings(units="m"))
    return m.vertices, m.faces


def texture_file(src: Path, dst: Path, s: TextureSettings, force: bool = False,
                 cancel=None) -> TextureResult:
    """Texture the mesh file ``src`` into ``dst`` (format from its extension)."""
    dst = Path(dst)
    ext = dst.suffix.lower()
    if ext not in OUTPUT_EXTENSIONS:
        raise OutputUnwritableError(f"{dst}: unsupported output type '{ext or '(none)'}' "
                                    f"(one of {' '.join(OUTPUT_EXTENSIONS)})")
    if dst.exists() and not force:
        raise OutputExistsError(f"{dst}: exists (pass --force to replace it)")
    parent = dst.absolute().parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise OutputUnwritableError(f"{dst}: directory {parent} is missing or not writable")
    vertices, faces = _load(Path(src))
    try:
        res = texture_mesh(vertices, faces, s, source=str(src), cancel=cancel)
    except TextureParameterError as exc:
        if str(exc).startswith(f"{src}:"):
            raise
        raise TextureParameterError(f"{src}: {exc}") from None
    data = trimesh.Trimesh(res.vertices, res.faces, process=False).export(file_type=ext[1:])
    if isinstance(data, str):
        data = data.encode()
    write_atomic(dst, lambda tmp: tmp.write_bytes(data))
    return res
