"""Outliers and jumps: the bake's repair of jumps between
neighbouring texels (hbake/stages/atlas.py, repair_jumps) on a case with a known answer, and
format 1.1's compatibility with 1.0.

The test on the shared models' bundles (every reconstructed point within a texel of the
full surface) is tests/hbake/stages/test_bake_models.py::test_atlas_outliers, which reuses that
module's bakes.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from hbake import constants as C
from hbake.stages.atlas import repair_jumps, texel_edges
from hbake.bundle import FORMAT_VERSION, manifest_bytes, read_bundle, validate_bundle

GOLDEN = Path(__file__).resolve().parents[2] / "golden"
TX = 1e-3            # texel size of the synthetic case (m)


def _wall(z: float, lo: float, cells: int, size: float, offset: int):
    """A square wall at height z: cells x cells squares of ``size`` from (lo, lo), two
    triangles each (a mesh like a scan's, not two huge triangles: MeshLab's closest-point
    grid is built for those)."""
    i, j = np.meshgrid(np.arange(cells + 1), np.arange(cells + 1), indexing="ij")
    V = np.stack([lo + i.ravel() * size, lo + j.ravel() * size, np.full(i.size, z)], axis=1)
    a = (i[:-1, :-1] * (cells + 1) + j[:-1, :-1]).ravel()
    b, c, d = a + (cells + 1), a + (cells + 1) + 1, a + 1
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]) + offset
    return V, F


def _wall_triangle(x, y, lo: float, cells: int, size: float):
    """Index (within one wall) of the triangle of _wall under (x, y)."""
    u, v = (x - lo) / size, (y - lo) / size
    ci, cj = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    cell = ci * cells + cj
    return np.where(v - cj <= u - ci, cell, cells * cells + cell)


def _two_walls(gap_texels: float, n: int = 32, slope: float = 0.15):
    """Two parallel walls z = 0 and z = gap and an n x n texel grid whose coarse points
    rise across the medial plane along x, rays along +-z: the nearest hit switches walls at
    the medial line, where two neighbours are ``gap`` apart and their chord's midpoint is
    gap / 2 off both walls."""
    g = gap_texels * TX
    lo, size = -8.3 * TX, 3.7 * TX
    cells = int(np.ceil((n + 16) * TX / size))
    Vb, Fb = _wall(0.0, lo, cells, size, 0)
    Vt, Ft = _wall(g, lo, cells, size, len(Vb))
    V, F = np.concatenate([Vb, Vt]), np.concatenate([Fb, Ft[:, ::-1]])
    ys, xs = np.nonzero(np.ones((n, n), dtype=bool))
    z = 0.5 * g + (xs - n / 2 + 0.5) * slope * TX
    up = np.stack([xs * TX, ys * TX, np.full(len(xs), g)], axis=1)
    down = np.stack([xs * TX, ys * TX, np.zeros(len(xs))], axis=1)
    use_neg = z < 0.5 * g                   # nearer wall below
    tri = _wall_triangle(xs * TX, ys * TX, lo, cells, size)
    points = np.where(use_neg[:, None], down, up)
    alt = np.where(use_neg[:, None], up, down)
    prim = np.where(use_neg, tri, len(Fb) + tri).astype(np.int64)
    alt_prim = np.where(use_neg, len(Fb) + tri, tri).astype(np.int64)
    chart = np.zeros(len(xs), dtype=np.int64)
    return V, F, points, prim, alt, alt_prim, use_neg, ys, xs, chart, n, g


def _chords(points, ys, xs, chart, n, g):
    e = texel_edges(ys, xs, chart, n, n)
    p, q = points[e[:, 0]], points[e[:, 1]]
    length = np.linalg.norm(p - q, axis=1)
    mid = 0.5 * (p + q)
    off = np.minimum(np.abs(mid[:, 2]), np.abs(mid[:, 2] - g))    # exact: two planes
    return length, off


@pytest.mark.parametrize("gap", [2.5, 3.5])
def test_repair_two_walls(gap):
    """A wall switch whose chord is 1.25-1.75 texels off the surface (and shorter than the
    4-texel rule, so no reader would cut it) is repaired: afterwards every uncut chord is
    within the repair threshold of the surface, every texel is still on a wall, the
    manifest's counts say so, and the result is the same on a second run."""
    V, F, points, prim, alt, alt_prim, use_neg, ys, xs, chart, n, g = _two_walls(gap)
    length, off = _chords(points, ys, xs, chart, n, g)
    rule = C.DISCONTINUITY_TEXELS * TX
    before = int(np.sum((length <= rule) & (off > C.JUMP_REPAIR_TEXELS * TX)))
    assert before == n                      # one switch per row, all uncut and off
    runs = []
    for _ in range(2):
        pts, pr = points.copy(), prim.copy()
        info = repair_jumps(pts, pr, alt, alt_prim, use_neg, ys, xs, chart, n, n, TX, V, F)
        runs.append((pts, info))
    pts, info = runs[0]
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]
    # every texel on one of the walls (the full surface)
    assert np.all(np.minimum(np.abs(pts[:, 2]), np.abs(pts[:, 2] - g)) < 1e-12)
    length, off = _chords(pts, ys, xs, chart, n, g)
    uncut = length <= rule
    assert np.all(off[uncut] <= C.JUMP_REPAIR_TEXELS * TX + 1e-12), off[uncut].max() / TX
    assert info["off_before"] == before and info["off_after"] == 0
    assert info["cut"] == int(np.sum(~uncut)) and info["texels_moved"] > 0
    assert info["max_off_texels"] <= C.JUMP_REPAIR_TEXELS + 1e-9


