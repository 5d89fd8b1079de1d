"""Tolerances and defaults of hbake, in one place.

Every default of a setting (``hbake/settings.py``) and every numerical
tolerance used by a stage is defined here, with the reason for its value, so
that a reviewer can audit them together and tests can refer to them by name.
Lengths are in meters unless a name says ``_REL`` (relative to the bounding-box
diagonal of the full-resolution mesh) or ``_TEXELS``.
"""
from __future__ import annotations

# --- units ---------------------------------------------------------------------------------
#: Meters per source unit. The bundle is always in meters (docs/bundle-format.md).
UNIT_SCALE: dict[str, float] = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254}
#: File extensions whose format fixes the unit (glTF 2.0 mandates meters).
UNIT_FROM_FORMAT: dict[str, str] = {".gltf": "m", ".glb": "m"}
#: Extensions hbake reads (through trimesh). PLY and STL may be ASCII or binary.
SUPPORTED_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".gltf", ".glb")

# --- load and repair -----------------------------------------------------------------------
#: Largest input file read (bytes): 1 GiB is about 21 M triangles of binary STL, far past
#: what a haptic bake needs (the paper's models have 285k-658k triangles); the readers
#: hold several times the file in memory.
MAX_INPUT_BYTES = 1 << 30
#: Coordinate range of an input after scaling to meters. Haptic objects are hand-held
#: to room-sized; the bundle stores positions as float32 (coarse.ply, atlas.exr,
#: pieces.ply), and native stages misbehave far outside that: pymeshlab crashes at
#: 1e200, xatlas asserts on normals it cannot normalise at 1e15 and hangs at 1e20.
#: Every used coordinate is finite with |x| <= MAX_COORDINATE, the bounding-box diagonal
#: lies in [MIN_BBOX_DIAGONAL, MAX_BBOX_DIAGONAL] (10 um: below it the texel of a
#: 1024 atlas is 10 nm, and float32 epsilon-scale tolerances of the stages stop making
#: sense), ...
MAX_COORDINATE = 1e4
MIN_BBOX_DIAGONAL = 1e-5
MAX_BBOX_DIAGONAL = 1e4
#: ... and the part lies within MAX_OFFSET_RATIO bounding-box diagonals of the origin:
#: the float32 spacing at its largest coordinate X is 2^-23 X <= 1.2e-4 diagonal, at most
#: 1/8 of the texel of the default 1024 atlas (a texel is at least about diagonal / 1000)
#: and about one texel at the 8192 maximum. The bundle is not re-centred (the object
#: frame is the file's), so a part modelled far from its origin must be moved.
MAX_OFFSET_RATIO = 1e3
#: A face is degenerate (zero area) when its height is below this fraction of its longest
#: edge: a shape criterion, so tiny but well-shaped triangles of big CAD parts stay (the
#: shared planetary_gears.stl has genuine faces of area 4e-13 diag**2). 1e-9 sits above
#: the float64 round-off of a collinear triple (~1e-16 |coordinate| / edge) for parts up to
#: 1e5 edge lengths away from the origin.
DEGENERATE_HEIGHT_REL = 1e-9

