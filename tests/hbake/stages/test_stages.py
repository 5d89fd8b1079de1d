"""Unit tests of the baking stages (hbake.stages.load, settings, atlas, mass, geometry,
decompose, parameterize) against independent references: closed forms, brute force,
analytic surfaces. Tolerances are stated and justified next to each assertion."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import trimesh

from hbake import constants as C
from hbake.errors import (ConfigError, HbakeError, InputInvalidError, InputMissingError,
                          OutputExistsError, OutputUnwritableError)
from hbake.settings import SECTIONS, BakeSettings, describe, parse_value

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))


# ------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------
def write_obj(path: Path, vertices, faces) -> Path:
    """OBJ with 1-based faces; faces may be polygons (lists of any length)."""
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def bumpy_sphere(subdiv=4, amp=0.02, freq=6, radius=0.05) -> trimesh.Trimesh:
    """Closed sphere with smooth relief (radius modulated by products of sines)."""
    s = trimesh.creation.icosphere(subdivisions=subdiv, radius=1.0)
    v = s.vertices
    r = radius * (1 + amp * np.sin(freq * v[:, 0]) * np.sin(freq * v[:, 1]) * np.sin(freq * v[:, 2] + 1))
    return trimesh.Trimesh(v * r[:, None], s.faces, process=False)


@pytest.fixture(scope="module")
def small_model(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("model") / "bumpy.ply"
    bumpy_sphere().export(path)
    return path


SMALL = {"simplify.target_faces": 120, "parameterize.atlas_width": 128,
         "parameterize.atlas_height": 96, "quality.samples": 2000, "load.units": "m",
         "decompose.mcts_iterations": 20, "decompose.resolution": 500}


# ------------------------------------------------------------------------------------------
# load and repair
# ------------------------------------------------------------------------------------------
def test_repair_counts_and_result(tmp_path):
    from hbake.stages.load import load_mesh

    # a unit tetrahedron written with a duplicated vertex, a degenerate face (repeated
    # vertex), a duplicate face (reversed winding), an unused vertex and a quad face
    # (a square pyramid base: the quad is split into two triangles by the reader).
    v = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 0.5, 1),   # pyramid
         (1, 0, 0),            # 5: duplicate of 1
         (7, 7, 7)]            # 6: unused
    f = [[0, 3, 2, 1],         # quad base, outward (-z)
         [0, 5, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4],
         [0, 1, 1],            # degenerate
         [4, 1, 0]]            # duplicate of [0, 1, 4] (reversed)
    path = write_obj(tmp_path / "pyramid.obj", v, f)
    warnings = []
    m = load_mesh(path, warn=warnings.append)
    assert len(m.vertices) == 5
    assert len(m.faces) == 6                     # 2 base + 4 sides
    assert m.closed and m.bodies == 1 and m.boundary_edges == 0
    assert m.repair["merged_vertices"] == 1
    assert m.repair["degenerate_faces"] == 1
    assert m.repair["duplicate_faces"] == 1
    assert m.name == "pyramid.obj" and len(m.sha256) == 64
    assert m.source_unit == "unknown" and m.scale_to_meters == 1.0
    assert any("records no unit" in w and "1 x 1 x 1 m" in w for w in warnings)
    # outward: positive signed volume 1/3 * base * height
    from hbake.stages.geometry import signed_volumes
    assert signed_volumes(m.vertices, m.faces).sum() == pytest.approx(1 / 3, rel=1e-12)


def test_units_and_inside_out(tmp_path):
    from hbake.stages.load import load_mesh

    box = trimesh.creation.box(extents=[10, 20, 30])
    box.invert()                                   # inside-out on purpose
    path = tmp_path / "box.stl"
    box.export(path)                               # binary STL
    from hbake.settings import LoadSettings
    m = load_mesh(path, LoadSettings(units="mm"))
    assert m.source_unit == "mm" and m.scale_to_meters == 1e-3
    assert np.allclose(m.vertices.max(axis=0) - m.vertices.min(axis=0), [0.01, 0.02, 0.03])
    assert m.repair["flipped_bodies"] == 1
    from hbake.stages.geometry import signed_volumes
    assert signed_volumes(m.vertices, m.faces).sum() == pytest.approx(6e-6, rel=1e-9)
    # glTF fixes the unit: meters, no warning about units
    glb = tmp_path / "box.glb"
    trimesh.creation.box().export(glb)
    warnings = []
    g = load_mesh(glb, warn=warnings.append)
    assert g.source_unit == "m" and not any("unit" in w for w in warnings)


@pytest.mark.parametrize("fmt", ["obj", "ply", "stl", "off"])
def test_formats_roundtrip(tmp_path, fmt):
    from hbake.stages.load import load_mesh

    s = trimesh.creation.icosphere(2)
    path = tmp_path / f"s.{fmt}"
    s.export(path)
    m = load_mesh(path)
    assert len(m.faces) == len(s.faces) and m.closed
    assert abs(np.abs(m.vertices).max() - 1.0) < 1e-6


def test_ascii_stl(tmp_path):
    from hbake.stages.load import load_mesh

    path = tmp_path / "a.stl"
    trimesh.creation.box().export(path, file_type="stl_ascii")
    assert path.read_text().startswith("solid")
    m = load_mesh(path)
    assert len(m.faces) == 12 and m.closed


def test_open_and_multibody_warn(tmp_path):
    from hbake.stages.load import load_mesh

    a = trimesh.creation.box()
    b = trimesh.creation.box()
    b.apply_translation([3, 0, 0])
    two = trimesh.util.concatenate([a, b])
    path = tmp_path / "two.ply"
    two.export(path)
    w = []
    m = load_mesh(path, warn=w.append)
    assert m.bodies == 2 and m.closed
    assert any("2 separate bodies" in x for x in w)
    open_ = trimesh.Trimesh(a.vertices, a.faces[:-2], process=False)
    path = tmp_path / "open.ply"
    open_.export(path)
    w = []
    m = load_mesh(path, warn=w.append)
    assert not m.closed and m.boundary_edges == 4
    assert any("not closed" in x for x in w)


@pytest.mark.parametrize("case, error, text", [
    ("missing", InputMissingError, "no such file"),
    ("empty", InputInvalidError, "empty"),
    ("garbage", InputInvalidError, ""),
    ("nan", InputInvalidError, "NaN"),
    ("degenerate", InputInvalidError, "nothing left after repair"),
    ("extension", InputInvalidError, "unsupported file type"),
    ("directory", InputMissingError, "directory"),
])
def test_bad_inputs(tmp_path, case, error, text):
    from hbake.stages.load import load_mesh

    if case == "missing":
        path = tmp_path / "nope.obj"
    elif case == "empty":
        path = tmp_path / "e.obj"
        path.write_text("")
    elif case == "garbage":
        path = tmp_path / "g.stl"
        path.write_bytes(np.random.default_rng(1).integers(0, 256, 3000, dtype=np.uint8).tobytes())
    elif case == "nan":
        path = write_obj(tmp_path / "n.obj", [(0, 0, 0), (1, 0, 0), (float("nan"), 1, 0)], [[0, 1, 2]])
    elif case == "degenerate":
        path = write_obj(tmp_path / "d.obj", [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)],
                         [[0, 1, 2], [1, 2, 3]])
    elif case == "extension":
        path = tmp_path / "m.xyz"
        path.write_text("1 2 3\n")
    else:
        path = tmp_path / "dir.obj"
        path.mkdir()
    with pytest.raises(error) as info:
        load_mesh(path)
    msg = str(info.value)
    assert "\n" not in msg and text in msg
    assert path.name in msg


def test_duplicate_faces_and_fins():
    """Same-winding copies collapse to one face; opposite-winding pairs (a fin) cancel."""
    from hbake.stages.load import _drop_duplicate_faces

    f = np.array([[0, 1, 2], [1, 2, 0], [2, 1, 0],      # net +1: keep the first
                  [3, 4, 5], [5, 4, 3],                 # fin: both go
                  [6, 7, 8], [8, 7, 6], [7, 6, 8],      # net -1: keep [8, 7, 6]
                  [9, 10, 11]])
    assert _drop_duplicate_faces(f).tolist() == [[0, 1, 2], [8, 7, 6], [9, 10, 11]]
    assert _drop_duplicate_faces(f, cancel_fins=False).tolist() == [
        [0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11]]
    # a box whose simplification left a fin (an extra reversed copy of a face plus the
    # face itself): cancelling the pair would open it, keeping one copy closes it
    from hbake.stages.geometry import is_closed
    from hbake.stages.load import repair_mesh
    b = trimesh.creation.box()
    faces = np.vstack([b.faces, b.faces[:1], b.faces[:1, ::-1]])     # net: one copy
    v, f2, counts = repair_mesh(b.vertices, faces, cancel_fins=True)
    assert counts["duplicate_faces"] == 2 and len(f2) == 12 and is_closed(f2)


def test_degenerate_is_shape_relative():
    """Tiny but well-shaped faces survive (planetary_gears.stl has them); needles go."""
    from hbake.stages.load import degenerate_faces

    s = 1e-6
    v = np.array([[0, 0, 0], [s, 0, 0], [0, s, 0], [1, 0, 0], [2, 0, 1e-12], [3, 0, 0]], float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    assert degenerate_faces(v, f).tolist() == [False, True]


# ------------------------------------------------------------------------------------------
# settings and configs
# ------------------------------------------------------------------------------------------
def test_configs_map_one_to_one():
    """Every configs/*.toml names every setting exactly once and nothing else."""
    assert {p.name for p in CONFIGS} >= {"default.toml", "cad.toml", "scan.toml"}
    want = BakeSettings().to_dict()
    for path in CONFIGS:
        data = tomllib.loads(path.read_text())
        assert set(data) == set(want), path.name
        for section in SECTIONS:
            assert set(data[section]) == set(want[section]), (path.name, section)
        s = BakeSettings.from_toml(path)
        assert s.to_dict() == json.loads(json.dumps(data)), path.name   # lossless
    assert BakeSettings.from_toml(ROOT / "configs" / "default.toml") == BakeSettings()


def test_describe_documents_every_field():
    rows = describe()
    keys = {k for k, _, _ in rows}
    flat = {f"{s}.{k}" if isinstance(v, dict) else s
            for s, v in BakeSettings().to_dict().items()
            for k in (v if isinstance(v, dict) else [None])}
    assert keys == flat
    assert all(doc for _, _, doc in rows)


@pytest.mark.parametrize("text, message", [
    ("bogus = 1", "unknown setting 'bogus'"),
    ("[simplify]\ntarget_face = 3", "unknown setting 'target_face'"),
    ("[simplify]\ntarget_faces = '600'", "expected int"),
    ("[simplify]\ntarget_faces = 2", "must be >= 4"),
    ("[atlas]\ncompression = 'zstd'", "not one of zip, piz"),
    ("[atlas]\ngutter = true", "expected int"),
    ("[cage]\nmax_ray_distance = nan", "not finite"),
    ("method = 'magic'", "not one of cage, pp"),
    ("[load]\nunits = 'km'", "not one of"),
    ("simplify = 3", "must be a table"),
    ("[simplify", "not valid TOML"),
])
def test_config_errors(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text + "\n")
    with pytest.raises(ConfigError) as info:
        BakeSettings.from_toml(path)
    assert message in str(info.value) and "bad.toml" in str(info.value)


def test_overrides_and_precedence(tmp_path):
    from hbake.cli.main import build_settings

    cfg = tmp_path / "c.toml"
    cfg.write_text("seed = 5\n[simplify]\ntarget_faces = 800\n[atlas]\ngutter = 6\n")
    s = build_settings(cfg, ["simplify.target_faces=900", "atlas.compression=piz"],
                       gutter=7, atlas_size=(512, 256))
    assert s.seed == 5 and s.simplify.target_faces == 900 and s.atlas.gutter == 7
    assert s.atlas.compression == "piz"
    assert (s.parameterize.atlas_width, s.parameterize.atlas_height) == (512, 256)
    with pytest.raises(ConfigError):
        build_settings(None, ["nokey"])
    with pytest.raises(ConfigError):
        build_settings(None, ["simplify.nokey=1"])
    assert parse_value("1e-3") == 1e-3 and parse_value("abc") == "abc"
    # int given where a float is wanted is accepted and stored as float
    assert BakeSettings().with_overrides({"cage.max_ray_distance": 1}).cage.max_ray_distance == 1.0


def test_settings_are_frozen_and_validated():
    s = BakeSettings()
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.seed = 3
    from hbake.settings import ParameterizeSettings
    with pytest.raises(ConfigError):
        ParameterizeSettings(padding=1)


# ------------------------------------------------------------------------------------------
# geometry
# ------------------------------------------------------------------------------------------
def test_closest_point_on_triangles_matches_dense_sampling():
    """Brute-force reference vs a dense barycentric grid on the triangle (edges and
    corners included): the grid's minimum can only be larger, by at most the grid step
    (longest edge / n)."""
    from hbake.stages.geometry import closest_point_on_triangles
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    tri = np.array([[0.1, 0.0, 0.0], [1.0, 0.2, 0.1], [0.3, 0.9, -0.2]])
    q = rng.normal(size=(3000, 3))
    cp, bary = closest_point_on_triangles(q, tri[0], tri[1], tri[2])
    assert np.allclose(bary.sum(axis=1), 1) and (bary >= -1e-12).all()
    assert np.allclose(np.einsum("nk,kd->nd", bary, tri), cp)
    n = 500
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    b1, b2 = i[keep] / n, j[keep] / n
    dense = np.outer(1 - b1 - b2, tri[0]) + np.outer(b1, tri[1]) + np.outer(b2, tri[2])
    dd, _ = cKDTree(dense).query(q)
    gap = dd - np.linalg.norm(cp - q, axis=1)
    step = np.linalg.norm(tri - np.roll(tri, 1, axis=0), axis=1).max() / n
    assert gap.min() > -1e-12 and gap.max() < step


def test_closest_points_matches_brute_force():
    from hbake.stages.geometry import closest_point_on_triangles, closest_points

    s = bumpy_sphere(subdiv=3)
    v, f = s.vertices, s.faces
    rng = np.random.default_rng(0)
    q = rng.normal(scale=0.06, size=(500, 3))
    cp, d = closest_points(v, f, q)
    tri = v[f]
    ref, _ = closest_point_on_triangles(q[:, None], tri[None, :, 0], tri[None, :, 1], tri[None, :, 2])
    dref = np.linalg.norm(ref - q[:, None], axis=2).min(axis=1)
    assert np.abs(d - dref).max() < 1e-12


def test_closed_and_components():
    from hbake.stages.geometry import boundary_edge_count, face_components, is_closed

    b = trimesh.creation.box()
    assert is_closed(b.faces) and boundary_edge_count(b.faces) == 0
    flipped = b.faces.copy()
    flipped[0] = flipped[0][::-1]                  # inconsistent winding: not closed
    assert not is_closed(flipped)
    assert boundary_edge_count(b.faces[1:]) == 3
    two = np.vstack([b.faces, b.faces + 8])
    assert face_components(two, 16)[0] == 2


def test_winding_numbers():
    from hbake.stages.geometry import winding_numbers

    s = trimesh.creation.icosphere(3)
    w = winding_numbers(np.array([[0, 0, 0], [0.5, 0.2, 0.1], [2, 0, 0], [0, 0, -1.5]]), s.vertices, s.faces)
    assert np.allclose(w, [1, 1, 0, 0], atol=1e-9)


# ------------------------------------------------------------------------------------------
# mass properties
# ------------------------------------------------------------------------------------------
def test_mass_box_closed_form():
    from hbake.stages.mass import polyhedron_mass_properties

    a, b, c = 0.1, 0.2, 0.3
    box = trimesh.creation.box(extents=[a, b, c])
    box.apply_translation([1.0, -2.0, 3.0])        # far from the origin on purpose
    vol, com, inertia = polyhedron_mass_properties(box.vertices, box.faces)
    m = a * b * c
    assert vol == pytest.approx(m, rel=1e-12)
    assert np.allclose(com, [1.0, -2.0, 3.0], atol=1e-14)
    expect = m / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    assert np.allclose(inertia, expect, rtol=1e-10, atol=1e-18)


def test_mass_sphere_closed_form():
    """An inscribed polyhedron converges to the sphere from below: the volume deficit of
    an icosphere with edge e is about (e / r)^2 / 4 relative (each facet's cap is ~1/4 of
    the squared chord ratio); subdivision 6 has e / r ~ 0.019, so 1e-4 is ample, and the
    inertia (r^5) errs by 5/3 of that."""
    from hbake.stages.mass import polyhedron_mass_properties

    r = 0.25
    s = trimesh.creation.icosphere(subdivisions=6, radius=r)
    vol, com, inertia = polyhedron_mass_properties(s.vertices, s.faces)
    v_exact = 4 / 3 * math.pi * r ** 3
    assert vol == pytest.approx(v_exact, rel=2e-4)
    assert np.abs(com).max() < 1e-12
    assert np.allclose(inertia, np.eye(3) * 2 / 5 * v_exact * r * r, rtol=4e-4, atol=1e-14)


def test_mass_rotated_box_vs_trimesh():
    """Off-diagonal terms: a rotated, translated box against trimesh's independent code
    and against R I R^T of the closed form."""
    from hbake.stages.mass import polyhedron_mass_properties

    a, b, c = 1.0, 2.0, 0.5
    box = trimesh.creation.box(extents=[a, b, c])
    R = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])
    R[:3, 3] = [0.3, 0.1, -0.2]
    box.apply_transform(R)
    vol, com, inertia = polyhedron_mass_properties(box.vertices, box.faces)
    m = a * b * c
    local = m / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    assert np.allclose(inertia, R[:3, :3] @ local @ R[:3, :3].T, atol=1e-12)
    assert np.allclose(inertia, box.moment_inertia, atol=1e-12)
    assert np.allclose(com, [0.3, 0.1, -0.2], atol=1e-14)


def test_mass_basis_fallbacks():
    from hbake.stages.mass import mass_properties

    s = trimesh.creation.icosphere(3)
    open_v, open_f = s.vertices, s.faces[:-5]
    mp = mass_properties(s.vertices, s.faces, True, s.vertices, s.faces, True)
    assert mp.basis == "full" and mp.closed
    mp = mass_properties(open_v, open_f, False, s.vertices, s.faces, True)
    assert mp.basis == "coarse" and not mp.closed
    mp = mass_properties(open_v, open_f, False, open_v, open_f, False)
    assert mp.basis == "hull"
    # the hull of the sphere's vertices is the closed icosphere itself
    assert mp.volume == pytest.approx(s.volume, rel=1e-12)


# ------------------------------------------------------------------------------------------
# atlas bake on an analytic case
# ------------------------------------------------------------------------------------------
def test_bake_flat_square_against_sine_heightfield():
    """Coarse mesh: the square [0, L]^2 at z = 0 (two triangles, UVs u = x / L, v = y / L).
    Full mesh: the height field z = A sin(2 pi x / lam) on a fine grid. Every normal is
    +z, so a texel at (x, y) must bake to (x, y, z_full(x, y)) exactly in x and y, and in z
    within the linear interpolation error of the full grid, A k^2 s^2 / 8 (k = 2 pi / lam,
    s = grid step). Lookups through the atlas between texels add the bilinear error of
    the texel grid, A k^2 t^2 / 8 (t = texel step)."""
    from hbake.stages.atlas import bake_atlas
    from hbake.bundle import atlas_lookup

    L, A, lam = 1.0, 0.02, 0.25
    W = H = 64
    cv = np.array([[0, 0, 0], [L, 0, 0], [L, L, 0], [0, L, 0]], float)
    cf = np.array([[0, 1, 2], [0, 2, 3]])
    uvs = (cv[cf][..., :2] / L).astype(np.float32)
    n = 200
    g = np.linspace(-0.1, L + 0.1, n + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = A * np.sin(2 * np.pi * X / lam)
    fv = np.stack([X, Y, Z], -1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    ff = np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    baked = bake_atlas(cv, cf, uvs, W, H, fv, ff)
    k = 2 * np.pi / lam
    s = g[1] - g[0]
    lin = A * k * k * s * s / 8
    img = baked.image
    # every texel centre of the square is covered: (i + 0.5) / W is inside [0, 1]
    assert baked.covered.all() and baked.coverage == 1.0 and baked.fallbacks == 0
    i, j = np.meshgrid(np.arange(W), np.arange(H), indexing="xy")
    x = (i + 0.5) / W * L
    y = (1 - (j + 0.5) / H) * L
    assert np.abs(img[..., 0] - x).max() < 1e-6          # float32 storage of ~1: 6e-8
    assert np.abs(img[..., 1] - y).max() < 1e-6
    assert np.abs(img[..., 2] - A * np.sin(k * x)).max() < lin + 1e-7
    assert np.all(img[..., 3] == 1)
    # texel size: L / W; displacement bounds: the sine's extremes (within lin)
    assert baked.texel_size == pytest.approx(L / W, rel=1e-6)
    assert baked.displacement_outward == pytest.approx(A, abs=lin + A * (k * L / W) ** 2)
    assert baked.displacement_inward == pytest.approx(A, abs=lin + A * (k * L / W) ** 2)
    # bilinear lookups at random UVs follow the analytic surface
    rng = np.random.default_rng(0)
    uv = rng.uniform(0.5 / W, 1 - 0.5 / W, size=(5000, 2))
    p = atlas_lookup(img, uv)
    t = L / W
    bil = A * k * k * t * t / 8
    assert np.abs(p[:, 2] - A * np.sin(k * uv[:, 0] * L)).max() < lin + bil + 1e-6


def test_bake_border_texels_and_gutter():
    """Texels within 1.5 of a UV triangle are baked from it (extrapolated along its
    plane); the rest of the gutter is dilated; texels beyond the gutter stay 0."""
    from hbake.stages.atlas import bake_atlas

    W = H = 64
    cv = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    cf = np.array([[0, 1, 2]])
    # UV triangle in the middle of the atlas: texels (20..40) in x and y
    uvs = (np.array([[[20, 44], [40, 44], [20, 24]]], float) / 64).astype(np.float32)
    full = trimesh.creation.box(extents=[4, 4, 0.2])
    full.apply_translation([0, 0, -0.1])           # top face at z = 0
    baked = bake_atlas(cv, cf, uvs, W, H, full.vertices, full.faces,
                       atlas=__import__("hbake.settings").settings.AtlasSettings(gutter=3))
    img = baked.image
    assert baked.baked.sum() > baked.covered.sum()            # border texels exist
    border = baked.baked & ~baked.covered
    # border texels lie on the plane of the triangle extended: z = 0, x, y linear in uv
    assert np.abs(img[border, 2]).max() < 1e-7
    from scipy.ndimage import distance_transform_cdt
    cheb = distance_transform_cdt(~baked.covered, metric="chessboard")
    filled = np.any(img[..., :3] != 0, axis=2) | baked.baked
    assert baked.gutter == 3                                   # no sliver tips here
    assert (filled[cheb <= 3]).all()                           # the gutter is filled
    assert not (filled & (cheb > 3) & ~baked.baked).any()     # beyond it: 0
    assert np.isfinite(img).all()


def test_border_texels_of_a_needle_stay_near_it():
    """A UV needle whose 3D triangle is well shaped: across the needle one texel maps to
    hundreds of texel sizes, and extrapolating its affine map 1.5 texels put border texels
    far off the part (measured on the ridged block: 36 mm on an 80 mm part, read by
    lookups next to the needle). The extrapolation is capped at BORDER_STRETCH_TEXELS
    texel sizes per texel, so every baked texel stays within
    BAKE_BORDER_TEXELS * BORDER_STRETCH_TEXELS texel sizes of the coarse surface."""
    from hbake.stages.atlas import bake_atlas

    W = H = 64
    cv = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    cf = np.array([[0, 1, 2], [1, 3, 2]])
    # texel coordinates (x, y); face 1's corner 3 sits 0.01 texel off the edge 1-2
    px = np.array([[[10, 42], [42, 42], [10, 10]],
                   [[42, 42], [26.007, 25.993], [10, 10]]], float)
    uvs = np.stack([(px[..., 0] + 0.5) / W, 1 - (px[..., 1] + 0.5) / H], -1).astype(np.float32)
    full = trimesh.creation.box(extents=[400, 400, 0.2])
    full.apply_translation([0, 0, -0.1])           # top face at z = 0, far beyond the square
    baked = bake_atlas(cv, cf, uvs, W, H, full.vertices, full.faces)
    texel = baked.texel_size
    assert texel == pytest.approx(1 / 32, rel=1e-6)
    needle = baked.baked & (baked.triangle == 1)
    assert needle.sum() > 10                       # the needle owns border texels
    p = baked.image[baked.baked, :2].astype(np.float64)
    outside = np.maximum(np.maximum(-p, p - 1), 0).max(axis=1)   # distance past the square
    reach = C.BAKE_BORDER_TEXELS * C.BORDER_STRETCH_TEXELS * texel
    assert outside.max() <= reach * (1 + 1e-6), (outside.max() / texel, "texel sizes")


def test_gutter_widens_for_sliver_tips():
    """A UV sliver whose tip runs many texels past the last covered texel: every texel a
    lookup inside it can read must lie within the (effective) gutter."""
    from hbake.stages.atlas import bake_atlas
    from hbake.bundle.uv_coverage import _footprint_texels
    from hbake.settings import AtlasSettings

    W = H = 64
    cv = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    cf = np.array([[0, 1, 2]])
    # 3 texels wide at the base, 40 texels long: the last 12 or so rows hold no centre
    uvs = (np.array([[[10.2, 60.0], [13.2, 60.0], [11.7, 20.0]]]) / 64).astype(np.float32)
    full = trimesh.creation.box(extents=[4, 4, 0.2])
    full.apply_translation([0, 0, -0.1])
    baked = bake_atlas(cv, cf, uvs, W, H, full.vertices, full.faces, atlas=AtlasSettings(gutter=2))
    from scipy.ndimage import distance_transform_cdt
    cheb = distance_transform_cdt(~baked.covered, metric="chessboard")
    ci, cj = _footprint_texels(uvs[0].astype(np.float64), W, H)
    assert cheb[cj, ci].max() > 2                  # the requested gutter is not enough
    assert baked.gutter == cheb[cj, ci].max() or baked.gutter >= cheb[cj, ci].max()
    assert baked.baked[cj, ci].all()


# ------------------------------------------------------------------------------------------
# stages on a small closed model: invariants and determinism
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def stages(small_model):
    from hbake.stages.atlas import bake_atlas
    from hbake.stages.decompose import decompose
    from hbake.stages.load import load_mesh
    from hbake.stages.parameterize import parameterize
    from hbake.stages.simplify import simplify

    s = BakeSettings().with_overrides(SMALL)

    def run():
        m = load_mesh(small_model, s.load)
        c = simplify(m.vertices, m.faces, s.simplify, input_closed=m.closed)
        p = parameterize(c.vertices, c.faces, s.parameterize)
        a = bake_atlas(c.vertices, c.faces, p.uvs, p.width, p.height, m.vertices, m.faces,
                       s.cage, s.atlas)
        d = decompose(c.vertices, c.faces, s.decompose, seed=s.seed)
        return m, c, p, a, d

    return s, run(), run()


def test_stages_are_deterministic(stages):
    _, (m1, c1, p1, a1, d1), (m2, c2, p2, a2, d2) = stages
    assert np.array_equal(m1.vertices, m2.vertices) and np.array_equal(m1.faces, m2.faces)
    assert np.array_equal(c1.vertices, c2.vertices) and np.array_equal(c1.faces, c2.faces)
    assert np.array_equal(p1.uvs, p2.uvs)
    assert np.array_equal(a1.image, a2.image)
    assert len(d1.vertices) == len(d2.vertices)
    for x, y in zip(d1.vertices + d1.faces + d1.coarse_faces, d2.vertices + d2.faces + d2.coarse_faces):
        assert np.array_equal(x, y)


def test_coarse_mesh_invariants(stages):
    s, (m, c, p, a, d), _ = stages
    from hbake.stages.geometry import signed_volumes
    from hbake.stages.simplify import coarse_is_valid

    assert c.closed and coarse_is_valid(c.vertices, c.faces)
    assert abs(len(c.faces) - s.simplify.target_faces) <= 4
    assert np.array_equal(c.vertices, c.vertices.astype(np.float32).astype(np.float64))
    assert signed_volumes(c.vertices, c.faces).sum() > 0


def test_parameterization_invariants(stages):
    s, (m, c, p, a, d), _ = stages
    from hbake.stages.parameterize import chart_labels, covered_triangles

    assert p.uvs.dtype == np.float32 and p.uvs.shape == (len(c.faces), 3, 2)
    assert p.uvs.min() >= 0 and p.uvs.max() <= 1
    assert (p.width, p.height) == (128, 96)                  # non-square, as asked
    assert p.packed_width <= 128 and p.packed_height <= 96
    charts = chart_labels(c.faces, p.uvs)
    has = np.zeros(charts.max() + 1, bool)
    has[charts[covered_triangles(p.uvs, p.width, p.height)]] = True
    assert has.all()                                          # every chart covers a texel


def test_one_texel_density_for_every_chart():
    """A long bar (160 x 20 x 6 mm, like the procedural rasp): xatlas shrinks the charts
    of the long faces to fit its page and leaves the end caps at the requested density
    (measured before the fix: end caps at 8x the faces' density). Every chart must get
    the density the packer settled on, less at most the 3 % it allows
    (C.PACK_MIN_DENSITY_RATIO)."""
    from hbake.stages.parameterize import chart_labels, parameterize, texel_coordinates
    from hbake.settings import ParameterizeSettings

    bar = trimesh.creation.box(extents=[0.16, 0.02, 0.006])
    res = parameterize(bar.vertices, bar.faces, ParameterizeSettings(atlas_width=256, atlas_height=256))
    px = texel_coordinates(res.uvs, 256, 256)
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    at = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    charts = chart_labels(bar.faces, res.uvs)
    assert charts.max() >= 1                                   # several charts
    density = np.sqrt(np.bincount(charts, at) / np.bincount(charts, bar.area_faces))
    # No chart below 97 % of the density the search settled on; none above it by more
    # than xatlas's own rounding (measured: +2.5 %).
    assert density.min() >= C.PACK_MIN_DENSITY_RATIO * res.texels_per_unit, density
    assert density.max() <= 1.05 * res.texels_per_unit, density
    # ... which is about the most that fits: the 160 mm faces across the 256-texel page
    # (the 3 % xatlas may shrink them by, and the rest of its rounding, on top).
    assert 0.8 * 256 / 0.16 <= res.texels_per_unit <= 1.05 * 256 / 0.16


def test_small_charts_snap_onto_a_texel_centre():
    from hbake.stages.parameterize import covered_triangles, snap_small_charts

    W = H = 32
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    # chart 0: a triangle between texel centres (x in 3.1..3.9, y in 5.1..5.9)
    # chart 1: a big triangle that covers centres (left alone)
    px = np.array([[[3.1, 5.1], [3.9, 5.2], [3.5, 5.9]], [[10, 10], [20, 10], [10, 20]]], float)
    uvs = np.stack([(px[..., 0] + 0.5) / W, 1 - (px[..., 1] + 0.5) / H], -1).astype(np.float32)
    assert covered_triangles(uvs, W, H).tolist() == [False, True]
    snapped = snap_small_charts(faces, uvs, W, H)
    assert covered_triangles(snapped, W, H).all()
    assert np.array_equal(snapped[1], uvs[1])
    shift = (snapped[0] - uvs[0]) * [W, H]
    assert np.abs(shift).max() <= 0.5 + 1e-4 and np.allclose(shift, shift[0], atol=1e-4)


def test_unmapped_sliver_attaches_to_its_neighbour():
    """xatlas parks slivers it cannot flatten at UV (0, 0); they get the UVs of the edge
    they share with a mapped neighbour (third corner: its projection onto that edge)."""
    from hbake.stages.parameterize import attach_unmapped_faces

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, -0.01, 0]], float)
    faces = np.array([[0, 1, 2], [1, 0, 3]])          # face 1: sliver below edge 0-1
    uvs = np.array([[[0.1, 0.1], [0.5, 0.1], [0.1, 0.5]], [[0, 0], [0, 0], [0, 0]]], np.float32)
    out = attach_unmapped_faces(v, faces, uvs, 64, 64)
    assert np.array_equal(out[0], uvs[0])
    assert np.allclose(out[1, 0], uvs[0, 1]) and np.allclose(out[1, 1], uvs[0, 0])
    assert np.allclose(out[1, 2], [0.2, 0.1])          # 1/4 of the way from vertex 0 to 1


def test_unmapped_cap_attaches_across_its_long_edge():
    """A cap (vertex 3 on the long edge 0-1 of face 2) has mapped neighbours across its
    long edge (face 0) and a short one (face 1). Attached across the short edge, its far
    corner would clamp to an end of that edge, 3/4 of the cap's length from where it is
    (measured on fandisk: lookups 30 texels from their coarse point); across the long
    edge every corner keeps its place along the edge."""
    from hbake.stages.parameterize import attach_unmapped_faces

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, -0.001, 0], [0.1, -0.5, 0]], float)
    faces = np.array([[0, 1, 2], [3, 0, 4], [0, 3, 1]])     # face 1 across the short edge 0-3
    uvs = np.array([[[0.1, 0.1], [0.5, 0.1], [0.1, 0.5]],
                    [[0.6, 0.6], [0.7, 0.6], [0.6, 0.7]],
                    [[0, 0], [0, 0], [0, 0]]], np.float32)
    out = attach_unmapped_faces(v, faces, uvs, 64, 64)
    assert np.allclose(out[2, 0], uvs[0, 0]) and np.allclose(out[2, 2], uvs[0, 1])
    assert np.allclose(out[2, 1], [0.2, 0.1])                # vertex 3: 1/4 along 0 -> 1


def test_lookups_stay_in_their_chart(stages):
    """Every texel a bilinear lookup inside a UV triangle reads was baked from a triangle
    of the same chart (no lookup crosses a seam)."""
    s, (m, c, p, a, d), _ = stages
    from hbake.bundle.uv_coverage import _footprint_texels
    from hbake.stages.parameterize import chart_labels

    charts = chart_labels(c.faces, p.uvs)
    for t in range(len(c.faces)):
        ci, cj = _footprint_texels(p.uvs[t].astype(np.float64), p.width, p.height)
        src = a.triangle[cj, ci]
        assert (src >= 0).all(), t
        assert (charts[src] == charts[t]).all(), t


def test_pieces_convex_outward_and_map_complete(stages):
    s, (m, c, p, a, d), _ = stages

    diag = float(np.linalg.norm(c.vertices.max(0) - c.vertices.min(0)))
    tol = C.CONVEX_TOLERANCE_REL * diag + C.CONVEX_TOLERANCE_ABS
    for v, f in zip(d.vertices, d.faces):
        assert len(v) >= 4 and len(f) >= 4
        assert np.array_equal(v, v.astype(np.float32).astype(np.float64))
        tri = v[f]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        centre = v.mean(axis=0)
        assert (np.einsum("ij,ij->i", n, tri[:, 0] - centre) > 0).all()   # outward
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        off = np.einsum("ij,ij->i", n, tri[:, 0])
        assert (v @ n.T - off).max() <= tol                               # convex
    covered = np.zeros(len(c.faces), int)
    for ids in d.coarse_faces:
        assert np.array_equal(ids, np.unique(ids))
        covered[ids] += 1
    # CoACD's pieces cover the closed coarse surface: every triangle maps to a piece
    assert (covered > 0).all()


def test_map_triangles_against_sampling():
    """The exact clipping test agrees with a dense point sample where the sample is
    conclusive: a triangle with a sample point inside the grown hull must be mapped, and
    a mapped triangle must come within tol (plus the plane-offset slack) of the hull."""
    from hbake.stages.decompose import hull_planes, map_triangles
    from hbake.stages.mass import convex_hull_mesh

    rng = np.random.default_rng(5)
    hv, hf = convex_hull_mesh(rng.normal(size=(40, 3)))
    tris = rng.uniform(-2.5, 2.5, size=(400, 3, 3))
    V = tris.reshape(-1, 3)
    F = np.arange(len(V)).reshape(-1, 3)
    tol = 0.05
    mapped = np.zeros(len(F), bool)
    mapped[map_triangles(V, F, [hv], [hf], tol)[0]] = True
    n, dd = hull_planes(hv, hf)
    bary = rng.dirichlet([1, 1, 1], 4000)
    pts = np.einsum("sk,tkd->tsd", bary, tris)
    inside = ((pts @ n.T - dd).max(axis=2) <= tol).any(axis=1)
    assert mapped[inside].all()
    assert 0 < mapped.sum() < len(F)


def test_pp_method_unreachable_leaves_nothing(tmp_path, small_model):
    """Method 'pp' (tests/integration/test_preserve.py): a target it cannot reach
    with every chart border locked is its own error and writes nothing."""
    from hbake.errors import TargetUnreachableError
    from hbake.routes.pipeline import bake

    s = BakeSettings(method="pp").with_overrides({"simplify.target_faces": 4,
                                                  "preserve.seams": "locked"})
    with pytest.raises(TargetUnreachableError, match="cannot reach 4 triangles"):
        bake(small_model, tmp_path / "x.hbundle", s)
    assert not (tmp_path / "x.hbundle").exists()


def test_output_checks(tmp_path, small_model):
    from hbake.routes.pipeline import bake

    (tmp_path / "there.hbundle").mkdir()
    with pytest.raises(OutputExistsError):
        bake(small_model, tmp_path / "there.hbundle")
    with pytest.raises(OutputUnwritableError):
        bake(small_model, tmp_path / "no" / "dir" / "x.hbundle")
    with pytest.raises(HbakeError, match=r"\.hbundle"):
        bake(small_model, tmp_path / "x.bundle")


def test_decompose_runs_alongside_and_reports(tmp_path, small_model, monkeypatch):
    """CoACD runs in a thread next to parameterize and bake: its failure reaches the caller
    as the same error (CLI exit 7) with nothing written, and its warnings land in the
    manifest after the bake's, in a fixed order, while it did run in another thread."""
    import threading

    import hbake.routes.cage as cage
    import hbake.routes.pipeline as pipeline
    from hbake.errors import BakeFailedError

    real = cage.decompose
    seen = {}

    def failing(*args, **kwargs):
        seen["thread"] = threading.current_thread().name
        raise BakeFailedError("convex decomposition (CoACD) failed: test")

    monkeypatch.setattr(cage, "decompose", failing)
    out = tmp_path / "x.hbundle"
    with pytest.raises(BakeFailedError, match="CoACD"):
        pipeline.bake(small_model, out)
    assert seen["thread"] != threading.main_thread().name
    assert not out.exists() and list(tmp_path.iterdir()) == []

    def warning(*args, **kwargs):
        pieces = real(*args, **kwargs)
        pieces.warnings.extend(["decompose warning 1", "decompose warning 2"])
        return pieces

    monkeypatch.setattr(cage, "decompose", warning)
    report = pipeline.bake(small_model, out)
    w = report["manifest"]["warnings"]
    assert w.index("decompose warning 1") + 1 == w.index("decompose warning 2")
    assert report["timings"]["decompose"] > 0


def test_pipeline_bake_is_byte_deterministic(tmp_path, small_model):
    """Two bakes of the same input and settings give byte-identical bundles, and the
    manifest records the settings, seeds and libraries."""
    from hbake.routes.pipeline import bake

    s = BakeSettings().with_overrides(SMALL)
    r1 = bake(small_model, tmp_path / "a.hbundle", s)
    bake(small_model, tmp_path / "b.hbundle", s)
    for name in ("manifest.json", "coarse.ply", "atlas.exr", "pieces.ply"):
        b1 = (tmp_path / "a.hbundle" / name).read_bytes()
        b2 = (tmp_path / "b.hbundle" / name).read_bytes()
        assert hashlib.sha256(b1).digest() == hashlib.sha256(b2).digest(), name
    m = r1["manifest"]
    assert m["settings"] == s.to_dict() and m["seeds"] == {"coacd": 0, "quality": 0}
    assert {"numpy", "pymeshlab", "xatlas", "coacd", "embreex"} <= set(m["libraries"])
    assert m["method"] == "cage" and m["atlas"]["width"] == 128 and m["atlas"]["height"] == 96
    assert set(r1["timings"]) == {"load", "simplify", "parameterize", "bake", "decompose",
                                  "mass", "quality", "write"}
    # the reconstruction is far below half a texel on this smooth model
    texel = m["atlas"]["texel_size"]
    for key in ("coarse_to_full", "full_to_coarse"):
        assert m["quality"]["reconstruction"][key]["p95"] < 0.5 * texel
    from hbake.bundle import validate_bundle
    assert validate_bundle(tmp_path / "a.hbundle") == []
