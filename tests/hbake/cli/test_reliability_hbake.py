"""Reliability of hbake on hostile or absurd input (the hbake side of the reliability issue).

Each test fails on the code before the fix: a traceback, a hang, a quadratic blow-up, a
native library's chatter on the terminal, or a file left behind. Inputs are small and
generated here. CLI tests run the real console script and check the exit code and the
one-line ``hbake: error: <file>: <what>`` (or ``BUNDLE: <class>: <message>``) without a
traceback.
"""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hbake import bundle as hb
from hbake.bundle import uv_coverage
from hbake.errors import (EXIT_BAKE_FAILED, EXIT_CONFIG, EXIT_INPUT_INVALID, EXIT_INPUT_MISSING,
                          EXIT_INTERRUPTED, EXIT_USAGE, VALIDATE_EXIT)

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from bundledata import cube_data  # noqa: E402  (the hand-built cube bundle)
from hbakecli import _hbake, _sphere_hull  # noqa: E402




def _env(**extra) -> dict:
    env = dict(os.environ)
    env.pop("FORCE_COLOR", None)
    env.pop("HBAKE_DEBUG", None)
    env["NO_COLOR"] = "1"
    env["COLUMNS"] = "200"
    env.update(extra)
    return env


def _run(args: list[str], cwd: Path, timeout: float = 120, **popen):
    return subprocess.run(_hbake() + args, cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=_env(), **popen)


