"""`hbake texture`: relief synthesis by refinement and displacement.

Through the command (a child process, as a user runs it): the relief's heights against
the pattern's closed form, the adaptive refinement's edge bound, closed meshes staying
closed, determinism (the same bytes twice), and the errors: one line naming the file,
a distinct exit code, no output left behind.
"""
from __future__ import annotations

import hashlib
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

REPO = Path(__file__).resolve().parents[3]
MM = 1e-3
EXIT_TEXTURE = 20
#: MeshLab's refinement stores positions in float32: coordinates of ~5 mm to 2^-24.
F32 = 1e-9


def hbake(*args, cwd=None):
    cmd = [sys.executable, "-c", "import sys; from hbake.cli import main; sys.argv[0] = 'hbake'; main()", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=cwd)


@pytest.fixture
def box(tmp_path) -> Path:
    """A 20 x 20 x 5 mm box, corner at the origin (12 triangles), meters."""
    b = trimesh.creation.box(extents=(20 * MM, 20 * MM, 5 * MM))
    b.apply_translation((10 * MM, 10 * MM, 2.5 * MM))
    p = tmp_path / "box.ply"
    trimesh.Trimesh(b.vertices, b.faces, process=False).export(p)
    return p


RIDGES = ["--pattern", "ridges", "--amplitude", "0.0002", "--wavelength", "0.004",
          "--direction", "0.9205048534524404,0.3907311284892737,0", "--origin", "0,0,0",
          "--region", "facing:0,0,1,10", "--along", "axis", "--fade", "0"]


def test_ridges_follow_the_profile_and_the_refinement_bound(box, tmp_path):
    out = tmp_path / "r.ply"
    res = hbake("texture", box, "-o", out, *RIDGES)
    assert res.returncode == 0, res.stderr
    m = trimesh.load(out, process=False)
    assert f"{len(m.faces):,} triangles" in res.stdout
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    # The top's vertices off its rim (the side walls' vertices under the rim take the
    # relief spilled over 4 A, weighted).
    xy0 = m.vertices[:, :2]
    top = (m.vertices[:, 2] > 4 * MM) & np.all((xy0 > 1e-9) & (xy0 < 20 * MM - 1e-9), axis=1)
    d = np.array([0.9205048534524404, 0.3907311284892737, 0.0])
    want = 5 * MM + 0.2 * MM * np.sin(2 * np.pi * (m.vertices[top] @ d) / (4 * MM))
    # Displaced along z by exactly A f(u) at the refined positions; MeshLab keeps those
    # in float32 (5 mm to 2^-24 relative: 3e-10 m), so 1e-9 m.
    assert np.abs(m.vertices[top, 2] - want).max() < F32
    # Every top edge within wavelength / samples (8 by default) in the plane.
    f = m.faces[np.all(top[m.faces], axis=1)]
    xy = m.vertices[:, :2]
    e = np.linalg.norm(xy[f[:, [1, 2, 0]]] - xy[f], axis=2)
    assert e.max() <= 0.5 * MM * (1 + 1e-5)
    # Adaptive: the bottom (not in the region, 5 mm from it) stays coarse: its 2
    # triangles split only where the side walls' conforming splits reach its edges.
    bottom = np.all(m.vertices[m.faces][:, :, 2] < 1e-9, axis=1)
    assert bottom.sum() <= 16 < len(f) / 100


def test_trapezoid_profile_has_flat_plateaus(box, tmp_path):
    out = tmp_path / "t.ply"
    res = hbake("texture", box, "-o", out, *RIDGES, "--profile", "trapezoid", "--flank", "0.125",
                "--samples", "16")
    assert res.returncode == 0, res.stderr
    m = trimesh.load(out, process=False)
    xy0 = m.vertices[:, :2]
    z = m.vertices[(m.vertices[:, 2] > 4 * MM) & np.all((xy0 > 1e-9) & (xy0 < 20 * MM - 1e-9), axis=1), 2]
    # Flanks are 1/8 of the wavelength each: 3/4 of the top's vertices sit on a plateau.
    on = (np.abs(z - 5.2 * MM) < F32) | (np.abs(z - 4.8 * MM) < F32)
    assert on.mean() > 0.6


def test_same_input_same_bytes(box, tmp_path):
    digests = []
    for i in range(2):
        out = tmp_path / f"n{i}.ply"
        res = hbake("texture", box, "-o", out, "--pattern", "noise", "--amplitude", "0.0001",
                    "--wavelength", "0.003", "--seed", "7")
        assert res.returncode == 0, res.stderr
        digests.append(hashlib.sha256(out.read_bytes()).hexdigest())
    assert digests[0] == digests[1]
    res = hbake("texture", box, "-o", tmp_path / "n2.ply", "--pattern", "noise", "--amplitude", "0.0001",
                "--wavelength", "0.003", "--seed", "8")
    assert hashlib.sha256((tmp_path / "n2.ply").read_bytes()).hexdigest() != digests[0]


