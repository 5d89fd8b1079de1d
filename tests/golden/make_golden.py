"""Regenerate the golden bundles, their expected values and the corrupted variants.

    .venv/bin/python tests/golden/make_golden.py

Builds three tiny procedural inputs here (numpy + trimesh, no random state outside
fixed seeds), bakes each with ``hbake.bake`` into ``tests/golden/<name>.hbundle``,
writes ``<name>.expected.json`` (atlas texels, bilinear lookups at listed UVs and
surface samples, all computed with ``hbake.bundle.atlas_lookup``; layout in
docs/bundle-format.md, "Golden bundles"), and writes the corrupted variants of the
smallest bundle into ``tests/golden/corrupt/`` with tests/corrupt.py.

It also writes ``tests/golden/format-1.2/ridged_box_pp.hbundle``: the ridged block baked
by ``--method pp`` and stored as format 1.2 (pieces.ply's map as one variable-length
list per piece, the layout before 1.3), byte for byte what hbake's 1.2 writer made, so
that the readers (``hbake validate``, the runtime) keep being tested on a 1.2 bundle.

The C++ runtime's tests read the same files, so rerun this only on purpose (a
format or pipeline change), and commit the results together.
"""
from __future__ import annotations

import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

import trimesh  # noqa: E402

from hbake.bundle import atlas_lookup, read_bundle, validate_bundle  # noqa: E402

MM = 1e-3

#: Tolerance (m) for comparing positions read through the atlas with the expected
#: values. The values are float64 bilinear combinations of float32 texels; a float32
#: implementation (the C++ runtime) differs by a few ulps of the coordinates (< 1e-8 m
#: for these 40 mm parts) plus the float32 rounding of x = u W - 0.5 (about 1e-5 texel,
#: times a texel-to-texel change below 2 mm: < 2e-8 m). 1e-6 m leaves a 50x margin and
#: is still 1000x below a texel (about 1 mm), so a wrong convention (v flip, missing
#: half-texel shift, swapped W and H) cannot pass.
POSITION_TOL = 1e-6


# --------------------------------------------------------------------------- inputs