def _one_error_line(r, want_rc: int, *mentions: str) -> str:
    out = r.stdout + r.stderr
    assert "Traceback" not in out, out[-3000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{r.stderr[-3000:]}"
    assert lines[0].startswith("hbake: error: "), lines[0]
    for m in mentions:
        assert m in lines[0], f"{m!r} not in {lines[0]!r}"
    assert r.returncode == want_rc, f"exit {r.returncode}, expected {want_rc}: {lines[0]}"
    return lines[0]


def _validate(bundle: Path, cls: str, *mentions: str, timeout: float = 60) -> str:
    r = _run(["validate", str(bundle)], bundle.parent, timeout=timeout)
    assert "Traceback" not in r.stdout + r.stderr, (r.stdout + r.stderr)[-3000:]
    lines = [ln for ln in r.stdout.splitlines() if ln.strip()]
    assert lines, r.stderr
    assert lines[0].startswith(f"{bundle}: {cls}: "), lines
    for m in mentions:
        assert m in lines[0], f"{m!r} not in {lines[0]!r}"
    assert r.returncode == VALIDATE_EXIT[cls], (r.returncode, lines)
    assert max(len(ln) for ln in lines) < 2000, "a problem line echoes the whole input"
    return lines[0]


def _rehash(bundle: Path, manifest: dict | None = None) -> None:
    """Recompute sizes and SHA-256 of the files in the manifest (so only the content
    check can catch a change)."""
    mpath = bundle / "manifest.json"
    m = manifest if manifest is not None else json.loads(mpath.read_text())
    for entry in m["files"].values():
        blob = (bundle / entry["path"]).read_bytes()
        entry["bytes"] = len(blob)
        entry["sha256"] = hashlib.sha256(blob).hexdigest()
    mpath.write_bytes(hb.manifest_bytes(m))


@pytest.fixture()
def cube(tmp_path) -> Path:
    out = tmp_path / "cube.hbundle"
    hb.write_bundle(out, cube_data())
    return out


# --------------------------------------------------------------------------- A: manifest

def test_validate_huge_format_version_is_a_version_error(cube):
    m = json.loads((cube / "manifest.json").read_text())
    m["format_version"] = "1" * 26_500 + ".0"
    (cube / "manifest.json").write_bytes(hb.manifest_bytes(m))
    line = _validate(cube, "version", "is not MAJOR.MINOR (at most 32 characters)")
    assert len(line) < 400


def test_validate_long_major_one_with_zeros_is_refused_like_the_loader(cube):
    # the C++ loader caps format_version at 32 characters; up to that, leading zeros are
    # compared as digits: still version 1
    m = json.loads((cube / "manifest.json").read_text())
    m["format_version"] = "0" * 5000 + "1.0"
    (cube / "manifest.json").write_bytes(hb.manifest_bytes(m))
    _validate(cube, "version", "(at most 32 characters)")
    m["format_version"] = "0" * 29 + "1.3"  # the cube's pieces.ply has 1.3's layout
    (cube / "manifest.json").write_bytes(hb.manifest_bytes(m))
    assert hb.validate_bundle(cube) == []


@pytest.mark.parametrize("depth", [35_000, 900])
def test_validate_deeply_nested_manifest_is_a_schema_error(cube, depth):
    m = json.loads((cube / "manifest.json").read_text())
    text = hb.manifest_bytes(m).decode()
    # a field of the wrong type (coarse.vertices must be an integer) nested `depth` deep
    nested = "[" * depth + "1" + "]" * depth
    text = text.replace('"vertices": 8', f'"vertices": {nested}', 1)
    assert nested in text
    (cube / "manifest.json").write_text(text)
    _validate(cube, "schema", "manifest.json")


def test_validate_infinite_number_in_manifest_is_a_schema_error(cube):
    text = (cube / "manifest.json").read_text().replace('"density": 1.0', '"density": 1e999', 1)
    (cube / "manifest.json").write_text(text)
    _validate(cube, "schema", "manifest.json")


# --------------------------------------------------------------------------- B: pieces, atlas



def write_pieces(bundle: Path, pieces: list[tuple[np.ndarray, np.ndarray]]) -> int:
    """Replace the cube bundle's pieces by ``pieces`` (each mapped to triangle 0) and fix
    the manifest; returns the size of pieces.ply."""
    path = bundle / "pieces.ply"
    hb.write_pieces_ply(path, [p[0] for p in pieces], [p[1] for p in pieces],
                        [np.array([0], np.uint32)] * len(pieces))
    m = json.loads((bundle / "manifest.json").read_text())
    m["pieces"]["count"] = len(pieces)
    _rehash(bundle, m)
    return path.stat().st_size


def many_small_pieces(count: int, n: int = 12, seed: int = 0):
    """``count`` convex hulls of ``n`` points inside the 0.1 m cube: one hull, translated
    (identical shapes keep the generator fast; the validator checks each one)."""
    rng = np.random.default_rng(seed)
    hv, hf = _sphere_hull(n, rng, (0, 0, 0), 0.004)
    centres = rng.uniform(0.005, 0.095, size=(count, 3))
    return [((hv + c).astype(np.float32).astype(np.float64), hf) for c in centres]


def test_validate_refuses_a_piece_over_the_vertex_limit(cube):
    rng = np.random.default_rng(1)
    big = _sphere_hull(1500, rng, (0.05, 0.05, 0.05), 0.04)
    write_pieces(cube, [big] + many_small_pieces(2))
    assert len(big[0]) > hb.MAX_PIECE_VERTICES
    _validate(cube, "pieces", f"piece 0 has {len(big[0])} vertices, more than the limit 1024")


def test_validate_accepts_a_piece_at_the_vertex_limit(cube):
    rng = np.random.default_rng(2)
    hv, hf = _sphere_hull(1024, rng, (0.05, 0.05, 0.05), 0.04)
    assert len(hv) == 1024
    write_pieces(cube, [(hv, hf)])
    assert hb.validate_bundle(cube) == []


def test_validate_still_finds_a_nonconvex_piece_among_many(cube):
    pieces = many_small_pieces(300)
    hv, hf = pieces[123]
    hv = hv.copy()
    hv[0] = hv[:].mean(axis=0) + 0.3 * (hv[0] - hv.mean(axis=0))   # dent one vertex inwards
    pieces[123] = (hv, hf)
    write_pieces(cube, pieces)
    problems = hb.validate_bundle(cube)
    assert [p.cls for p in problems] == ["pieces"], problems
    assert "piece 123" in problems[0].message and "not convex" in problems[0].message


def _time_validate(bundle: Path) -> tuple[float, float]:
    """(wall seconds, peak RSS MiB) of `hbake validate` in a fresh process."""
    # Peak RSS from VmHWM of the new process image: ru_maxrss survives execve on
    # Linux, so after a fork of a big pytest process it would report the parent's.
    code = ("import re, sys, time; from hbake.bundle import validate_bundle; "
            "t = time.perf_counter(); p = validate_bundle(sys.argv[1]); "
            "dt = time.perf_counter() - t; "
            "hwm = int(re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1)); "
            "print(dt, hwm / 1024, len(p))")
    r = subprocess.run([sys.executable, "-c", code, str(bundle)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    dt, rss, nprob = r.stdout.split()
    assert nprob == "0", hb.validate_bundle(bundle)
    return float(dt), float(rss)


def test_validate_time_is_bounded_for_one_huge_piece(cube):
    """One piece of 40,000 vertices (2 MB): refused by the vertex limit at once, instead
    of a 40,000 x 80,000 distance matrix (25 GB)."""
    rng = np.random.default_rng(3)
    size = write_pieces(cube, [_sphere_hull(40_000, rng, (0.05, 0.05, 0.05), 0.04)])
    assert size > 1.5e6
    # Refused by counting (the message names the limit it counted against), not timed: a
    # clock bound fails on a loaded machine and proves nothing a count does not.
    problems = hb.validate_bundle(cube)
    assert [p.cls for p in problems] == ["pieces"] and "more than the limit 1024" in problems[0].message


def _set_atlas_size(bundle: Path, w: int, h: int) -> None:
    m = json.loads((bundle / "manifest.json").read_text())
    m["atlas"]["width"] = m["files"]["atlas"]["width"] = w
    m["atlas"]["height"] = m["files"]["atlas"]["height"] = h
    _rehash(bundle, m)


@pytest.mark.parametrize("w, h, cls", [(8193, 16, "atlas"), (16, 100_000, "schema"),
                                       (8192, 4096, "atlas"), (10**30, 1, "schema")])
def test_validate_refuses_an_atlas_over_the_limit_before_decoding(cube, w, h, cls):
    # sides past 65536 are a schema error, as in the C++ loader
    _set_atlas_size(cube, w, h)
    if cls == "atlas":
        line = _validate(cube, "atlas", "limit")
        assert f"{w}x{h}" in line
    else:
        _validate(cube, "schema", "files/atlas/", "65536" if w < 10**20 else "out of range")


@pytest.mark.parametrize("option, rc", [("8193", EXIT_USAGE), ("8192x4096", EXIT_USAGE),
                                        ("4096x8192", EXIT_USAGE)])
def test_bake_atlas_size_option_limit(tmp_path, option, rc):
    src = tmp_path / "t.obj"
    src.write_text("v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv 0 0 0.01\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n")
    r = _run(["bake", str(src), "-o", str(tmp_path / "x.hbundle"), "--atlas-size", option], tmp_path)
    assert "Traceback" not in r.stderr
    assert r.returncode == rc, r.stderr
    assert "8192" in r.stderr or "16,777,216" in r.stderr or "16777216" in r.stderr, r.stderr


def test_settings_atlas_limit_is_a_config_error(tmp_path):
    from hbake.errors import ConfigError
    from hbake.settings import BakeSettings, ParameterizeSettings
    with pytest.raises(ConfigError):
        ParameterizeSettings(atlas_width=8193, atlas_height=16)
    with pytest.raises(ConfigError, match="16,777,216"):
        ParameterizeSettings(atlas_width=8192, atlas_height=4096)
    ParameterizeSettings(atlas_width=8192, atlas_height=2048)
    cfg = tmp_path / "c.toml"
    cfg.write_text("[parameterize]\natlas_width = 6000\natlas_height = 6000\n")
    with pytest.raises(ConfigError):
        BakeSettings.from_toml(cfg)
    src = tmp_path / "t.obj"
    src.write_text("v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv 0 0 0.01\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n")
    r = _run(["bake", str(src), "-o", str(tmp_path / "x.hbundle"), "-c", str(cfg)], tmp_path)
    _one_error_line(r, EXIT_CONFIG, "16,777,216")


# --------------------------------------------------------------------------- E: non-regular files

TETRA = "v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv 0 0 0.01\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n"


@pytest.mark.parametrize("which", ["fifo", "dev_zero"])
def test_validate_refuses_a_non_regular_manifest(cube, which):
    m = cube / "manifest.json"
    m.unlink()
    if which == "fifo":
        os.mkfifo(m)
    else:
        m.symlink_to("/dev/zero")
    _validate(cube, "io", "manifest.json", "not a regular file", timeout=30)


def test_validate_refuses_a_fifo_in_place_of_a_bundle_file(cube):
    (cube / "pieces.ply").unlink()
    os.mkfifo(cube / "pieces.ply")
    _validate(cube, "io", "pieces.ply", "not a regular file", timeout=30)


@pytest.mark.parametrize("which", ["fifo", "dev_zero"])
def test_bake_refuses_a_non_regular_input(tmp_path, which):
    src = tmp_path / "in.obj"
    if which == "fifo":
        os.mkfifo(src)
    else:
        src.symlink_to("/dev/zero")
    r = _run(["bake", str(src), "-o", str(tmp_path / "x.hbundle")], tmp_path, timeout=30)
    _one_error_line(r, EXIT_INPUT_MISSING, "in.obj", "not a regular file")


def test_bake_refuses_an_input_over_the_size_limit(tmp_path):
    from hbake.constants import MAX_INPUT_BYTES
    src = tmp_path / "huge.stl"
    with open(src, "wb") as fh:        # sparse: no disk, no time
        fh.truncate(MAX_INPUT_BYTES + 1)
    # Refused by its size before a byte is read (the message names the limit); the 60 s
    # timeout is the only clock: reading 1 GiB of zeros would take far longer on any box.
    r = _run(["bake", str(src), "-o", str(tmp_path / "x.hbundle")], tmp_path, timeout=60)
    _one_error_line(r, EXIT_INPUT_INVALID, "huge.stl", "limit")


def test_config_fifo_is_a_config_error(tmp_path):
    cfg = tmp_path / "c.toml"
    os.mkfifo(cfg)
    src = tmp_path / "t.obj"
    src.write_text(TETRA)
    r = _run(["bake", str(src), "-o", str(tmp_path / "x.hbundle"), "-c", str(cfg)], tmp_path,
             timeout=30)
    _one_error_line(r, EXIT_CONFIG, "c.toml", "not a regular file")


# --------------------------------------------------------------------------- F: smaller ones

def test_bake_unreadable_input_is_exit_3_in_one_line(tmp_path):
    """As root, permission bits are bypassed (CAP_DAC_OVERRIDE): drop those capabilities
    for the child with setpriv, so chmod 000 really makes the file unreadable."""
    import shutil
    setpriv = shutil.which("setpriv")
    # setpriv is util-linux's, an essential Debian package: never skipped
    assert os.geteuid() != 0 or setpriv is not None, "setpriv (util-linux) is missing"
    src = tmp_path / "locked.obj"
    src.write_text(TETRA)
    src.chmod(0)
    prefix = ([setpriv, "--inh-caps=-dac_override,-dac_read_search",
               "--bounding-set=-dac_override,-dac_read_search"] if os.geteuid() == 0 else [])
    r = subprocess.run(prefix + _hbake() + ["bake", str(src), "-o", str(tmp_path / "x.hbundle")],
                       cwd=tmp_path, capture_output=True, text=True, timeout=60, env=_env())
    _one_error_line(r, EXIT_INPUT_MISSING, "locked.obj", "cannot read")


def test_obj_face_index_zero_is_refused_with_its_line(tmp_path):
    src = tmp_path / "zero.obj"
    src.write_text("# one face uses index 0\n" + TETRA.replace("f 1 4 3", "f 0 4 3"))
    r = _run(["bake", str(src), "-o", str(tmp_path / "x.hbundle")], tmp_path)
    _one_error_line(r, EXIT_INPUT_INVALID, "zero.obj", "line 9", "index 0")


def test_obj_zero_index_scan_ignores_other_tokens():
    from hbake.stages.load import _OBJ_ZERO_INDEX
    for ok in (b"f 10 20 30\n", b"f 1/0/1 2 3\n", b"vt 0 0\n", b"v 0 0 0\n", b"f -1 -2 -3\n",
               b"f 1//0 2//0 3//0\n"):
        assert _OBJ_ZERO_INDEX.search(ok) is None, ok
    for bad in (b"f 0 1 2\n", b"f 1 2 0", b"  f\t1 0/3 2\n", b"f 1 2 00\r\n", b"f 1 0//2 3\n"):
        assert _OBJ_ZERO_INDEX.search(bad) is not None, bad


def test_gltf_short_buffer_is_one_clear_line(tmp_path):
    import struct
    import trimesh
    blob = trimesh.creation.icosphere(subdivisions=1, radius=0.02).export(file_type="glb")
    magic, ver, _ = struct.unpack_from("<III", blob, 0)
    jlen, jtype = struct.unpack_from("<II", blob, 12)
    js = blob[20:20 + jlen]
    blen, btype = struct.unpack_from("<II", blob, 20 + jlen)
    short = blob[28 + jlen:28 + jlen + blen // 2]
    short += b"\0" * (-len(short) % 4)
    out = (struct.pack("<III", magic, ver, 28 + jlen + len(short)) + struct.pack("<II", jlen, jtype)
           + js + struct.pack("<II", len(short), btype) + short)
    src = tmp_path / "short.glb"
    src.write_bytes(out)
    r = _run(["bake", str(src), "-o", str(tmp_path / "x.hbundle")], tmp_path)
    line = _one_error_line(r, EXIT_INPUT_INVALID, "short.glb", "shorter than")
    assert "AssertionError" not in line


# --------------------------------------------------------------------------- D: absurd scales

def _scaled_tetra(tmp_path: Path, scale: float, offset: float = 0.0, name: str = "s.obj") -> Path:
    v = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]]) * scale + offset
    src = tmp_path / name
    src.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in v.tolist())
                   + "f 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n")
    return src


