"""`hbake bake` on bad input: one clear line, a distinct exit code, nothing left behind.

The corpus is generated here. Every case runs
the real console script in a subprocess and checks:
  * the exit code is the documented one (hbake/errors.py), distinct per kind;
  * stderr is exactly one line, starting with 'hbake: ', naming the culprit;
  * no Python traceback anywhere in the output;
  * the output directory holds nothing new (no bundle, no temporary directory).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hbake.errors import (
    EXIT_INPUT_INVALID, EXIT_INPUT_MISSING, EXIT_INTERRUPTED, EXIT_OUTPUT_EXISTS,
    EXIT_OUTPUT_UNWRITABLE,
)


def _hbake() -> list[str]:
    script = Path(sys.executable).with_name("hbake")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "from hbake.cli import main; main()"]


def _env() -> dict:
    env = dict(os.environ)
    env.pop("FORCE_COLOR", None)
    env["NO_COLOR"] = "1"
    env["COLUMNS"] = "200"  # so that a wrapped message is not mistaken for a second line
    return env


def _snapshot(d: Path) -> list[str]:
    return sorted(str(p.relative_to(d)) for p in d.rglob("*"))


#: Fragments of Python internals that a clear message for a user must not show.
_INTERNALS = ("No module named", "has no attribute", "NoneType", "object is not", "KeyError",
              "IndexError", "ValueError", "internal error")


def _check_failure(proc_rc: int, stdout: str, stderr: str, want_rc: int, mentions: list[str]):
    assert "Traceback" not in stdout + stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, f"expected exactly one line on stderr, got {len(lines)}:\n{stderr}"
    assert lines[0].startswith("hbake: "), lines[0]
    leaked = [frag for frag in _INTERNALS if frag in lines[0]]
    assert not leaked, f"the message shows Python internals ({leaked}): {lines[0]}"
    for m in mentions:
        assert m in lines[0], f"{m!r} not in {lines[0]!r}"
    assert proc_rc == want_rc, f"exit code {proc_rc}, expected {want_rc}; stderr: {stderr}"


def _bake(args: list[str], cwd: Path, timeout: float = 120):
    return subprocess.run(_hbake() + ["bake"] + args, cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=_env())


# --------------------------------------------------------------------------- the corpus

def _tetra_obj(nan: bool = False) -> str:
    x = "nan" if nan else "0"
    return ("v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv " + x + " 0 0.01\n"
            "f 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n")


def _sphere(path: Path, subdivisions: int = 3) -> Path:
    import trimesh
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.02)
    m.export(path)
    return path


CORPUS = {
    # name: (file name, bytes or str, expected exit code)
    "empty_obj": ("empty.obj", b"", EXIT_INPUT_INVALID),
    "empty_stl": ("empty.stl", b"", EXIT_INPUT_INVALID),
    "random_ply": ("noise.ply", np.random.default_rng(1).bytes(4096), EXIT_INPUT_INVALID),
    "random_stl": ("noise.stl", np.random.default_rng(2).bytes(4096), EXIT_INPUT_INVALID),
    "random_obj": ("noise.obj", np.random.default_rng(3).bytes(4096), EXIT_INPUT_INVALID),
    "random_off": ("noise.off", np.random.default_rng(4).bytes(4096), EXIT_INPUT_INVALID),
    "random_glb": ("noise.glb", np.random.default_rng(5).bytes(4096), EXIT_INPUT_INVALID),
    "nan_vertex_obj": ("nan.obj", _tetra_obj(nan=True), EXIT_INPUT_INVALID),
    "nan_vertex_ply": ("nan.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n"
                       "property float y\nproperty float z\nelement face 4\n"
                       "property list uchar int vertex_indices\nend_header\n"
                       "0 0 0\n0.01 0 0\n0 0.01 0\n0 0 nan\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n",
                       EXIT_INPUT_INVALID),
    "only_degenerate_faces": ("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\n"
                              "f 1 2 3\nf 2 3 4\nf 1 1 2\nf 4 4 4\n", EXIT_INPUT_INVALID),
    "unsupported_extension": ("model.fbx", _tetra_obj(), EXIT_INPUT_INVALID),
    "no_extension": ("model", _tetra_obj(), EXIT_INPUT_INVALID),
}


@pytest.mark.parametrize("case", sorted(CORPUS))
def test_bad_input(tmp_path, case):
    name, content, rc = CORPUS[case]
    src = tmp_path / name
    src.write_bytes(content if isinstance(content, bytes) else content.encode())
    out = tmp_path / "out"
    out.mkdir()
    r = _bake([str(src), "-o", str(out / "x.hbundle"), "--units", "m"], tmp_path)
    _check_failure(r.returncode, r.stdout, r.stderr, rc, [name])
    assert _snapshot(out) == []


def test_missing_input(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    r = _bake([str(tmp_path / "nothere.obj"), "-o", str(out / "x.hbundle"), "--units", "m"], tmp_path)
    _check_failure(r.returncode, r.stdout, r.stderr, EXIT_INPUT_MISSING, ["nothere.obj"])
    assert _snapshot(out) == []


def test_input_is_a_directory(tmp_path):
    (tmp_path / "dir.obj").mkdir()
    out = tmp_path / "out"
    out.mkdir()
    r = _bake([str(tmp_path / "dir.obj"), "-o", str(out / "x.hbundle"), "--units", "m"], tmp_path)
    _check_failure(r.returncode, r.stdout, r.stderr, EXIT_INPUT_MISSING, ["dir.obj"])
    assert _snapshot(out) == []


def test_existing_output_without_force(tmp_path):
    src = _sphere(tmp_path / "ball.ply")
    out = tmp_path / "out"
    out.mkdir()
    existing = out / "x.hbundle"
    existing.mkdir()
    (existing / "manifest.json").write_text('{"format": "hbundle"}\n')
    before = _snapshot(out)
    r = _bake([str(src), "-o", str(existing), "--units", "m"], tmp_path)
    _check_failure(r.returncode, r.stdout, r.stderr, EXIT_OUTPUT_EXISTS, ["x.hbundle"])
    assert _snapshot(out) == before
    assert (existing / "manifest.json").read_text() == '{"format": "hbundle"}\n'


def test_unwritable_output_directory(tmp_path):
    """The output's parent is a regular file, so no directory can be made there
    (permission bits would not do: the tests may run as root, which ignores them)."""
    src = _sphere(tmp_path / "ball.ply")
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("")
    before = _snapshot(tmp_path)
    r = _bake([str(src), "-o", str(blocker / "x.hbundle"), "--units", "m"], tmp_path)
    _check_failure(r.returncode, r.stdout, r.stderr, EXIT_OUTPUT_UNWRITABLE, ["not_a_dir"])
    assert _snapshot(tmp_path) == before


def test_missing_output_parent(tmp_path):
    src = _sphere(tmp_path / "ball.ply")
    before = _snapshot(tmp_path)
    r = _bake([str(src), "-o", str(tmp_path / "no" / "such" / "x.hbundle"), "--units", "m"], tmp_path)
    _check_failure(r.returncode, r.stdout, r.stderr, EXIT_OUTPUT_UNWRITABLE, ["no/such"])
    assert _snapshot(tmp_path) == before


def test_exit_codes_are_distinct():
    codes = [EXIT_INPUT_MISSING, EXIT_INPUT_INVALID, EXIT_OUTPUT_EXISTS, EXIT_OUTPUT_UNWRITABLE,
             EXIT_INTERRUPTED]
    assert len(set(codes)) == len(codes) and 0 not in codes and 1 not in codes


# --------------------------------------------------------------------------- Ctrl-C

@pytest.fixture(scope="module")
def big_mesh(tmp_path_factory) -> Path:
    """A 327,680-triangle bumpy sphere: baking it takes seconds, so a signal lands mid-bake."""
    import trimesh
    m = trimesh.creation.icosphere(subdivisions=7, radius=0.03)
    v = np.asarray(m.vertices)
    d = v / np.linalg.norm(v, axis=1, keepdims=True)
    bumps = 1 + 0.02 * np.sin(40 * d[:, 0]) * np.sin(37 * d[:, 1] + 1.0) * np.cos(29 * d[:, 2])
    m = trimesh.Trimesh(v * bumps[:, None], m.faces, process=False)
    path = tmp_path_factory.mktemp("big") / "bumpy.ply"
    m.export(path)
    return path


#: Seconds to wait for a bake to stop after SIGINT/SIGTERM before dumping where it is
#: stuck, and the time it must have stopped in. The bake runs in a forked child that
#: the hbake process kills on a signal (hbake/guard.py), so even a native call that
#: holds the GIL cannot delay it; 5 s leaves room for a loaded 2-core machine.
STOP_TIMEOUT = 60
STOP_WITHIN = 5.0


def _family(pid: int) -> list[int]:
    """``pid`` and its descendants (the bake runs in a child of the hbake process)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                todo += [int(c) for c in Path(f"/proc/{p}/task/{task}/children").read_text().split()]
        except OSError:
            pass
    return out


