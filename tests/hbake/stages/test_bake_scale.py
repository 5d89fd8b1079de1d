"""A bake does not depend on the part's absolute size.

The same smooth sphere (icosphere of 1280 triangles, cut to the default 600) is baked at
radius 2 mm and, scaled by exactly 4, at 8 mm. Before hbake handed xatlas (and the
quadric collapse) small parts scaled up by a power of two, xatlas ignored the 2 mm
sphere's coarse faces as zero-area (its FLT_EPSILON area rule, in meters^2): 34 charts
instead of 7 and reconstruction errors of 2 texels (coarse->full p95) and 41 texels
(full->coarse p95), while the 8 mm sphere baked to 0.016 texel (measured with these
settings). See hbake/constants.py, XATLAS_MIN_MEDIAN_FACE_AREA and SIMPLIFY_MIN_DIAGONAL.

Bounds, fixed in advance:

* each reconstruction error (p95 both ways), in texel sizes, is below
  RELIEF_WARN_P95_TEXELS (half a texel), the threshold of the bake's own warning that the
  baked surface strays from the full one; the max is below one texel (a smooth sphere
  has no relief the atlas cannot hold, so no sample may stray by a texel);
* the two bakes agree in texels within a factor AGREE: the stages are scale-free and the
  quality samples are seeded identically (the same barycentric samples on the same
  faces), so the two errors in texels differ only by the float rounding of the stored
  positions (a few 1e-7 relative, 1e-4 texel at most); 1.1 leaves room for that
  and would fail by orders of magnitude on the old behaviour (ratios of about 140 and 2400);
* the 8 mm bundle is the 2 mm bundle times 4: same coarse faces and UVs, positions
  (coarse vertices, atlas texels) within float32 rounding (2^-23 relative to the part's
  size, twice for the two roundings). Power-of-two scaling is exact in floating point,
  so a scale-free bake gives that for any scale factor 2^j.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from hbake import bake
from hbake import constants as C
from hbake.lab import procedural as P
from hbake.bundle import read_bundle
from hbake.stages.parameterize import xatlas_scale
from hbake.settings import BakeSettings
from hbake.stages.simplify import collapse_scale

GOLDEN = Path(__file__).resolve().parents[2] / "golden"

RADIUS = 2e-3
FACTOR = 4.0            # exactly representable: the 8 mm mesh is the 2 mm mesh times 4
AGREE = 1.1
#: 256 x 256 atlas and 2000 samples per direction keep each bake near a second.
SETTINGS = {"load.units": "m", "quality.samples": 2000,
            "parameterize.atlas_width": 256, "parameterize.atlas_height": 256}


def _sphere(radius: float) -> trimesh.Trimesh:
    ico = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    return P._finish(trimesh.Trimesh(ico.vertices * radius, ico.faces, process=False))


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    out = {}
    d = tmp_path_factory.mktemp("scale")
    for name, r in (("small", RADIUS), ("large", FACTOR * RADIUS)):
        src = d / f"sphere_{name}.ply"
        _sphere(r).export(src)
        dst = d / f"sphere_{name}.hbundle"
        bake(src, dst, BakeSettings().with_overrides(SETTINGS, source="test_bake_scale"))
        out[name] = read_bundle(dst)
    return out


def _errors_in_texels(b) -> dict:
    m = b.manifest
    t = m["atlas"]["texel_size"]
    rec = m["quality"]["reconstruction"]
    return {f"{k} {s}": rec[k][s] / t for k in ("coarse_to_full", "full_to_coarse")
            for s in ("p95", "max")}


def test_errors_below_half_a_texel_at_both_scales(bundles):
    for name, b in bundles.items():
        e = _errors_in_texels(b)
        for key, val in e.items():
            bound = C.RELIEF_WARN_P95_TEXELS if key.endswith("p95") else 1.0
            assert val < bound, f"{name} sphere: {key} = {val:.3g} texel (bound {bound})"
        assert not any("strays" in w for w in b.manifest["warnings"]), b.manifest["warnings"]


def test_errors_in_texels_agree_between_scales(bundles):
    small, large = _errors_in_texels(bundles["small"]), _errors_in_texels(bundles["large"])
    for key in small:
        ratio = small[key] / large[key]
        assert 1 / AGREE < ratio < AGREE, f"{key}: {small[key]:.4g} vs {large[key]:.4g} texel"
    t_small = bundles["small"].manifest["atlas"]["texel_size"]
    t_large = bundles["large"].manifest["atlas"]["texel_size"]
    assert t_large / t_small == pytest.approx(FACTOR, rel=1e-6)


def test_bundle_scales_with_the_part(bundles):
    s, b = bundles["small"], bundles["large"]
    tol = 2 * 2.0 ** -23 * 2 * FACTOR * RADIUS        # float32 rounding at the part's size
    assert np.array_equal(s.coarse_faces, b.coarse_faces)
    assert np.array_equal(s.coarse_uvs, b.coarse_uvs)
    assert np.abs(FACTOR * s.coarse_vertices.astype(np.float64)
                  - b.coarse_vertices.astype(np.float64)).max() <= tol
    assert np.array_equal(s.atlas[..., 3], b.atlas[..., 3])          # coverage
    assert np.abs(FACTOR * s.atlas[..., :3].astype(np.float64)
                  - b.atlas[..., :3].astype(np.float64)).max() <= tol
    assert s.manifest["atlas"]["charts"] == b.manifest["atlas"]["charts"]


def test_parts_of_ordinary_size_are_not_rescaled():
    """The golden bundles' parts (26-63 mm) reach xatlas and the collapse unscaled, so they
    bake byte for byte as before the scale fix."""
    for path in sorted(GOLDEN.glob("*.hbundle")):
        b = read_bundle(path)
        v = b.coarse_vertices.astype(np.float64)
        f = b.coarse_faces.astype(np.int64)
        assert xatlas_scale(v, f) == 1.0, path.name
        assert json.loads((path / "manifest.json").read_text())["quality"]["bbox_diagonal"] \
            >= C.SIMPLIFY_MIN_DIAGONAL, path.name


def test_scales_are_powers_of_two_and_equivariant():
    m = _sphere(RADIUS)
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    for j in range(0, 5):
        s = 2.0 ** -j
        xs, cs = xatlas_scale(v * s, f), collapse_scale(v * s, f)
        assert xs == xatlas_scale(v, f) * 2.0 ** j
        assert cs == collapse_scale(v, f) * 2.0 ** j
    # a large part is never scaled (down or up)
    assert xatlas_scale(v * 100, f) == 1.0 and collapse_scale(v * 100, f) == 1.0
