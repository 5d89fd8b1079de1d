"""Every input path of every hbake command goes through the one reader `hbake bake` uses
(regular files within a size limit, named when they are not), and usage errors are one
line: the batch config, the entries of a batch folder and of its command line, the texture
image, the texture pattern and wavelength."""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import trimesh

REPO = Path(__file__).resolve().parents[3]
T = 60   # s: every command here answers at once; a hang is a failure, not a slow test


def hbake(*args, cwd=None, timeout=T):
    return subprocess.run([str(REPO / ".venv" / "bin" / "hbake"), *[str(a) for a in args]], capture_output=True,
                          text=True, timeout=timeout, cwd=cwd, env=dict(os.environ, NO_COLOR="1"))


def one_line(r, code, *needles):
    assert r.returncode == code, f"exit {r.returncode}, want {code}: {r.stderr}"
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("hbake: error: ") and "Traceback" not in r.stderr, r.stderr
    for n in needles:
        assert str(n) in lines[0], (n, lines[0])
    return lines[0]


def cube(path: Path) -> Path:
    trimesh.creation.box(extents=(0.02, 0.02, 0.02)).export(path)
    return path


def test_batch_config_is_read_like_every_input(tmp_path):
    cube(tmp_path / "c.ply")
    fifo = tmp_path / "cfg.toml"
    os.mkfifo(fifo)
    one_line(hbake("batch", tmp_path / "c.ply", "-o", tmp_path / "out", "-c", fifo), 8, fifo, "FIFO")
    one_line(hbake("batch", tmp_path / "c.ply", "-o", tmp_path / "out", "-c", "/dev/zero"), 8, "/dev/zero",
             "character device")
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * ((1 << 20) + 1))
    one_line(hbake("batch", tmp_path / "c.ply", "-o", tmp_path / "out", "-c", big), 8, big, "limit")
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_batch_lists_entries_that_are_no_regular_file(tmp_path):
    d = tmp_path / "models"
    d.mkdir()
    cube(d / "good.ply")
    os.mkfifo(d / "fifo.stl")
    (d / "zero.obj").symlink_to("/dev/zero")
    (d / "dangling.ply").symlink_to(tmp_path / "nowhere.ply")
    (d / "folder.off").mkdir()
    out = tmp_path / "out"
    cfg = tmp_path / "low.toml"
    cfg.write_text("[defaults]\nsimplify.target_faces = 12\nparameterize.atlas_width = 32\n"
                   "parameterize.atlas_height = 32\nquality.samples = 1000\n")
    r = hbake("batch", d, "-o", out, "-j", "1", "--json", "-c", cfg, timeout=600)
    assert r.returncode == 18, r.stderr
    rep = {m["name"]: m for m in json.loads(r.stdout)["models"]}
    assert sorted(rep) == ["dangling.ply", "fifo.stl", "folder.off", "good.ply", "zero.obj"]
    assert rep["good.ply"]["status"] == "baked"
    for name, what in (("fifo.stl", "FIFO"), ("zero.obj", "character device"), ("dangling.ply", "no such"),
                       ("folder.off", "directory")):
        assert rep[name]["status"] == "failed" and what in rep[name]["error"], rep[name]
    # Named on the command line: a FIFO does not hang the batch; a dangling link is a failed
    # model, not the end of the batch.
    r = hbake("batch", d / "fifo.stl", d / "dangling.ply", d / "good.ply", "-o", out, "-j", "1", "--json",
              "-c", cfg, timeout=600)
    assert r.returncode == 18, r.stderr
    rep = {m["name"]: m for m in json.loads(r.stdout)["models"]}
    assert rep["fifo.stl"]["status"] == rep["dangling.ply"]["status"] == "failed"
    assert rep["good.ply"]["status"] in ("baked", "skipped")


def test_texture_inputs_and_parameters(tmp_path):
    src = cube(tmp_path / "c.ply")
    fifo = tmp_path / "img.png"
    os.mkfifo(fifo)
    one_line(hbake("texture", src, "-o", tmp_path / "t.ply", "--pattern", f"image:{fifo}", "--amplitude", "0.0005",
                   "--wavelength", "0.004"), 3, fifo, "FIFO")
    one_line(hbake("texture", src, "-o", tmp_path / "t.ply", "--pattern", "bogus", "--amplitude", "0.0005",
                   "--wavelength", "0.004"), 2, "--pattern", "bogus", "see hbake texture --help")
    one_line(hbake("texture", src, "-o", tmp_path / "t.ply", "--pattern", "ridges", "--amplitude", "0.0005",
                   "--wavelength", "1e308"), 20, "--wavelength", "longer than the part")
    assert not (tmp_path / "t.ply").exists()


def test_option_errors_are_one_line(tmp_path):
    one_line(hbake("bake", "x.obj", "-o", tmp_path / "y.hbundle", "--units", "km"), 2, "--units", "km",
             "see hbake bake --help")
    one_line(hbake("bake"), 2, "INPUT", "see hbake bake --help")
    one_line(hbake("bogus"), 2, "bogus", "see hbake --help")
    r = hbake("--version")
    assert r.returncode == 0 and "hbake" in r.stdout
    r = hbake("bake", "--help")
    assert r.returncode == 0 and r.stdout.startswith("Usage: ")


def test_bake_errors_name_the_input(tmp_path):
    # Four points on a plane: a flat tetrahedron whose convex hull fails deep in the bake,
    # where the stage does not know the file's name.
    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv 0.01 0.01 0\nf 1 2 3\nf 2 4 3\nf 1 3 2\nf 2 3 4\n")
    r = hbake("bake", flat, "-o", tmp_path / "flat.hbundle", "--units", "m")
    assert r.returncode != 0
    line = [ln for ln in r.stderr.splitlines() if ln.startswith("hbake: error: ")][-1]
    assert "flat.obj" in line, line


def test_a_full_disk_is_the_unwritable_output_exit(tmp_path):
    """A write that fails for lack of room (here a file-size limit, which fails the write as
    a full disk does: EFBIG instead of ENOSPC; the signal it raises is ignored, as a
    shell's `trap '' XFSZ` does) is exit 6 with one line naming the output, and leaves
    nothing behind: no bundle, no temporary directory."""
    src = tmp_path / "src"
    src.mkdir()
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.02)
    mesh.export(src / "ball.ply")
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "ball.hbundle"
    r = subprocess.run(["bash", "-c", 'ulimit -f 64; trap "" XFSZ; exec "$@"', "bash",
                        str(REPO / ".venv" / "bin" / "hbake"), "bake", str(src / "ball.ply"), "-o", str(out),
                        "--units", "m", "-q"],
                       capture_output=True, text=True, timeout=600, env=dict(os.environ, NO_COLOR="1"))
    one_line(r, 6, out, "File too large")
    assert not any(out_dir.iterdir()), list(out_dir.iterdir())
