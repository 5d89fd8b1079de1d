"""Haptic-session harness: the real chain.

Meshes are baked with ``hbake bake`` (tests/fullsurface.py's cached bake), scene files
(docs/scene-format.md) and device trajectories (docs/trajectory-format.md) are written
here, ``hrt run --lockstep`` runs them, and the tests read its trace
(docs/trace-format.md, through tests/trace.py) and device log.

Models (meters):
* the textured plate, the grating block, the bumpy sphere and the untextured box of the
  full-surface harness (tests/fullsurface.py);
* ``strip``: a long grating for the sliding tests: ridges at 23 degrees to x (not a
  multiple of 45), wavelength STRIP_L = 4 mm (4.35 mm along x), amplitude 0.1 mm,
  96 x 10 mm, 0.125 mm cells (32 per wavelength);
* ``fine_strip``: the same grating at FINE_L = 0.8 mm (0.1 mm cells, 8 per wavelength),
  amplitude 0.05 mm, 66 x 8 mm, for the sound of a slide (tests/integration/test_sound.py);
* ``tip``: a smooth sphere of radius 4 mm (its coarse mesh is curved), the ball tip
  that slides over the strip;
* ``block``: an untextured 12 x 8 x 4 mm block and ``slab``, an untextured
  160 x 60 x 6 mm plate (the tilted-plate friction test); both centred on their origin.
"""
from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import trimesh

import fullsurface as FS
from hbake.lab import procedural as P

REPO = FS.REPO
MM = 1e-3

STRIP_L = 4 * MM
STRIP_A = 0.1 * MM
STRIP_ANGLE = 23.0
STRIP_SIZE = (96 * MM, 10 * MM)
STRIP_CELL = 0.125 * MM
STRIP_THICK = 3 * MM
FINE_L = 0.8 * MM
FINE_A = 0.05 * MM
FINE_SIZE = (66 * MM, 8 * MM)
FINE_CELL = 0.1 * MM
TIP_R = 4 * MM
BLOCK = (12 * MM, 8 * MM, 4 * MM)
SLAB = (160 * MM, 60 * MM, 6 * MM)


def grating_height(x, y, wavelength=STRIP_L, amplitude=STRIP_A):
    """Height of a strip grating: ridges at STRIP_ANGLE to x on a STRIP_THICK slab."""
    a = math.radians(STRIP_ANGLE)
    s = np.asarray(x) * math.cos(a) + np.asarray(y) * math.sin(a)
    return STRIP_THICK + amplitude * np.sin(2 * np.pi * s / wavelength)


def strip_height(x, y):
    return grating_height(x, y)


def make_grating_strip(size, cell, wavelength, amplitude) -> trimesh.Trimesh:
    xs = np.linspace(0.0, size[0], int(round(size[0] / cell)) + 1)
    ys = np.linspace(0.0, size[1], int(round(size[1] / cell)) + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return P._finish(P._heightfield_block(xs, ys, grating_height(X, Y, wavelength, amplitude), np.zeros_like(X)))


def make_strip() -> trimesh.Trimesh:
    return make_grating_strip(STRIP_SIZE, STRIP_CELL, STRIP_L, STRIP_A)


def make_fine_strip() -> trimesh.Trimesh:
    return make_grating_strip(FINE_SIZE, FINE_CELL, FINE_L, FINE_A)


def make_tip() -> trimesh.Trimesh:
    ico = trimesh.creation.icosphere(subdivisions=4, radius=TIP_R)
    return P._finish(trimesh.Trimesh(ico.vertices, ico.faces, process=False))


def make_block() -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=BLOCK)
    return P._finish(trimesh.Trimesh(b.vertices, b.faces, process=False))


def make_slab() -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=SLAB)
    return P._finish(trimesh.Trimesh(b.vertices, b.faces, process=False))


OWN = {"strip": make_strip, "fine_strip": make_fine_strip, "tip": make_tip, "block": make_block, "slab": make_slab}


def bake(name: str, root: Path) -> FS.Model:
    return FS.bake_model(name, root, OWN.get(name))


# ----------------------------------------------------------------------------
# Scene files, trajectories, runs
# ----------------------------------------------------------------------------


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (str, Path)):
        return json.dumps(str(v))
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML for {v!r}")


def scene_toml(tables: dict) -> str:
    """A scene file from {table: {key: value}}; a list of dicts is an array of tables
    (``object``, ``material``)."""
    out = []
    for name, body in tables.items():
        rows = body if isinstance(body, list) else [body]
        for row in rows:
            out.append(f"[[{name}]]" if isinstance(body, list) else f"[{name}]")
            out += [f"{k} = {_toml_value(v)}" for k, v in row.items()]
            out.append("")
    return "\n".join(out)


def quat(axis, angle) -> list:
    """[x, y, z, w] of a rotation by `angle` (rad) about `axis`."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    return [*(a * math.sin(angle / 2)), math.cos(angle / 2)]


def quat_mul(q1, q2) -> list:
    x1, y1, z1, w1 = q1
    x2, y2, z2, w2 = q2
    return [w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2]


def rotate(q, p) -> np.ndarray:
    x, y, z, w = q
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    return R @ np.asarray(p, float)


def write_trajectory(path: Path, times, positions, quats) -> Path:
    """A trajectory CSV (docs/trajectory-format.md)."""
    positions = np.asarray(positions, float).reshape(len(times), 3)
    quats = np.asarray(quats, float).reshape(len(times), 4)
    with open(path, "w") as f:
        f.write("t,x,y,z,qx,qy,qz,qw\n")
        for t, p, q in zip(times, positions, quats):
            f.write(",".join(repr(float(v)) for v in (t, *p, *q)) + "\n")
    return path


def hrt_binary() -> str:
    import hrt_locate
    return hrt_locate.hrt_binary("hrt run sessions")


def run_scene(folder: Path, name: str, tables: dict, *args, timeout=900) -> dict:
    """Write folder/name.toml, run `hrt run --lockstep --json` on it, return the summary
    (``trace`` and ``device_log`` hold the read files when the scene writes them)."""
    import trace as T
    folder.mkdir(parents=True, exist_ok=True)
    scene = folder / f"{name}.toml"
    scene.write_text(scene_toml(tables))
    cmd = [hrt_binary(), "run", str(scene), "--json", *args]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if res.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)}: exit {res.returncode}: {res.stderr[-2000:]}")
    out = json.loads(res.stdout)
    tr = tables.get("trace", {})
    if tr.get("path"):
        out["trace_rows"] = T.read_trace(tr["path"])
    if tr.get("device_log"):
        out["device_rows"] = T.read_device_log(tr["device_log"])
    return out


if __name__ == "__main__":
    import sys
    import time
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/sess")
    for n in sys.argv[2:] or list(OWN):
        t = time.perf_counter()
        m = bake(n, root)
        print(n, len(m.mesh.faces), "->", len(m.coarse_faces), f"{time.perf_counter() - t:.1f} s", m.bundle)