def test_repair_leaves_good_texels_alone():
    """Walls within a texel: the switch's chord is on the surface within the threshold,
    nothing is moved."""
    V, F, points, prim, alt, alt_prim, use_neg, ys, xs, chart, n, g = _two_walls(0.8)
    pts = points.copy()
    info = repair_jumps(pts, prim.copy(), alt, alt_prim, use_neg, ys, xs, chart, n, n, TX, V, F)
    assert np.array_equal(pts, points)
    assert info["off_before"] == 0 and info["texels_moved"] == 0 and info["cut"] == 0


def test_format_1_0_still_read(tmp_path):
    """hbake writes 1.1's fields (atlas.discontinuities, quality.reconstruction.
    coarse_to_full_uncut); a 1.0 bundle (the golden bundle with those fields removed,
    version 1.0 and pieces.ply in the layout of 1.0-1.2) validates and reads, and so does
    a later 1.x with a field it does not know."""
    import hashlib
    import sys

    sys.path.insert(0, str(GOLDEN))
    dont_write, sys.dont_write_bytecode = sys.dont_write_bytecode, True  # no __pycache__ in tests/golden
    try:
        from make_golden import write_pieces_ply_1_2
    finally:
        sys.path.remove(str(GOLDEN))
        sys.dont_write_bytecode = dont_write
    assert FORMAT_VERSION == "1.3"
    src = GOLDEN / "pebble.hbundle"
    m = read_bundle(src).manifest
    assert m["format_version"] == "1.3" and "discontinuities" in m["atlas"]
    for version, edit in (("1.0", "drop"), ("1.7", "extra")):
        dst = tmp_path / f"v{version}.hbundle"
        shutil.copytree(src, dst)
        man = json.loads((dst / "manifest.json").read_text())
        man["format_version"] = version
        if edit == "drop":
            del man["atlas"]["discontinuities"]
            del man["quality"]["reconstruction"]["coarse_to_full_uncut"]
            write_pieces_ply_1_2(dst / "pieces.ply", src / "pieces.ply")
            blob = (dst / "pieces.ply").read_bytes()
            man["files"]["pieces"].update(sha256=hashlib.sha256(blob).hexdigest(), bytes=len(blob))
        else:
            man["atlas"]["a_later_field"] = {"x": 1}
        (dst / "manifest.json").write_bytes(manifest_bytes(man))
        assert validate_bundle(dst) == [], version
        assert read_bundle(dst).manifest["format_version"] == version