# --- simplify ------------------------------------------------------------------------------
#: Default coarse triangle count: Table 1 of the paper has 518-720 coarse triangles
#: for 285k-658k-triangle models.
DEFAULT_TARGET_FACES = 600
#: pymeshlab's quadric collapse penalises collapses that create triangles of lower
#: quality (0..1, 1 = equilateral) than this. MeshLab's default is 0.3; 0.5 keeps the
#: corners of the ridged block at 16 triangles (two-sided mean distance 0.18 mm instead
#: of 0.46 mm) and is as good or better on the shared and procedural models (rocker_arm:
#: 11 % worse, fandisk 25 % better).
DEFAULT_QUALITY_THRESHOLD = 0.5
#: Inputs with more faces than DEFAULT_PRE_DECIMATE_ABOVE are first reduced to
#: DEFAULT_PRE_DECIMATE_FACES by fast-simplification (about 1.5 s for 650k faces) before
#: pymeshlab's slower but topology-preserving collapse (about 25 us per face, run twice
#: for the two placements) finishes the job. The pre-pass costs accuracy on relief-covered
#: blocks (the ridged block at 16 faces: two-sided mean distance 0.46 mm without it,
#: 2.3 mm with it), so smaller inputs skip it; at 100k faces the two collapses take about
#: 8 s of the bake's 30 s budget.
DEFAULT_PRE_DECIMATE_ABOVE = 100_000
DEFAULT_PRE_DECIMATE_FACES = 40_000
#: The collapses are scale-dependent too: on a sphere of 1280 triangles cut to 300,
#: pymeshlab's optimal placement gives the same mesh (two-sided mean distance 0.0104 radius)
#: from 8 mm radius (diagonal 28 mm) up to 1 m, 0.0125 radius at 2 mm and 0.031 at 1 mm, for
#: 4 times finer inputs alike (so a length, not a face size, sets it). A part whose
#: bounding-box diagonal is below SIMPLIFY_MIN_DIAGONAL is therefore collapsed scaled by the
#: least power of two 2^k that brings its diagonal to at least that (exact in float64 and
#: float32; the result is scaled back by the same 2^-k, also exact), so every part below
#: it is simplified as the same part between 20 and 40 mm. 20 mm: above the sizes where
#: the collapse was seen to change much (2 mm radius, 7 mm diagonal: +20 %), below the
#: smallest golden input (the pebble, 26.4 mm) and the smallest test part (the 16 mm
#: grating block of tests/fullsurface.py, 23 mm, whose coarse mesh and pieces the issue-8
#: continuity tests were measured on; at 25 mm it was collapsed at twice its size, and its
#: patch normal jumped on 74 of 120 steps of a slow path instead of under 30), so parts of
#: ordinary size are collapsed exactly as before.
SIMPLIFY_MIN_DIAGONAL = 0.020
#: Samples per side (and their seed) scoring the two vertex placements of the collapse.
SCORE_SAMPLES = 20_000
SCORE_SEED = 0
#: fast-simplification's aggressiveness (its default is 7).
PRE_DECIMATE_AGGRESSIVENESS = 7

