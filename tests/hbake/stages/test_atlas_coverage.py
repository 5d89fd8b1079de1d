"""How much of the atlas the charts cover, through the real ``hbake bake``.

One texel density for every chart (hbake/stages/parameterize.py) makes the longest chart set
the density of the whole atlas: a chart must fit the page whole. The hammer's handle
(four strips the length of the part) held the hammer at 41.6 % coverage and a 73.8 um
texel in cm; a 160 x 20 x 6 mm bar (the rasp's body) at 34 %. Charts longer than the
page are now cut across and the densest packing is kept (C.PACK_SPLIT_FRACTIONS), which
these tests hold in place.

The floors were fixed before the tests were written, from the bakes measured with the
change (docs/guides/baking.md, "The atlas"), with a margin for a future xatlas or chart rule:

* bar, 768 triangles, 256 x 256 atlas: 79.6 % measured, 34.0 % before; floor 70 %
  (12 % below the measured figure for a different packer's placement, still twice the
  coverage of the uncut packing);
* hammer_scan.obj in cm (slow, shared model): 61.6 % measured (60.2 um texel), 41.6 %
  before (73.8 um); floor 55 %.

Coverage is only worth having at one density per chart, so each test also checks that
every chart has the density of the manifest's texel size, and that the bundle validates
(the gutter around every chart included).
"""
from __future__ import annotations

import os

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from hbake import constants as C
from hbake.lab.bench import shared_models_dir
from hbake.bundle import read_coarse_ply, validate_bundle
from hbake.stages.parameterize import chart_labels, texel_coordinates

REPO = Path(__file__).resolve().parents[3]

BAR_FLOOR = 0.70
HAMMER_FLOOR = 0.55


def _bake(src: Path, out: Path, *args: str) -> dict:
    r = subprocess.run([sys.executable, "-m", "hbake.cli", "bake", str(src), "-o", str(out),
                        "--quiet", *args], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert validate_bundle(out) == []
    return json.loads((out / "manifest.json").read_text())


def _chart_densities(bundle: Path, width: int, height: int) -> np.ndarray:
    """Texels per meter of every chart of a bundle's coarse mesh (UV area / 3D area)."""
    v, f, uvs = read_coarse_ply(bundle / "coarse.ply")
    f = np.asarray(f, dtype=np.int64)
    tri = np.asarray(v, dtype=np.float64)[f]
    a3 = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    px = texel_coordinates(uvs, width, height)
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    at = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    charts = chart_labels(f, uvs)
    a3c, atc = np.bincount(charts, a3), np.bincount(charts, at)
    big = atc >= C.PACK_DENSITY_MIN_CHART_TEXELS2       # as the packer's own check
    return np.sqrt(atc[big] / a3c[big])


def _check_one_density(bundle: Path, atlas: dict) -> None:
    d = _chart_densities(bundle, atlas["width"], atlas["height"])
    # the manifest's texel size is a median over covered texels; every chart within the
    # packer's 3 % (and xatlas's rounding above) of it
    assert d.min() * atlas["texel_size"] >= C.PACK_MIN_DENSITY_RATIO * 0.99, d
    assert d.max() * atlas["texel_size"] <= 1.05, d


def test_long_bar_fills_the_atlas(tmp_path):
    bar = trimesh.creation.box(extents=[0.160, 0.020, 0.006]).subdivide().subdivide().subdivide()
    src = tmp_path / "bar.ply"
    bar.export(src)
    out = tmp_path / "bar.hbundle"
    m = _bake(src, out, "--units", "m", "--atlas-size", "256", "--target-faces", "300")
    atlas = m["atlas"]
    assert atlas["coverage"] >= BAR_FLOOR, atlas
    assert atlas["gutter"] >= C.DEFAULT_GUTTER
    _check_one_density(out, atlas)
    # the 160 mm faces no longer set the texel: finer than one 256th of the bar's length
    assert atlas["texel_size"] < 0.160 / 256, atlas


@pytest.mark.slow
def test_hammer_coverage(tmp_path):
    src = shared_models_dir() / "hammer_scan.obj"
    if not src.is_file():
        if os.environ.get("CI"):
            pytest.fail(f"{src} is missing (CI is set; set HBAKE_MODELS)")
        pytest.skip(f"{src} is missing (set HBAKE_MODELS)")
    out = tmp_path / "hammer.hbundle"
    m = _bake(src, out, "--units", "cm")
    atlas = m["atlas"]
    assert atlas["coverage"] >= HAMMER_FLOOR, atlas
    assert atlas["texel_size"] <= 65e-6, atlas          # 60.2 um measured, 73.8 um before
    _check_one_density(out, atlas)