@pytest.mark.parametrize("scale, offset, what", [
    (1e306, 1e308, "beyond the limit"),                 # coordinates of 1e308
    (1e200, 0.0, "beyond the limit"),
    (1e100, 0.0, "beyond the limit"),
    (1e22, 0.0, "beyond the limit"),                    # 1e20 m across
    (1e17, 0.0, "beyond the limit"),                    # 1e15 m across
    (1e6, 0.0, "outside"),                              # 1.7e4 m across, within 1e4 m
    (1e-4, 0.0, "outside"),                             # 1.7 um across
    (1.0, 50.0, "from the origin"),                     # 1.7 cm at 50 m
])
def test_absurd_scales_are_refused_in_the_load_stage(tmp_path, scale, offset, what):
    if scale == 1e6:
        src = _scaled_tetra(tmp_path, 1e6, -5000.0)
    else:
        src = _scaled_tetra(tmp_path, scale, offset)
    r = _run(["bake", str(src), "-o", str(tmp_path / "x.hbundle"), "--units", "m", "-q"],
             tmp_path, timeout=120)
    _one_error_line(r, EXIT_INPUT_INVALID, "s.obj", what)
    assert not any(p.name.startswith(".x.hbundle") or p.name == "x.hbundle" for p in tmp_path.iterdir())