# --- parameterize --------------------------------------------------------------------------
#: The paper stores 1024x1024 float textures (Sec. 6.2).
DEFAULT_ATLAS_SIZE = 1024
#: Atlas limit shared with the runtime (docs/input-contract.md): each side at most 8192
#: texels and at most 16,777,216 texels in all (256 MiB of float32 RGBA), checked from
#: the manifest and the EXR header before any pixel is decoded.
MAX_ATLAS_SIDE = 8192
MAX_ATLAS_TEXELS = 16_777_216
#: Texels between charts (xatlas ``padding``); with ``bilinear`` packing this keeps every
#: bilinear footprint of one chart off the texels of another, so no lookup crosses a seam.
DEFAULT_PADDING = 2
#: xatlas chart growing: cost limit and weight of normal deviation (xatlas defaults 2, 2).
DEFAULT_MAX_CHART_COST = 2.0
DEFAULT_NORMAL_DEVIATION_WEIGHT = 2.0
#: xatlas works in the units it is given and has absolute tolerances made for game meshes
#: of metres: it ignores every face whose area is at most FLT_EPSILON (2^-23 = 1.19e-7
#: unit^2; xatlas.cpp AddMesh, "Zero area face"), welds vertices closer than FLT_EPSILON
#: per coordinate and compares chart boundary lengths within kEpsilon = 1e-4 units. In
#: meters, the 600 faces of a 2 mm-radius sphere have about 8e-8 m^2 each, so xatlas
#: dropped nearly all of them (parked at UV (0, 0), reattached one by one: 35 charts instead
#: of 7 and texels 4 texel sizes off the surface). hbake therefore hands xatlas the coarse
#: mesh scaled by 2^k (exact in float32; texels_per_unit divided by the same 2^k, so the
#: UVs are those of the mesh in meters), the least k >= 0 that gives the median coarse face
#: at least XATLAS_MIN_MEDIAN_FACE_AREA (unit^2): 64 FLT_EPSILON = 2^-17 = 7.6e-6, a median
#: face edge of about 4 mm = 42 kEpsilon. Then a face 64 times smaller than the median
#: (a sliver) still clears the zero-area rule, and every part below that size is
#: parameterized as the same part scaled into [1, 4) times that median area: the same UVs
#: for any power-of-two scale. k = 0 above it, so parts of ordinary size keep their
#: parameterization bit for bit: the golden bundles have medians of 227-497 FLT_EPSILON
#: (k = 0); a 600-face sphere reaches the threshold at about 66 mm across, so smaller ones
#: are now scaled (the 8 mm-radius sphere by 4, the 2 mm one by 16: both are parameterized
#: as the same 32 mm sphere). Scaling up only (never down) is deliberate: xatlas's
#: tolerances shrink relative to the part as it grows, the parts above the threshold are
#: those that were already baked correctly, and their bundles stay as they were.
XATLAS_AREA_EPSILON = 2.0 ** -23
XATLAS_MIN_MEDIAN_FACE_AREA = 64 * XATLAS_AREA_EPSILON
#: ... and the scale stops where a coordinate of the scaled mesh would pass this (xatlas's
#: float32 cross products stay far from overflow; it fails near 1e15, see MAX_COORDINATE).
XATLAS_MAX_SCALED_COORDINATE = 1e6
#: The packer is rerun with a smaller texel density until the atlas fits the requested
#: size; stop when the density is known to within this ratio.
PACK_SEARCH_RATIO = 1.02
PACK_SEARCH_MAX_STEPS = 14
#: Long charts cap the density: a chart must fit the page at one density (see below), so
#: one long chart (the hammer's handle: 4 strips the length of the part) sets the texel of
#: the whole atlas and leaves the rest of the page empty (41.6 % covered). The search is
#: therefore repeated with the charts longer than each of these fractions of the page's
#: side (at the density that would fill the page) cut across into slabs, and the densest
#: packing of all is kept (hbake/stages/parameterize.py). Measured with `hbake bake` on the
#: shared models (docs/guides/baking.md, "The atlas"): 1 cuts only the charts that cannot fit the page
#: (hammer 41.6 -> 61.5 %), 0.5 and 0.3 gain on terrain-like and organic parts; finer
#: cuts only add padding.
PACK_SPLIT_FRACTIONS = (1.0, 0.5, 0.3)
#: A packing is accepted only when every chart of at least PACK_DENSITY_MIN_CHART_TEXELS2
#: texels^2 has at least this fraction of the requested texel density (linear): xatlas
#: shrinks charts that do not fit its page on their own (see hbake/stages/parameterize.py).
#: Charts it does not shrink keep their density to about 2 % (measured on a 160 mm bar;
#: they come out slightly denser), so 0.97 passes them and refuses the 8x shrink
#: measured on the rasp as well as a 10 % one.
PACK_MIN_DENSITY_RATIO = 0.97
PACK_DENSITY_MIN_CHART_TEXELS2 = 64.0

