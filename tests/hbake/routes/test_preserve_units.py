"""The preserve route does not depend on the unit a mesh is given in.

The same file baked with ``--units mm`` and ``--units m`` (a factor of 1000) must give the
same coarse mesh (triangle count, and triangles in the same UV places) with the texel size
scaled by the unit ratio. Before the route worked in a frame scaled to a fixed diagonal,
pymeshlab's proxy collapse, xatlas's charts and meshoptimizer's UV weight all changed with
the unit; the shared models' hammer_scan.obj baked with --units cm was refused (a coarse UV
triangle of no area on a chart outline read texels outside the gutter) while in, mm and m
passed.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from hbake.lab.bench import shared_models_dir
from hbake.stages.load import load_mesh
from hbake.routes.preserve import bake_preserve, degenerate_footprints
from hbake.settings import BakeSettings

#: $HBAKE_MODELS, else ../shared/models beside the repository (the project's one setting).
HAMMER = shared_models_dir() / "hammer_scan.obj"

#: The texel sizes of the two units, each divided by its unit, agree to this ratio. The
#: texel size is the median over covered texels of sqrt(3D area / UV area) of their coarse
#: triangle; with the same coarse mesh and UVs, the only difference is the float32
#: rounding of the stored coarse vertices (2^-24 relative) and of the UVs, so 1e-5 is
#: far above what rounding does and far below what another coarse mesh or packing
#: changes (the old unit-dependent bakes of the hammer differed by 2e-3 relative).
TEXEL_RATIO_TOL = 1e-5


def _bumpy_sphere() -> trimesh.Trimesh:
    """A closed, bumpy, elongated sphere (20,480 triangles, diagonal about 8.8 file units,
    like hammer_scan.obj): relief in every direction, so the proxy has several charts."""
    s = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    v = np.asarray(s.vertices, dtype=np.float64)
    bump = 1.0 + 0.06 * np.sin(7 * v[:, 0]) * np.sin(5 * v[:, 1]) * np.sin(6 * v[:, 2] + 0.3)
    v = v * bump[:, None] * np.array([1.5, 0.6, 4.0])
    return trimesh.Trimesh(v, np.asarray(s.faces), process=False)


def _bake(path: Path, unit: str, **overrides):
    s = BakeSettings(method="pp").with_overrides({"load.units": unit, **overrides})
    full = load_mesh(path, s.load)
    return bake_preserve(full.vertices, full.faces, s, input_closed=full.closed)


def _check_same_bake(a, b, ratio: float):
    assert len(a.coarse.faces) == len(b.coarse.faces)
    assert a.stats["proxy_charts"] == b.stats["proxy_charts"]
    # the same triangles, at the same places of the atlas
    assert np.array_equal(a.coarse.faces, b.coarse.faces)
    assert np.allclose(a.param.uvs, b.param.uvs, atol=1e-6)
    assert a.baked.coverage == pytest.approx(b.baked.coverage, abs=1e-6)
    assert b.baked.texel_size / a.baked.texel_size == pytest.approx(ratio, rel=TEXEL_RATIO_TOL)
    assert b.param.texels_per_unit * ratio == pytest.approx(a.param.texels_per_unit, rel=TEXEL_RATIO_TOL)


def test_bumpy_sphere_mm_and_m_give_the_same_coarse_mesh(tmp_path):
    path = tmp_path / "bumpy.ply"
    _bumpy_sphere().export(path)
    ov = {"simplify.target_faces": 300, "parameterize.atlas_width": 256,
          "parameterize.atlas_height": 256}
    mm = _bake(path, "mm", **ov)
    m = _bake(path, "m", **ov)
    assert len(m.coarse.faces) <= 300
    _check_same_bake(mm, m, 1000.0)


def test_zero_area_uv_triangle_footprint_is_baked():
    """A coarse UV triangle of no area (three seam vertices on one outline segment) has
    its footprint baked and counted in the distance, so the gutter covers what its
    lookups read."""
    W = H = 32
    # texel centres (x, y) -> uv: x = u W - 0.5, y = (1 - v) H - 0.5
    seg = np.array([[4.0, 10.0], [20.0, 10.0], [12.0, 10.0]])
    uv = np.stack([(seg[:, 0] + 0.5) / W, 1.0 - (seg[:, 1] + 0.5) / H], axis=1)[None]
    tri_of = np.full((H, W), -1, dtype=np.int64)
    bary = np.zeros((H, W, 3))
    dist = np.full((H, W), np.inf)
    added = degenerate_footprints(uv, tri_of, bary, dist, W, H)
    assert added > 0
    # every texel a bilinear lookup on the segment reads (Chebyshev <= 1) is baked from it,
    # within sqrt(2) of it, and never counted as covered
    assert (tri_of[9:12, 3:22] == 0).all()
    assert (dist[9:12, 3:22] <= np.sqrt(2.0) + 1e-9).all()
    assert (bary[tri_of == 0] == -1.0).all()


@pytest.mark.slow
def test_hammer_cm_and_m_give_the_same_coarse_mesh():
    if not HAMMER.exists():
        if os.environ.get("CI"):
            pytest.fail(f"{HAMMER} is missing (CI is set)")
        pytest.skip(f"{HAMMER} is absent")
    cm = _bake(HAMMER, "cm")
    m = _bake(HAMMER, "m")
    _check_same_bake(cm, m, 100.0)