def _grid_faces(nx: int, ny: int, offset: int, up: bool) -> np.ndarray:
    """Two triangles per cell of an (nx+1) x (ny+1) vertex grid (index = i * (ny+1) + j),
    counter-clockwise seen from +z (up) or -z."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    a = (i * (ny + 1) + j).ravel() + offset
    b, c, d = a + (ny + 1), a + (ny + 1) + 1, a + 1
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return tris if up else tris[:, ::-1]


def ridged_box() -> trimesh.Trimesh:
    """40 x 30 x 12 mm block whose top carries ridges along x (period 5 mm in y,
    amplitude 0.4 mm), faded out over 3 mm at the top's border so the sides stay
    planar. Top and bottom are 32 x 24 grids (1.25 mm cells: 4 per ridge period),
    joined by one-segment side strips: 3,296 triangles, closed, outward CCW."""
    nx, ny = 32, 24
    x = np.linspace(-20 * MM, 20 * MM, nx + 1)
    y = np.linspace(-15 * MM, 15 * MM, ny + 1)
    gx, gy = np.meshgrid(x, y, indexing="ij")
    wx = np.clip((20 * MM - np.abs(gx)) / (3 * MM), 0, 1)
    wy = np.clip((15 * MM - np.abs(gy)) / (3 * MM), 0, 1)
    top_z = 6 * MM + 0.4 * MM * np.sin(2 * np.pi * gy / (5 * MM)) * wx * wy
    top = np.stack([gx, gy, top_z], axis=-1).reshape(-1, 3)
    bottom = np.stack([gx, gy, np.full_like(gx, -6 * MM)], axis=-1).reshape(-1, 3)
    n = len(top)
    faces = [_grid_faces(nx, ny, 0, up=True), _grid_faces(nx, ny, n, up=False)]
    # boundary loop of the grid, counter-clockwise seen from +z
    loop = ([(i, 0) for i in range(nx)] + [(nx, j) for j in range(ny)]
            + [(i, ny) for i in range(nx, 0, -1)] + [(0, j) for j in range(ny, 0, -1)])
    ids = np.array([i * (ny + 1) + j for i, j in loop])
    nxt = np.roll(ids, -1)
    # side quad (top k, top k+1, bottom k+1, bottom k), outward for a CCW loop
    faces.append(np.stack([ids, nxt + n, nxt], 1))
    faces.append(np.stack([ids, ids + n, nxt + n], 1))
    mesh = trimesh.Trimesh(np.concatenate([top, bottom]), np.concatenate(faces), process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    return mesh


def bumpy_blob() -> trimesh.Trimesh:
    """An ellipsoid (radii 24 x 16 x 12 mm) with four Gaussian bumps at asymmetric
    places and a low ripple: no symmetry plane, so a swapped axis or a flipped v
    shows. 5,120 triangles, closed, outward CCW."""
    s = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    d = np.asarray(s.vertices)
    centres = np.array([[0.8, 0.3, 0.5], [-0.5, 0.7, -0.2], [0.1, -0.6, 0.8], [-0.7, -0.4, -0.6]])
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    heights = np.array([0.18, 0.12, -0.10, 0.15])
    widths = np.array([0.25, 0.35, 0.3, 0.2])
    r = 1.0 + np.sum(heights * np.exp(-np.sum((d[:, None, :] - centres) ** 2, axis=2) / widths ** 2), axis=1)
    r += 0.02 * np.sin(9 * d[:, 0] + 2 * d[:, 2]) * np.cos(7 * d[:, 1])
    v = d * r[:, None] * np.array([24, 16, 12]) * MM
    mesh = trimesh.Trimesh(v, s.faces, process=True)
    assert mesh.is_watertight and mesh.volume > 0
    return mesh


def pebble() -> trimesh.Trimesh:
    """A small pebble (radii 10 x 7 x 5 mm) with one bump and one dent, 1,280
    triangles: the smallest golden bundle, source of the corrupted variants."""
    s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    d = np.asarray(s.vertices)
    r = (1.0 + 0.15 * np.exp(-np.sum((d - [0.6, 0.64, 0.48]) ** 2, axis=1) / 0.2)
         - 0.08 * np.exp(-np.sum((d - [-0.8, 0.0, -0.6]) ** 2, axis=1) / 0.15))
    v = d * r[:, None] * np.array([10, 7, 5]) * MM
    mesh = trimesh.Trimesh(v, s.faces, process=True)
    assert mesh.is_watertight and mesh.volume > 0
    return mesh


#: name -> (mesh builder, settings overrides). Small atlases and coarse meshes keep the
#: files to tens of kB; the blob's atlas is non-square (96 x 64), and so is the pebble's.
GOLDEN = {
    "ridged_box": (ridged_box, {"simplify.target_faces": 48, "parameterize.atlas_width": 64,
                                "parameterize.atlas_height": 64}),
    "bumpy_blob": (bumpy_blob, {"simplify.target_faces": 60, "parameterize.atlas_width": 96,
                                "parameterize.atlas_height": 64}),
    "pebble": (pebble, {"simplify.target_faces": 24, "parameterize.atlas_width": 40,
                        "parameterize.atlas_height": 24}),
}
#: The corrupted variants are made from this one (the smallest: 12 copies of it).
CORRUPT_SOURCE = "pebble"


# --------------------------------------------------------------------------- expected values

def _f32(x) -> list:
    """Values as float64 numbers that are exactly float32 (so a float reader gets them)."""
    return np.asarray(x, dtype=np.float32).astype(np.float64).tolist()


def expected_values(path: Path, seed: int = 7) -> dict:
    b = read_bundle(path)
    atlas = b.atlas
    h, w = atlas.shape[:2]
    rng = np.random.default_rng(seed)
    v = b.coarse_vertices
    f = b.coarse_faces.astype(np.int64)
    uvs = b.coarse_uvs.astype(np.float64)

    # raw texels: the image corners, covered texels, gutter texels (filled but not
    # covered) and, if any, empty texels
    cov = atlas[:, :, 3] == 1
    texels = [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)]
    for mask, k in ((cov, 6), (~cov & np.any(atlas[:, :, :3] != 0, axis=2), 3),
                    (~cov & np.all(atlas[:, :, :3] == 0, axis=2), 1)):
        jj, ii = np.nonzero(mask)
        if len(ii):
            for s in rng.choice(len(ii), size=min(k, len(ii)), replace=False):
                texels.append((int(ii[s]), int(jj[s])))
    texel_rows = [{"i": i, "j": j, "rgba": atlas[j, i].astype(np.float64).tolist()} for i, j in texels]

    # lookups: inside UV triangles (random barycentrics), near their edges, at
    # covered texel centres, and anywhere in [0, 1]^2 (gutters, empty space, clamping)
    uv_list = []
    for t in rng.choice(len(f), size=10, replace=len(f) < 10):
        uv_list.append(rng.dirichlet([2, 2, 2]) @ uvs[t])
    for t in rng.choice(len(f), size=4, replace=len(f) < 4):
        bary = np.array([0.02, rng.uniform(0.1, 0.88), 0.0])
        bary[2] = 1 - bary[:2].sum()
        uv_list.append(bary @ uvs[t])
    jj, ii = np.nonzero(cov)
    for s in rng.choice(len(ii), size=4, replace=False):
        uv_list.append([(ii[s] + 0.5) / w, 1 - (jj[s] + 0.5) / h])
    uv_list += list(rng.uniform(0, 1, size=(3, 2))) + [[0.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
    uv_arr = np.asarray(_f32(uv_list))
    lookups = [{"uv": uv.tolist(), "rgba": val.tolist()}
               for uv, val in zip(uv_arr, atlas_lookup(atlas, uv_arr))]

    # surface samples: a coarse surface point (triangle + barycentrics), its UV, the
    # baked full-resolution point and its height along the coarse face normal
    samples = []
    tris = np.sort(rng.choice(len(f), size=min(16, len(f)), replace=False))
    for t in tris:
        bary = rng.dirichlet([3, 3, 3])
        bary = np.asarray(_f32(bary))
        bary[2] = 1.0 - bary[0] - bary[1]
        uv = bary @ uvs[t]
        p = bary @ v[f[t]]
        n = np.cross(v[f[t, 1]] - v[f[t, 0]], v[f[t, 2]] - v[f[t, 0]])
        n /= np.linalg.norm(n)
        pos = atlas_lookup(atlas, uv)[:3]
        samples.append({"triangle": int(t), "barycentrics": bary.tolist(), "uv": uv.tolist(),
                        "coarse_point": p.tolist(), "normal": n.tolist(), "position": pos.tolist(),
                        "height": float(np.dot(pos - p, n))})

    m = b.manifest
    return {
        "bundle": path.name,
        "format_version": m["format_version"],
        "atlas": {"width": w, "height": h},
        "coarse": {"vertices": len(v), "triangles": len(f)},
        "pieces": {"count": len(b.piece_vertices),
                   "coarse_faces": [np.asarray(m).astype(int).tolist() for m in b.piece_coarse_faces]},
        "tolerance": {
            "position": POSITION_TOL,
            "note": "metres; applies to lookups (all four channels), positions and heights. "
                    "Float64 bilinear of float32 texels; a float32 reader stays within 2e-8 m.",
        },
        "texels": texel_rows,
        "lookups": lookups,
        "surface_samples": samples,
    }


# --------------------------------------------------------------------------- main

def bake_one(name: str, out_dir: Path) -> Path:
    from hbake import bake
    from hbake.settings import BakeSettings

    build, overrides = GOLDEN[name]
    settings = BakeSettings().with_overrides({"load.units": "m", **overrides}, source="make_golden")
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / f"{name}.ply"
        build().export(src)
        out = out_dir / f"{name}.hbundle"
        if out.exists():
            shutil.rmtree(out)
        bake(src, out, settings)
    problems = validate_bundle(out)
    if problems:
        raise SystemExit(f"{out}: invalid golden bundle: {problems[0]}")
    return out


#: The bundle kept in format 1.2 (see the module's docstring): name, its folder.
LEGACY = ("ridged_box", "format-1.2")


def write_pieces_ply_1_2(path: Path, maps_from: Path) -> None:
    """Rewrite ``path`` (a 1.3 pieces.ply) in the layout of 1.0-1.2: the same vertices
    and faces, then per piece a uint32 count and its coarse_faces (``maps_from`` is the
    1.3 file, read with hbake's reader)."""
    import struct

    from hbake.bundle import read_pieces_ply

    v, vid, f, fid, maps = read_pieces_ply(maps_from)
    blob = maps_from.read_bytes()
    off = blob.index(b"end_header\n") + len(b"end_header\n")
    header = blob[:off].decode("ascii").split("\n")
    assert header[2] == "comment hbundle pieces 1.3" and header[-4].startswith("element piece_coarse_face ")
    header = header[:2] + ["comment hbundle pieces 1.0"] + header[3:-6] + [
        f"element piece {len(maps)}", "property list uint uint coarse_faces", "end_header", ""]
    body = blob[off:off + 16 * len(v) + 17 * len(f)]
    lists = b"".join(struct.pack("<I", len(m)) + np.asarray(m, "<u4").tobytes() for m in maps)
    path.write_bytes("\n".join(header).encode("ascii") + body + lists)


def bake_legacy(out_dir: Path = HERE) -> Path:
    """``<out_dir>/format-1.2/ridged_box_pp.hbundle`` (module docstring)."""
    import hashlib

    from hbake import bake
    from hbake.bundle import manifest_bytes
    from hbake.settings import BakeSettings

    name, folder = LEGACY
    build, overrides = GOLDEN[name]
    dest = out_dir / folder
    dest.mkdir(exist_ok=True)
    out = dest / f"{name}_pp.hbundle"
    if out.exists():
        shutil.rmtree(out)
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / f"{name}.ply"
        build().export(src)
        new = Path(tmp) / "new.hbundle"
        bake(src, new, BakeSettings().with_overrides(
            {"load.units": "m", **overrides, "method": "pp"}, source="make_golden"))
        shutil.copytree(new, out)
        write_pieces_ply_1_2(out / "pieces.ply", new / "pieces.ply")
    m = json.loads((out / "manifest.json").read_text())
    blob = (out / "pieces.ply").read_bytes()
    m["format_version"] = "1.2"
    m["files"]["pieces"].update(sha256=hashlib.sha256(blob).hexdigest(), bytes=len(blob))
    (out / "manifest.json").write_bytes(manifest_bytes(m))
    problems = validate_bundle(out)
    if problems:
        raise SystemExit(f"{out}: invalid 1.2 bundle: {problems[0]}")
    return out


def main(out_dir: Path = HERE) -> None:
    import corrupt

    for name in GOLDEN:
        out = bake_one(name, out_dir)
        exp = expected_values(out)
        (out_dir / f"{name}.expected.json").write_text(json.dumps(exp, indent=2, sort_keys=True) + "\n")
        size = sum(p.stat().st_size for p in out.iterdir())
        print(f"{out.name}: {exp['coarse']['triangles']} triangles, atlas {exp['atlas']['width']}x"
              f"{exp['atlas']['height']}, {exp['pieces']['count']} pieces, {size} bytes")
    dest = out_dir / "corrupt"
    if dest.exists():
        shutil.rmtree(dest)
    corrupt.write_variants(out_dir / f"{CORRUPT_SOURCE}.hbundle", dest)
    print(f"{dest}: {len(corrupt.VARIANTS)} corrupted variants of {CORRUPT_SOURCE}.hbundle")
    legacy = bake_legacy(out_dir)
    exp = expected_values(legacy)
    (legacy.parent / f"{legacy.stem}.expected.json").write_text(json.dumps(exp, indent=2, sort_keys=True) + "\n")
    print(f"{legacy}: format {exp['format_version']}")


if __name__ == "__main__":
    main()