# --- cage bake -----------------------------------------------------------------------------
#: Rays from the coarse surface reach at most this fraction of the bbox diagonal;
#: farther (or no) hits fall back to the closest point. The coarse meshes of the shared
#: models deviate from the full mesh by at most ~3 percent of the diagonal (measured
#: Hausdorff distances at 600 faces), so 5 percent keeps every genuine hit.
DEFAULT_MAX_RAY_DISTANCE_REL = 0.05
#: Texels whose centre lies within this distance (texels, Euclidean) of a UV triangle are
#: baked from that triangle (extrapolated past its edges): a bilinear lookup at a point
#: inside a UV triangle reads texels at Chebyshev distance < 1, i.e. Euclidean < sqrt(2).
BAKE_BORDER_TEXELS = 1.5
#: A texel centre counts as inside a UV triangle (coverage 1) when all its barycentric
#: coordinates are >= -this (a texel centre on a shared edge belongs to both triangles;
#: the lower triangle id wins).
INSIDE_EPS = 1e-9
#: Rays of border texels reach at most this many texel sizes (see hbake/stages/atlas.py).
#: A border texel's origin is extrapolated past its triangle's edge by at most this many
#: texel sizes per texel of UV distance. A well-shaped triangle maps one texel to about
#: one texel size, so the cap only bites on needle UV triangles, whose affine map
#: explodes across the needle (measured: barycentrics of 1.7e6 on the ridged block's
#: coarse mesh put border texels at the block's far corner, 36 mm away).
BORDER_STRETCH_TEXELS = 2.0
BORDER_RAY_TEXELS = 4.0
#: Two 4-neighbour texels whose points are more than this many texel sizes apart are a
#: discontinuity: no bilinear lookup interpolates across them (the runtime does not use a
#: 2x2 quad with such an edge). Why 4: the full surface's step per texel is sqrt(1 + s^2)
#: times the coarse one for a slope s, 3.9 at 75 degrees.
DISCONTINUITY_TEXELS = 4.0
#: The bake moves texels (hbake/stages/atlas.py, repair_jumps) whose edge midpoints to uncut
#: neighbours lie farther than this many texel sizes off the full surface. Why half a
#: texel: a lookup where the relief is resolved strays by at most about half a texel step
#: (the atlas samples once per texel, Sec. 7.2); a chord farther off is a jump, not relief.
JUMP_REPAIR_TEXELS = 0.5
#: The choice of wall (hit along +normal or -normal) is made for the texels within
#: JUMP_LABEL_RINGS texels of an off edge by a minimum cut: an off edge between a +hit and
#: a -hit costs JUMP_LABEL_EDGE, a texel's hit costs JUMP_LABEL_UNARY per texel size that
#: it lies farther than the nearer one (a tie-break: a wall switch may move up to about
#: EDGE / (UNARY * gap) rows to where the walls are within a texel or farther apart than
#: the cut length).
JUMP_LABEL_RINGS = 12
JUMP_LABEL_EDGE = 1000
JUMP_LABEL_UNARY = 10.0
#: Rounds of the repair (each moves both checkerboard colours once), and the least
#: improvement (texel sizes) of a texel's worst offset for a move to be kept.
JUMP_REPAIR_ITERATIONS = 16
JUMP_REPAIR_GAIN_TEXELS = 1e-3
#: UV triangles with twice their area below this (texels^2) are skipped by the bake.
UV_DEGENERATE_TEXELS2 = 1e-9
#: Rays are traced in chunks of this many texels (bounded memory, progress updates).
RAY_CHUNK = 1 << 18
#: Default gutter width (texels, Chebyshev) of docs/bundle-format.md.
DEFAULT_GUTTER = 4
DEFAULT_COMPRESSION = "zip"

# --- decompose -----------------------------------------------------------------------------
#: CoACD parameters. Threshold, resolutions and depth are CoACD's defaults; the tree
#: search is narrowed from CoACD's 20 nodes x 150 iterations to 10 x 50: on the 600-face
#: coarse meshes of rocker_arm.obj and fandisk.obj this cuts CoACD's CPU time from 19.6 s
#: to 9.0 s and from 24.7 s to 15.8 s for 37 instead of 34 and 33 instead of 30 pieces
#: (CoACD dominates the bake time of CAD parts; the bake's budget is 30 s for 650k triangles).
DEFAULT_COACD_THRESHOLD = 0.05
DEFAULT_COACD_PREPROCESS_RESOLUTION = 50
DEFAULT_COACD_RESOLUTION = 2000
DEFAULT_COACD_MCTS_NODES = 10
DEFAULT_COACD_MCTS_ITERATIONS = 50
DEFAULT_COACD_MCTS_MAX_DEPTH = 3
#: A coarse triangle belongs to a piece when it lies within this fraction of the coarse
#: bbox diagonal of the piece's hull. CoACD's hulls contain the surface they were cut
#: from, so the tolerance only absorbs float32 storage and qhull round-off; 1e-3 also
#: adds the neighbours that touch a piece along a cut.
DEFAULT_MAP_TOLERANCE_REL = 1e-3
#: Convexity tolerance of the spec (docs/bundle-format.md): a piece vertex may lie in front
#: of a face plane of its piece by at most CONVEX_TOLERANCE_REL * bbox_diagonal +
#: CONVEX_TOLERANCE_ABS metres. The relative part covers the float32 rounding of the stored
#: positions (2^-24 ~ 6e-8 relative to the coordinates, which are within about one bbox
#: diagonal of the origin for bundles that are not far off-centre); the absolute part keeps
#: tiny models from demanding exactness.
CONVEX_TOLERANCE_REL = 1e-6
CONVEX_TOLERANCE_ABS = 1e-9