def test_limits_of_scale_are_accepted_by_load(tmp_path):
    """Just inside each limit the load stage accepts the mesh."""
    from hbake.stages.load import load_mesh
    from hbake.settings import LoadSettings
    for scale, offset in ((5e5, -4000.0), (2e-3 / 1.7, 0.0), (1.0, 15.0)):
        src = _scaled_tetra(tmp_path, scale, offset)
        m = load_mesh(src, LoadSettings(units="m"))
        assert len(m.faces) == 4


# --------------------------------------------------------------------------- D: signals, native output

def _patched_env(tmp_path: Path, code: str) -> dict:
    """An environment whose interpreter runs ``code`` at start-up (sitecustomize), to
    stand in for a native stage that misbehaves."""
    d = tmp_path / "site"
    d.mkdir(exist_ok=True)
    (d / "sitecustomize.py").write_text(code)
    env = _env()
    env["PYTHONPATH"] = str(d) + os.pathsep + env.get("PYTHONPATH", "")
    return env


_NATIVE_STAGE = '''
import ctypes, os
import hbake.routes.cage as _p  # where the cage route calls parameterize
_orig = _p.parameterize
def parameterize(*a, **k):
    {body}
    return _orig(*a, **k)
_p.parameterize = parameterize
'''


def test_native_chatter_stays_off_the_terminal(tmp_path):
    """xatlas prints ASSERT lines with printf, CoACD and MeshLab log to fd 1/2: with -q
    nothing but hbake's own lines may reach the terminal."""
    body = ('os.write(1, b"NATIVE-STDOUT\\\\n"); os.write(2, b"NATIVE-STDERR\\\\n"); '
            'ctypes.CDLL(None).printf(b"NATIVE-PRINTF %d\\\\n", 7)')
    env = _patched_env(tmp_path, _NATIVE_STAGE.format(body=body))
    src = tmp_path / "t.obj"
    src.write_text(TETRA)
    r = subprocess.run(_hbake() + ["bake", str(src), "-o", str(tmp_path / "t.hbundle"), "-q"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=180, env=env)
    assert r.returncode == 0, r.stderr
    assert "NATIVE" not in r.stdout + r.stderr, (r.stdout, r.stderr)
    assert r.stdout == "" and r.stderr == ""
    # HBAKE_DEBUG=1 forwards it
    env["HBAKE_DEBUG"] = "1"
    r = subprocess.run(_hbake() + ["bake", str(src), "-o", str(tmp_path / "t.hbundle"), "-q", "-f"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=180, env=env)
    assert r.returncode == 0 and "NATIVE-STDERR" in r.stderr, r.stderr


def test_signal_during_a_long_native_call(tmp_path):
    """A native stage that runs for minutes in one C call, like xatlas spinning on a normal it
    cannot normalise (here: 200 M rounds of PBKDF2, one C call of about a minute that
    never looks at signals): SIGINT and SIGTERM must still end the bake with 130
    within 5 s, leaving nothing behind."""
    env = _patched_env(tmp_path, _NATIVE_STAGE.format(
        body='open(os.environ["HB_MARK"], "w").close(); import hashlib; '
             'hashlib.pbkdf2_hmac("sha256", b"x", b"salt", 200_000_000)'))
    src = tmp_path / "t.obj"
    src.write_text(TETRA)
    out = tmp_path / "out"
    out.mkdir()
    for sig in (signal.SIGINT, signal.SIGTERM):
        mark = tmp_path / f"in-native-{sig.name}"
        env["HB_MARK"] = str(mark)
        proc = subprocess.Popen(_hbake() + ["bake", str(src), "-o", str(out / "t.hbundle")],
                                cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=env)
        try:
            end = time.monotonic() + 120
            while not mark.exists() and time.monotonic() < end and proc.poll() is None:
                time.sleep(0.05)
            assert mark.exists(), proc.communicate()[1]
            time.sleep(1.0)
            proc.send_signal(sig)
            t = time.monotonic()
            try:
                _, stderr = proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                pytest.fail(f"still running 30 s after {sig.name}")
            dt = time.monotonic() - t
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert proc.returncode == EXIT_INTERRUPTED, stderr
        assert "Traceback" not in stderr
        assert [ln for ln in stderr.splitlines() if ln.strip()][-1] == "hbake: interrupted", stderr
        assert dt < 5, f"{sig.name}: stopped after {dt:.1f} s"
        assert list(out.iterdir()) == []


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_temporaries_of_dead_bakes_are_removed(tmp_path):
    """A bake killed with SIGKILL in its write stage leaves .NAME.hbundle.PID.HEX.tmp;
    the next bake of the same output removes it (with a warning) when PID is gone, and
    leaves the temporaries of live processes alone."""
    src = tmp_path / "t.obj"
    src.write_text(TETRA)
    dead = _dead_pid()
    stale = tmp_path / f".t.hbundle.{dead}.deadbeef.tmp"
    stale.mkdir()
    (stale / "atlas.exr").write_bytes(b"half written")
    live = tmp_path / f".t.hbundle.{os.getpid()}.cafebabe.tmp"
    live.mkdir()
    other = tmp_path / f".other.hbundle.{dead}.deadbeef.tmp"
    other.mkdir()
    r = _run(["bake", str(src), "-o", str(tmp_path / "t.hbundle")], tmp_path, timeout=180)
    assert r.returncode == 0, r.stderr
    assert not stale.exists() and live.exists() and other.exists()
    assert stale.name in r.stderr and "removed" in r.stderr
    assert (tmp_path / "t.hbundle" / "manifest.json").is_file()
    assert stale.name not in (tmp_path / "t.hbundle" / "manifest.json").read_text()


# --------------------------------------------------------------------------- C: piece vertex cap

def test_decompose_caps_hull_vertices(monkeypatch):
    """CoACD can return hulls of thousands of vertices (a convex coarse mesh of many
    vertices is one piece holding all of them; so can the voxel remesh of a non-manifold
    one); the bake must never store a piece over 1024 vertices: it reruns CoACD with hull
    decimation, and fails with exit 7 if that does not help."""
    import coacd
    import trimesh
    from hbake.stages.decompose import decompose
    from hbake.errors import BakeFailedError

    # Real CoACD: a sphere of 2562 vertices is one convex piece of 2562 vertices.
    calls = []
    real = coacd.run_coacd

    def spy(mesh, **kw):
        calls.append(kw["decimate"])
        return real(mesh, **kw)

    monkeypatch.setattr(coacd, "run_coacd", spy)
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.01)
    pieces = decompose(np.asarray(ball.vertices), np.asarray(ball.faces))
    assert calls == [False, True]
    assert max(len(v) for v in pieces.vertices) <= hb.MAX_PIECE_VERTICES
    assert any("hull decimation" in w for w in pieces.warnings)

    # The defensive branch, which CoACD's decimation (max_ch_vertex=1024) never reaches:
    # a CoACD that keeps returning a 3000-vertex hull must fail the bake, not write it.
    rng = np.random.default_rng(0)
    d = rng.normal(size=(3000, 3))
    big = 0.01 * d / np.linalg.norm(d, axis=1, keepdims=True)
    small_ball = trimesh.creation.icosphere(subdivisions=2, radius=0.01)
    monkeypatch.setattr(coacd, "run_coacd", lambda mesh, **kw: [(big, np.zeros((0, 3), int))])
    with pytest.raises(BakeFailedError, match="more than the limit 1024") as e:
        decompose(np.asarray(small_ball.vertices), np.asarray(small_ball.faces))
    assert e.value.exit_code == EXIT_BAKE_FAILED


# --------------------------------------------------------------------------- atlas work bound

def _sliver_bundle(out: Path, slivers: int, w: int = 1024, h: int = 1024, seed: int = 0) -> Path:
    """The cube bundle with a ``w`` x ``h`` atlas plus ``slivers`` coarse triangles (copies
    of triangle 0) whose UV triangles are slivers 2 texels wide across the whole atlas
    height, all overlapping: each one's texel bounding box is half the atlas, the texels
    it reads are about 10 per row."""
    hb.write_bundle(out, cube_data(w, h))
    v, f, uv = hb.read_coarse_ply(out / "coarse.ply")
    s = np.random.default_rng(seed).uniform(0.0, 0.5, slivers)
    zero, one = np.zeros(slivers), np.ones(slivers)
    tri = np.stack([np.stack([s, zero], -1), np.stack([s + 2.0 / w, zero], -1),
                    np.stack([s + 0.5, one], -1)], 1)
    faces = np.concatenate([f, np.repeat(f[:1], slivers, axis=0)])
    hb.write_coarse_ply(out / "coarse.ply", v, faces,
                        np.concatenate([uv.reshape(-1, 3, 2), tri.astype(np.float32)]))
    m = json.loads((out / "manifest.json").read_text())
    m["coarse"]["triangles"] = len(faces)
    _rehash(out, m)
    return out


_WORK_BOUND = ("texel tests (16 per texel of the atlas + 64 per triangle): "
               "UV triangles overlap or are slivers across the atlas")


def test_validate_refuses_overlapping_sliver_uv_triangles(tmp_path):
    """4,000 overlapping sliver UV triangles across a 1024 x 1024 atlas (a 470 KB bundle):
    the footprint check visited each one's texel bounding box (half the atlas), 75 s
    (`/usr/bin/time hbake validate`) before accepting the bundle, which the C++ loader
    refuses. Now the rows and candidate texels are counted first and the bundle is refused
    as the loader does (about 1.1 s). The test checks the count that stops it (the message
    names it), not the clock: a wall-time bound failed on a loaded machine (20.9 s against
    20 s) and proves nothing the count does not."""
    b = _sliver_bundle(tmp_path / "slivers.hbundle", 4000)
    line = _validate(b, "atlas", _WORK_BOUND, timeout=300)
    limit = 16 * 1024 * 1024 + 64 * (12 + 4000)
    assert f"atlas.exr: the UV triangles need more than {limit} texel tests" in line, line


def test_atlas_work_bound_is_the_loaders_count(tmp_path):
    """The count is the C++ loader's (runtime/src/io/bundle.cpp: rows and candidate texels
    of the footprint and coverage passes): with this generator both readers accept 1308
    slivers on a 1024 x 1024 atlas and refuse 1309 (checked with `hrt check` on the same
    bundles; their A is set to the UVs' coverage, so that the coverage check, the loader's
    and now hbake's, does not stop them first). A valid bundle needs 1.2-3.2 texel tests per texel (the golden bundles)."""
    ok = _with_coverage_of_the_uvs(_sliver_bundle(tmp_path / "ok.hbundle", 1308))
    assert hb.validate_bundle(ok) == []
    over = _with_coverage_of_the_uvs(_sliver_bundle(tmp_path / "over.hbundle", 1309))
    problems = hb.validate_bundle(over)
    assert [p.cls for p in problems] == ["atlas"], problems
    assert _WORK_BOUND in problems[0].message
    assert f"more than {16 * 1024 * 1024 + 64 * (12 + 1309)} texel tests" in problems[0].message


def _footprint_bbox_scan(uv_tri, width, height):
    """The footprint test as it was (every texel of the triangle's bounding box)."""
    p = hb.texel_coords(uv_tri, width, height)
    lo = np.maximum(np.floor(p.min(axis=0)).astype(np.int64) - 1, [-1, -1])
    hi = np.minimum(np.ceil(p.max(axis=0)).astype(np.int64) + 1, [width, height])
    ci, cj = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="xy")
    ci, cj = ci.ravel(), cj.ravel()
    keep = ((ci >= p[:, 0].min() - 1) & (ci <= p[:, 0].max() + 1)
            & (cj >= p[:, 1].min() - 1) & (cj <= p[:, 1].max() + 1))
    for k in range(3):
        a, b = p[k], p[(k + 1) % 3]
        n = np.array([b[1] - a[1], a[0] - b[0]])
        proj = p @ n
        centre = ci * n[0] + cj * n[1]
        r = abs(n[0]) + abs(n[1])
        keep &= (centre + r >= proj.min()) & (centre - r <= proj.max())
    return np.clip(ci[keep], 0, width - 1), np.clip(cj[keep], 0, height - 1)