def _wait_until_open(pid: int, path: Path, timeout: float) -> bool:
    """Poll /proc until process ``pid`` or a child of it has ``path`` open (it has
    started reading it)."""
    target = str(path.resolve())
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if not Path(f"/proc/{pid}").exists():
            return False
        for p in _family(pid):
            fd_dir = Path(f"/proc/{p}/fd")
            try:
                for fd in os.listdir(fd_dir):
                    try:
                        if os.readlink(fd_dir / fd) == target:
                            return True
                    except OSError:
                        pass
            except OSError:
                pass
        time.sleep(0.002)
    return False


@pytest.mark.parametrize("sig, extra_delay", [
    (signal.SIGINT, 0.0),   # while loading the input
    (signal.SIGINT, 1.5),   # 1-2 s in: simplification (pymeshlab)
    (signal.SIGINT, 2.0),   # later in the bake
    (signal.SIGTERM, 2.0),  # a pipeline's kill: same clean exit
])
def test_interrupt_during_bake(tmp_path, big_mesh, sig, extra_delay):
    if not Path("/proc/self/fd").exists():
        pytest.skip("needs /proc to see when the bake has opened its input")
    out = tmp_path / "out"
    out.mkdir()
    env = _env()
    # if the bake does not stop, SIGABRT makes faulthandler print where it is stuck
    env["PYTHONFAULTHANDLER"] = "1"
    proc = subprocess.Popen(_hbake() + ["bake", str(big_mesh), "-o", str(out / "big.hbundle"),
                                        "--units", "m"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    family = []
    try:
        started = _wait_until_open(proc.pid, big_mesh, timeout=60)
        family = _family(proc.pid)
        assert started or proc.poll() is None, "the bake never opened its input"
        time.sleep(extra_delay)
        assert proc.poll() is None, (
            f"the bake ended (rc {proc.returncode}) before the signal: make the mesh bigger")
        proc.send_signal(sig)
        t_signal = time.monotonic()
        try:
            stdout, stderr = proc.communicate(timeout=STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            _, stuck = proc.communicate(timeout=30)
            pytest.fail(f"the bake was still running {STOP_TIMEOUT} s after {sig.name}; "
                        f"where it was:\n{stuck[-3000:]}")
        stopped_after = time.monotonic() - t_signal
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    time.sleep(0.2)
    survivors = [p for p in family if Path(f"/proc/{p}").exists()
                 and "Z" not in Path(f"/proc/{p}/stat").read_text().split(")")[-1][:3]]
    assert survivors == [], f"processes of the bake still run after {sig.name}: {survivors}"
    # Stages completed before the signal each printed their progress line (stderr is not a
    # terminal: hbake/progress.py); the interruption itself is one line, the last.
    progress = [ln for ln in stderr.splitlines() if ln.startswith("hbake: stage ")]
    assert stderr.splitlines()[:len(progress)] == progress, stderr
    stderr = "".join(ln + "\n" for ln in stderr.splitlines() if not ln.startswith("hbake: stage "))
    _check_failure(proc.returncode, stdout, stderr, EXIT_INTERRUPTED, [])
    assert "interrupt" in stderr.lower() or "signal" in stderr.lower(), stderr
    assert _snapshot(out) == [], "the interrupted bake left files behind"
    assert stopped_after < STOP_WITHIN, f"{sig.name}: stopped {stopped_after:.2f} s after the signal"
    print(f"{sig.name}: stopped {stopped_after:.2f} s after the signal")