def test_default_fade_leaves_the_region_border_in_place(box, tmp_path):
    out = tmp_path / "f.ply"
    res = hbake("texture", box, "-o", out, "--pattern", "bumps", "--amplitude", "0.0002",
                "--wavelength", "0.004", "--region", "facing:0,0,1,10")
    assert res.returncode == 0, res.stderr
    m = trimesh.load(out, process=False)
    v = m.vertices
    rim = (np.abs(v[:, 2] - 5 * MM) < 1e-3 * MM) & ((v[:, 0] < 1e-9) | (v[:, 0] > 20 * MM - 1e-9)
                                                 | (v[:, 1] < 1e-9) | (v[:, 1] > 20 * MM - 1e-9))
    assert rim.sum() > 8 and np.abs(v[rim, 2] - 5 * MM).max() < F32
    assert m.is_watertight


def test_knurl_on_a_cylinder(tmp_path):
    c = trimesh.creation.cylinder(radius=6 * MM, height=30 * MM, sections=48)
    src = tmp_path / "cyl.ply"
    trimesh.Trimesh(c.vertices, c.faces, process=False).export(src)
    out = tmp_path / "k.ply"
    res = hbake("texture", src, "-o", out, "--pattern", "knurl", "--mapping", "cylindrical", "--axis", "0,0,1",
                "--origin", "0,0,0", "--region", "box:-1,-1,-0.012,1,1,0.012",
                "--amplitude", "0.0002", "--wavelength", "0.002")
    assert res.returncode == 0, res.stderr
    m = trimesh.load(out, process=False)
    assert m.is_watertight and len(m.faces) > 20 * len(c.faces)
    r = np.linalg.norm(m.vertices[:, :2], axis=1)
    side = np.abs(m.vertices[:, 2]) < 10 * MM
    # The side vertices move radially (the smoothed normals of a cylinder) within A of
    # the radius, up and down (pyramids and grooves).
    assert np.abs(r[side] - 6 * MM).max() <= 0.2 * MM * (1 + 1e-6) + 6 * MM * (1 - math.cos(math.pi / 48))
    assert (r[side] > 6.1 * MM).any() and (r[side] < 5.9 * MM).any()


def test_image_pattern(box, tmp_path):
    from PIL import Image

    img = tmp_path / "stripes.png"
    a = np.zeros((8, 16), np.uint8)
    a[:, 8:] = 255
    Image.fromarray(a).save(img)
    res = hbake("texture", box, "-o", tmp_path / "i.ply", "--pattern", f"image:{img}", "--amplitude", "0.0001",
                "--wavelength", "0.004", "--region", "facing:0,0,1,10")
    assert res.returncode == 0, res.stderr
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    res = hbake("texture", box, "-o", tmp_path / "j.ply", "--pattern", f"image:{bad}", "--amplitude", "0.0001",
                "--wavelength", "0.004")
    assert res.returncode == 4 and str(bad) in res.stderr and not (tmp_path / "j.ply").exists()


@pytest.mark.parametrize("args, code, text", [
    (["--pattern", "ridges", "--amplitude", "-0.001", "--wavelength", "0.004"], EXIT_TEXTURE,
     "--amplitude must be a positive length"),
    (["--pattern", "ridges", "--amplitude", "0.0001", "--wavelength", "0.00001"], EXIT_TEXTURE,
     "below the refinement limit"),
    (["--pattern", "ridges", "--amplitude", "0.0001", "--wavelength", "0.004", "--region", "box:1,1,1,2,2,2"],
     EXIT_TEXTURE, "no face of the mesh is in it"),
    (["--pattern", "ridges", "--amplitude", "0.0001", "--wavelength", "0.004", "--region", "cube:1"],
     EXIT_TEXTURE, "expected all, box:"),
    # An unknown --pattern is a usage error (exit 2) before the input is read:
    # tests/hbake/cli/test_hostile_hbake.py::test_texture_inputs_and_parameters.
    (["--pattern", "ridges", "--amplitude", "0.004", "--wavelength", "0.004"], EXIT_TEXTURE, "folds"),
    (["--pattern", "ridges", "--amplitude", "0.0001", "--wavelength", "0.004", "--profile", "trapezoid",
      "--flank", "0.6"], EXIT_TEXTURE, "--flank must be in (0, 0.5)"),
])
def test_bad_parameters_are_one_line_with_their_exit_code(box, tmp_path, args, code, text):
    out = tmp_path / "o.ply"
    res = hbake("texture", box, "-o", out, *args)
    assert res.returncode == code, (res.returncode, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"hbake: error: {box}: ") and text in lines[0], res.stderr
    assert "Traceback" not in res.stderr and not out.exists()
    assert not list(tmp_path.glob(".o.ply*"))


def test_missing_input_and_existing_output(box, tmp_path):
    res = hbake("texture", tmp_path / "nope.ply", "-o", tmp_path / "o.ply", "--pattern", "ridges",
                "--amplitude", "0.0001", "--wavelength", "0.004")
    assert res.returncode == 3 and "nope.ply" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    (tmp_path / "o.ply").write_text("keep")
    res = hbake("texture", box, "-o", tmp_path / "o.ply", "--pattern", "ridges", "--amplitude", "0.0001",
                "--wavelength", "0.004")
    assert res.returncode == 5 and (tmp_path / "o.ply").read_text() == "keep"