@pytest.mark.parametrize("w, h", [(40, 24), (17, 90), (1, 1)])
def test_footprint_spans_equal_the_bounding_box_scan(w, h):
    """Per row only the triangle's span is examined now; the texels (and their order and
    multiplicity, which the messages count) are those of the whole bounding box, also for
    vertices on the texel lattice (exact ties), slivers, degenerate and out-of-range UVs."""
    rng = np.random.default_rng(w * h)
    n = 150
    lattice = np.stack([(rng.integers(-2, 2 * w + 3, (n, 3)) / 2 + 0.5) / w,
                        1 - (rng.integers(-2, 2 * h + 3, (n, 3)) / 2 + 0.5) / h], -1)
    a, b = rng.uniform(0, 1, (n, 1, 2)), rng.uniform(0, 1, (n, 1, 2))
    kinds = [rng.uniform(0, 1, (n, 3, 2)), lattice,
             rng.uniform(0, 1, (n, 1, 2)) + rng.normal(0, 3 / w, (n, 3, 2)),
             np.concatenate([a, b, a + rng.normal(0, 1e-4, (n, 1, 2))], 1),
             np.concatenate([a, b, (a + b) / 2], 1), rng.uniform(-0.5, 1.5, (n, 3, 2))]
    uv = np.concatenate(kinds).astype(np.float32)
    fp = uv_coverage._Footprints(uv, w, h)
    got = [np.concatenate(x) for x in zip(*fp.visit())]
    for t in range(len(uv)):
        want = _footprint_bbox_scan(uv[t].astype(np.float64), w, h)
        sel = got[0] == t
        assert np.array_equal(got[1][sel], want[0]) and np.array_equal(got[2][sel], want[1]), (t, uv[t])


# --------------------------------------------------------------------------- validate refuses what the loader refuses

def _with_coverage_of_the_uvs(bundle: Path) -> Path:
    """The bundle with A = 1 at exactly the texels whose centre lies inside (or within the
    margin of) a UV triangle, so that the coverage check (the C++ loader's, now also
    hbake's) passes; RGB unchanged."""
    m = json.loads((bundle / "manifest.json").read_text())
    atlas = hb.read_atlas_exr(bundle / "atlas.exr")
    _, _, uv = hb.read_coarse_ply(bundle / "coarse.ply")
    h, w = atlas.shape[:2]
    # with A = 1 everywhere no texel stops the check early: `near` is complete
    near = uv_coverage._coverage_check(uv.reshape(-1, 3, 2), w, h, np.ones((h, w), np.float32), 1 << 62)[2]
    atlas[:, :, 3] = near
    hb.write_atlas_exr(bundle / "atlas.exr", atlas, compression=m["files"]["atlas"]["compression"])
    _rehash(bundle, m)
    return bundle