# --- quality -------------------------------------------------------------------------------
#: Samples per direction of the reconstruction error (at least 100k).
DEFAULT_QUALITY_SAMPLES = 100_000
MIN_QUALITY_SAMPLES = 1_000
#: Sec. 7.2: the atlas represents relief down to a wavelength of two texels.
MIN_WAVELENGTH_TEXELS = 2.0
#: Relief is reported as finer than the atlas can hold when the full surface strays
#: from the baked surface by more than this many texel sizes (p95) ...
RELIEF_WARN_P95_TEXELS = 0.5
#: ... and the full mesh has edges shorter than the shortest representable wavelength.

# --- seeds ---------------------------------------------------------------------------------
DEFAULT_SEED = 0

# --- the parameterization-preserving route (hbake/routes/preserve.py) -----------------------------
#: Proxy size whose charts are carried to the full mesh; 0 = simplify.target_faces (the
#: proxy is then the cage route's coarse mesh, whose xatlas charts take well under a second).
DEFAULT_PRESERVE_PROXY_FACES = 0
#: xatlas padding of the proxy's charts (texels): a folded coarse UV triangle leaves its
#: chart by up to 2.7 texels (measured on the wrinkled torus at 2,000 triangles), so 6
#: keeps it 3 texels clear of the next chart (the cage route's default is 2).
DEFAULT_PRESERVE_PADDING = 6
#: meshoptimizer's weight of the UVs (as lengths on the surface, with the part scaled to
#: PRESERVE_FRAME_DIAGONAL) against positions: 1 weighs a texel of UV error like a texel
#: of position error on a part whose largest side is that diagonal.
DEFAULT_PRESERVE_UV_WEIGHT = 1.0
#: The preserve route collapses its proxy and charts it (pymeshlab, xatlas) with the part
#: scaled to this bounding-box diagonal (the factor is not a power of two: it is exactly
#: diagonal / this), then scales the proxy back and multiplies the texel density by the
#: same factor. Both libraries have absolute thresholds that SIMPLIFY_MIN_DIAGONAL and
#: XATLAS_MIN_MEDIAN_FACE_AREA only keep away from small parts; above them the proxy
#: still changed with the unit: hammer_scan.obj (diagonal 8.78 file units) collapsed at
#: 0.0878 m (--units cm) gave another proxy than at 0.223, 8.78 or (at 4x) 0.0351 m, 18
#: charts instead of 16 (one a single triangle), and its bake was refused. Scaled to one
#: diagonal, the four units give the same proxy faces (vertices within 1e-16 diagonal).
#: meshoptimizer's collapse sees the part in the same frame (its UV weight against
#: positions depends on the unit of both). 1 m: within the range where pymeshlab's
#: collapse was seen to be stable (SIMPLIFY_MIN_DIAGONAL), large enough that xatlas's
#: FLT_EPSILON-scale tolerances stay far below a proxy face, and close to the size at
#: which the UV weight was tuned (the wrinkled torus, 0.2 m, given in m).
PRESERVE_FRAME_DIAGONAL = 1.0
#: Closest faces are searched among this many nearest centroids (exact on the proxy's and
#: the full mesh's well-shaped triangles; more costs time linearly).
PRESERVE_NEAREST_FACES = 16
#: --method auto takes the preserve route when it reaches the target and both
#: reconstruction errors (p95) are within this many of its texel sizes: the texture's own
#: resolution (half a texel is the relief warning's level, one texel the off-surface bound
#: of the preserve route's tests).
DEFAULT_AUTO_MAX_ERROR_TEXELS = 1.0
#: Reruns of meshoptimizer with the vertices of pinched edges locked (one sufficed on
#: every model measured; more only costs time).
PRESERVE_PINCH_ROUNDS = 2
#: Samples per direction of the reconstruction error on which --method auto chooses:
#: fewer than the quality stage's 100,000 (a p95 needs far fewer, and auto measures two
#: routes), seeded like it.
AUTO_SAMPLES = 20_000
#: Seeded sample points per coarse face (besides corners and edge midpoints) at which the
#: preserve route checks that its UV lies inside its chart, and how far outside (texels)
#: counts as leaving it (float32 UVs are exact to 1e-4 texel on a 1024 atlas).
PRESERVE_CONTAIN_SAMPLES = 16
PRESERVE_CONTAIN_TEXELS = 1e-3
