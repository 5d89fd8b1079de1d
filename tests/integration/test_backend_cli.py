"""`--backend cpu|gl|auto` of `hrt query`, `hrt bench`, `hrt run` and the scene file's
`[run] backend`: the choices, their errors and the fallbacks.

Every case runs the `hrt` binary (tests/hrt_locate.py) on the golden bundles of
tests/golden: the pebble (26 mm, the probe A) resting on the bumpy blob (B). The pebble's
coarse mesh spans z in [-4.71, 5.29] mm about its origin and the blob's top is at
z = 12.28 mm, so at z = 16.8 mm the pebble is 0.2 mm inside the blob's top: one patch
with a force of about 0.3 N (covered, not refused), which is what "same contacts" below
compares on.

None of these tests needs the GL backend to work: they check the paths that must hold on
any machine (no GL context, forced with HRT_EGL_PLATFORM=bogus, which the context code
refuses with one line; auto on a software renderer). The GL backend's own results are
tested elsewhere (runtime/tests/test_gl_depth.cpp).

Conventions checked on every failure: the documented exit code, exactly one line on
stderr starting with "hrt: " and naming the culprit, nothing on stdout, no crash text.
"""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import sessions as S
import trace as T

GOLDEN = Path(__file__).resolve().parents[1] / "golden"
PEBBLE = GOLDEN / "pebble.hbundle"
BLOB = GOLDEN / "bumpy_blob.hbundle"
Z_CONTACT = 0.0168                     # m: the pebble 0.2 mm inside the blob's top (see above)
POSES = ["--pose-a", "0", "0", str(Z_CONTACT), "0", "0", "0", "1", "--pose-b", "0", "0", "0", "0", "0", "0", "1"]
# Exit codes of hrt (runtime/apps/commands.h, docs/guides/runtime.md, "hrt check").
USAGE, SCENE, GL = 2, 4, 7
# Text on stderr that only a crash or an uncaught exception prints.
CRASH_MARKERS = ("Traceback", "terminate called", "what():", "Aborted", "core dumped", "Segmentation",
                 "internal error")
TIMING_COLUMNS = {c for c, unit, _, _ in T.spec_table(T.TRACE_SECTION) if unit == "us"}


def env(**extra) -> dict:
    """The environment of a run: no inherited GL overrides, plus `extra`."""
    e = {k: v for k, v in os.environ.items() if k not in ("HRT_EGL_PLATFORM", "HRT_GL_PROBE")}
    e.update(extra)
    return e


NO_GL = {"HRT_EGL_PLATFORM": "bogus"}  # the context code refuses it: no context at all


def run(hrt, *args, extra_env=None, timeout=300):
    return subprocess.run([hrt, *map(str, args)], capture_output=True, text=True, timeout=timeout,
                          env=env(**(extra_env or {})))


def one_line(stderr: str) -> str:
    lines = stderr.strip("\n").splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{stderr}"
    for m in CRASH_MARKERS:
        assert m not in stderr, f"crash text {m!r} on stderr: {stderr}"
    assert lines[0].startswith("hrt: "), lines[0]
    return lines[0]


def assert_failed(res, code, *needles) -> str:
    assert res.returncode == code, f"exit {res.returncode}, want {code}: {res.stderr}"
    line = one_line(res.stderr)
    for n in needles:
        assert str(n) in line, f"{n!r} not in {line!r}"
    assert res.stdout == "", f"stdout of a failed run: {res.stdout[:500]}"
    return line


def query(hrt, *args, extra_env=None):
    return run(hrt, "query", PEBBLE, BLOB, *POSES, *args, extra_env=extra_env)


def bench(hrt, *args, extra_env=None):
    # The smallest sweep: 4 poses, one pass, N = 16, one copy.
    return run(hrt, "bench", "--a", PEBBLE, "--b", BLOB, *POSES[:8], "--path", "0.002", "0", "0", "--frames", "4",
               "--passes", "1", "--resolutions", "16", "--copies", "1", *args, extra_env=extra_env)


def results(doc: dict) -> dict:
    """What a query computed, without the timings (the only member that differs between runs)."""
    return {k: doc[k] for k in ("pairs", "contacts", "force", "torque", "wrench_b", "warnings")}


def gl_info(hrt) -> dict | None:
    """`hrt gl-info --json` of this machine, None when no context can be made."""
    res = run(hrt, "gl-info", "--json")
    return json.loads(res.stdout) if res.returncode == 0 else None


# ----------------------------------------------------------------------------
# hrt query and hrt bench
# ----------------------------------------------------------------------------


def test_the_pose_is_a_contact(hrt):
    res = query(hrt, "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["options"]["backend"] == "cpu" and "gl" not in doc
    assert len(doc["contacts"]) == 1 and doc["contacts"][0]["covered"] and not doc["contacts"][0]["refused"]
    assert 0.1 < np.linalg.norm(doc["force"]) < 1.0
    assert res.stderr == ""  # the default backend is not announced


@pytest.mark.parametrize("command", ["query", "bench"])
def test_bad_backend_values_are_usage_errors(hrt, command):
    go = query if command == "query" else bench
    assert_failed(go(hrt, "--backend", "bogus"), USAGE, "--backend", "bogus", "cpu", "gl", "auto")
    assert_failed(go(hrt, "--backend", "gl", "--gl-search", "fast"), USAGE, "--gl-search", "fast")
    for steps in ("0", "25", "x", ""):
        assert_failed(go(hrt, "--backend", "gl", "--gl-search", "occlusion", "--occlusion-steps", steps), USAGE,
                      "--occlusion-steps")
    # Settings of a backend or search that would not use them.
    assert_failed(go(hrt, "--gl-search", "occlusion"), USAGE, "--gl-search", "only with --backend gl or auto")
    assert_failed(go(hrt, "--backend", "gl", "--occlusion-steps", "8"), USAGE, "--occlusion-steps",
                  "only with --gl-search occlusion")
    # The GL backend does not implement the Sec. 5.2 shortcut: refused before any GL work.
    assert_failed(go(hrt, "--backend", "gl", "--shortcut", extra_env=NO_GL), USAGE, "--shortcut",
                  "CPU backend only")
    # An unknown heights mode is a usage error.
    assert_failed(go(hrt, "--heights", "quads"), USAGE, "--heights", "quads")


@pytest.mark.parametrize("command", ["query", "bench"])
@pytest.mark.parametrize("json_flag", [[], ["--json"]])
def test_backend_gl_without_a_context_exits_7_with_one_line(hrt, command, json_flag):
    go = query if command == "query" else bench
    line = assert_failed(go(hrt, "--backend", "gl", *json_flag, extra_env=NO_GL), GL, "--backend gl",
                         "HRT_EGL_PLATFORM=bogus")
    assert "error" in line


def test_backend_auto_without_a_context_falls_back_to_the_cpu(hrt):
    cpu = query(hrt, "--backend", "cpu", "--json")
    assert cpu.returncode == 0 and cpu.stderr == "", cpu.stderr
    auto = query(hrt, "--backend", "auto", "--json", extra_env=NO_GL)
    assert auto.returncode == 0, auto.stderr
    line = one_line(auto.stderr)  # said once
    assert "auto -> cpu" in line and "no GL context" in line and "HRT_EGL_PLATFORM=bogus" in line, line
    a, c = json.loads(auto.stdout), json.loads(cpu.stdout)
    assert a["options"]["backend"] == "cpu" and "gl" not in a
    assert results(a) == results(c)  # the same computation, to the bit
    # The table names the backend in its header.
    table = query(hrt, "--backend", "auto", extra_env=NO_GL)
    assert table.returncode == 0, table.stderr
    assert "backend     cpu" in table.stdout.splitlines()[:6], table.stdout
    one_line(table.stderr)


def test_backend_auto_with_the_shortcut_stays_on_the_cpu(hrt):
    res = query(hrt, "--backend", "auto", "--shortcut", "--json")
    assert res.returncode == 0, res.stderr
    line = one_line(res.stderr)
    assert "auto -> cpu" in line and "shortcut" in line, line
    assert json.loads(res.stdout)["options"]["backend"] == "cpu"


def test_the_mesh_heights_run_on_either_backend_with_the_same_numbers(hrt):
    """Both backends implement --heights mesh (the GL one to float32 rounding of the atlas,
    here to the last bit: tests/integration/test_gl_backend.py has the bound); auto decides as for the
    other modes."""
    cpu = query(hrt, "--backend", "cpu", "--heights", "mesh", "--json")
    assert cpu.returncode == 0, cpu.stderr
    context_info(hrt)  # no context: fails under CI, else skips
    gl = query(hrt, "--backend", "gl", "--heights", "mesh", "--json")
    assert gl.returncode == 0, gl.stderr
    a, b = json.loads(cpu.stdout), json.loads(gl.stdout)
    assert a["options"]["heights"] == b["options"]["heights"] == "mesh"
    assert b["options"]["backend"] == "gl"
    assert a["contacts"] and [c["delta"] for c in a["contacts"]] == [c["delta"] for c in b["contacts"]]
    auto = query(hrt, "--backend", "auto", "--heights", "mesh", "--json")
    assert auto.returncode == 0, auto.stderr
    assert "mesh" not in one_line(auto.stderr)


def context_info(hrt) -> dict:
    """hrt gl-info's description; no context fails under CI (which has llvmpipe: make setup
    installs Mesa's EGL), else skips."""
    info = gl_info(hrt)
    if info is None:
        msg = "no OpenGL 4.5 context on this machine (hrt gl-info exits 7)"
        if os.environ.get("CI"):
            pytest.fail(msg + "; CI must have Mesa's llvmpipe (make setup installs it)")
        pytest.skip(msg)
    return info


def assert_probed(line: str, chosen: str):
    """On a hardware renderer auto runs its probe and says the figures, whichever it picks."""
    assert "probe" in line and f"auto -> {chosen}" in line, line


def test_backend_auto_on_a_software_renderer_picks_the_cpu(hrt):
    info = context_info(hrt)
    res = query(hrt, "--backend", "auto", "--json")
    assert res.returncode == 0, res.stderr
    line = one_line(res.stderr)
    if info["hardware"]:
        assert_probed(line, json.loads(res.stdout)["options"]["backend"])
        return
    assert "auto -> cpu" in line and "software renderer" in line and info["renderer"] in line, line
    doc = json.loads(res.stdout)
    assert doc["options"]["backend"] == "cpu" and "gl" not in doc
    assert results(doc) == results(json.loads(query(hrt, "--json").stdout))


def test_bench_backend_auto_without_a_context_runs_on_the_cpu(hrt):
    res = bench(hrt, "--backend", "auto", "--json", extra_env=NO_GL)
    assert res.returncode == 0, res.stderr
    assert "auto -> cpu" in one_line(res.stderr)
    doc = json.loads(res.stdout)
    assert "backend" not in doc["machine"]  # the CPU's output, unchanged
    assert "gl" not in doc["path_results"][0]
    assert doc["path_results"][0]["patches"]["max"] >= 1  # the sweep was in contact
    # And the table: no GL split.
    res = bench(hrt, "--backend", "auto", extra_env=NO_GL)
    assert res.returncode == 0, res.stderr
    assert "GL depth backend" not in res.stdout and "depth backend gl" not in res.stdout


# ----------------------------------------------------------------------------
# hrt run and the scene file
# ----------------------------------------------------------------------------


def scene_tables(folder: Path, **run_keys) -> dict:
    """A 30 ms lockstep session of the pebble held in contact on the blob (N = 16)."""
    still = S.write_trajectory(folder / "still.csv", [0.0, 1.0], [(0, 0, Z_CONTACT)] * 2, [(0, 0, 0, 1)] * 2)
    out = folder / "out"
    out.mkdir(exist_ok=True)
    return {
        "run": {"duration": 0.03, "lockstep": True, **run_keys},
        "object": [{"name": "pebble", "bundle": PEBBLE, "position": [0.0, 0.0, Z_CONTACT]},
                   {"name": "blob", "bundle": BLOB}],
        "force": {"resolution": 16},
        "device": {"trajectory": still},
        "trace": {"path": out / "trace.csv"},
    }


def write_scene(folder: Path, name: str, tables: dict) -> Path:
    path = folder / f"{name}.toml"
    path.write_text(S.scene_toml(tables))
    return path


def line_of(path: Path, needle: str) -> int:
    for i, line in enumerate(path.read_text().splitlines(), start=1):
        if line.startswith(needle):
            return i
    raise AssertionError(f"{needle!r} not in {path}")


def hrt_run(hrt, scene, *args, extra_env=None):
    return run(hrt, "run", scene, *args, extra_env=extra_env)


def physics(trace_path: Path) -> list[list[str]]:
    """The trace's rows without the wall-clock timing columns (docs/trace-format.md)."""
    rows = [r.split(",") for r in trace_path.read_text().splitlines()]
    keep = [i for i, c in enumerate(rows[0]) if c not in TIMING_COLUMNS]
    return [[r[i] for i in keep] for r in rows]


def assert_no_trace(tables):
    p = Path(tables["trace"]["path"])
    assert not p.exists() and not Path(str(p) + ".partial").exists()


def test_run_backend_auto_without_a_context_runs_on_the_cpu(hrt, tmp_path):
    cpu_t = scene_tables(tmp_path, backend="cpu")
    cpu_t["trace"]["path"] = tmp_path / "out" / "cpu.csv"
    cpu = hrt_run(hrt, write_scene(tmp_path, "cpu", cpu_t), "--json")
    assert cpu.returncode == 0 and cpu.stderr == "", cpu.stderr
    auto_t = scene_tables(tmp_path, backend="auto")
    auto_t["trace"]["path"] = tmp_path / "out" / "auto.csv"
    auto = hrt_run(hrt, write_scene(tmp_path, "auto", auto_t), "--json", extra_env=NO_GL)
    assert auto.returncode == 0, auto.stderr
    line = one_line(auto.stderr)
    assert "auto -> cpu" in line and "no GL context" in line, line
    summary = json.loads(auto.stdout)
    assert summary["backend"]["choice"] == "auto" and summary["backend"]["name"] == "cpu"
    assert "renderer" not in summary["backend"]
    assert json.loads(cpu.stdout)["backend"]["name"] == "cpu"
    assert summary["simulation"]["max_patches"] >= 1  # in contact
    # The same session, bit for bit (lockstep), but for the wall-clock timings.
    assert physics(tmp_path / "out" / "auto.csv") == physics(tmp_path / "out" / "cpu.csv")
    # --quiet: nothing at all.
    quiet = hrt_run(hrt, write_scene(tmp_path, "auto", auto_t), "--quiet", extra_env=NO_GL)
    assert quiet.returncode == 0 and quiet.stdout == "" and quiet.stderr == "", quiet.stderr


def test_run_backend_auto_on_a_software_renderer_picks_the_cpu(hrt, tmp_path):
    info = context_info(hrt)
    t = scene_tables(tmp_path)
    res = hrt_run(hrt, write_scene(tmp_path, "s", t), "--backend", "auto", "--json")
    assert res.returncode == 0, res.stderr
    line = one_line(res.stderr)
    if info["hardware"]:
        assert_probed(line, json.loads(res.stdout)["backend"]["name"])
        return
    assert "auto -> cpu" in line and "software renderer" in line, line
    import os
    assert json.loads(res.stdout)["backend"] == {"choice": "auto", "name": "cpu", "message": line[len("hrt: "):],
                                                 "threads": os.cpu_count()}


def test_run_backend_gl_without_a_context_exits_7(hrt, tmp_path):
    # From the scene file: the line names the file and the key.
    t = scene_tables(tmp_path, backend="gl")
    scene = write_scene(tmp_path, "gl", t)
    assert_failed(hrt_run(hrt, scene, extra_env=NO_GL), GL, scene, 'run.backend = "gl"', "HRT_EGL_PLATFORM=bogus")
    assert_no_trace(t)
    assert_failed(hrt_run(hrt, scene, "--json", extra_env=NO_GL), GL, "HRT_EGL_PLATFORM=bogus")
    # --backend gl over a cpu scene: the line names the flag.
    t = scene_tables(tmp_path)
    scene = write_scene(tmp_path, "cpu", t)
    assert_failed(hrt_run(hrt, scene, "--backend", "gl", extra_env=NO_GL), GL, "--backend gl",
                  "HRT_EGL_PLATFORM=bogus")
    assert_no_trace(t)
    # --backend cpu over a gl scene runs without GL.
    res = hrt_run(hrt, write_scene(tmp_path, "gl", scene_tables(tmp_path, backend="gl")), "--backend", "cpu",
                  "--quiet", extra_env=NO_GL)
    assert res.returncode == 0 and res.stderr == "", res.stderr


def test_run_backend_errors(hrt, tmp_path):
    # An unknown backend in the file: a scene error naming the file, the key and its line.
    t = scene_tables(tmp_path, backend="vulkan")
    scene = write_scene(tmp_path, "vulkan", t)
    assert_failed(hrt_run(hrt, scene), SCENE, scene, "run.backend", '"vulkan"', '"cpu", "gl", "auto"',
                  f"(line {line_of(scene, 'backend')})")
    assert_no_trace(t)
    # ... and on the command line, a usage error.
    scene = write_scene(tmp_path, "cpu", scene_tables(tmp_path))
    assert_failed(hrt_run(hrt, scene, "--backend", "vulkan"), USAGE, "--backend", "vulkan")
    # GL settings where no GL backend runs, or out of range.
    t = scene_tables(tmp_path, gl_search="occlusion")
    scene = write_scene(tmp_path, "search", t)
    assert_failed(hrt_run(hrt, scene), SCENE, scene, "run.gl_search", "only with backend")
    t = scene_tables(tmp_path, backend="gl", gl_search="fast")
    scene = write_scene(tmp_path, "fast", t)
    assert_failed(hrt_run(hrt, scene, extra_env=NO_GL), SCENE, scene, "run.gl_search", '"compute", "occlusion"')
    t = scene_tables(tmp_path, backend="auto", gl_search="occlusion", occlusion_steps=25)
    scene = write_scene(tmp_path, "steps", t)
    assert_failed(hrt_run(hrt, scene, extra_env=NO_GL), SCENE, scene, "run.occlusion_steps", "between 1 and 23")
    t = scene_tables(tmp_path, backend="gl", occlusion_steps=8)
    scene = write_scene(tmp_path, "compute_steps", t)
    assert_failed(hrt_run(hrt, scene, extra_env=NO_GL), SCENE, scene, "run.occlusion_steps",
                  'only with gl_search = "occlusion"')
    # The shortcut with the GL backend: refused by the file (exit 4) or against --backend gl (exit 2),
    # before any GL work.
    t = scene_tables(tmp_path, backend="gl")
    t["force"]["shortcut"] = True
    scene = write_scene(tmp_path, "shortcut_gl", t)
    assert_failed(hrt_run(hrt, scene, extra_env=NO_GL), SCENE, scene, "force.shortcut", "CPU backend only")
    t = scene_tables(tmp_path)
    t["force"]["shortcut"] = True
    scene = write_scene(tmp_path, "shortcut", t)
    assert_failed(hrt_run(hrt, scene, "--backend", "gl", extra_env=NO_GL), USAGE, "--backend gl", "shortcut")
    # auto with the shortcut keeps to the cpu, and says so.
    res = hrt_run(hrt, scene, "--backend", "auto", "--json")
    assert res.returncode == 0, res.stderr
    assert "shortcut" in one_line(res.stderr)
    assert json.loads(res.stdout)["backend"]["name"] == "cpu"


def test_a_mesh_heights_session_is_the_same_on_either_backend(hrt, tmp_path):
    """[force] heights = "mesh" with backend = "gl" runs (it was refused before the GL
    backend drew the mesh heights); in lockstep its trace is the CPU's, every column but the
    timings (``*_us``) character for character."""
    context_info(hrt)  # no context: fails under CI, else skips
    traces = {}
    for backend in ("cpu", "gl"):
        folder = tmp_path / backend
        folder.mkdir()
        t = scene_tables(folder, backend=backend)
        t["force"]["heights"] = "mesh"
        res = hrt_run(hrt, write_scene(folder, "mesh", t), "--json")
        assert res.returncode == 0, res.stderr
        out = json.loads(res.stdout)
        assert out["backend"]["name"] == backend
        if backend == "gl":
            assert out["backend"]["last_frame"]["mesh_quads"] > 0
        rows = [line.split(",") for line in (folder / "out" / "trace.csv").read_text().splitlines()]
        keep = [k for k, name in enumerate(rows[0]) if not name.endswith("_us")]
        traces[backend] = [[r[k] for k in keep] for r in rows]
    assert len(traces["cpu"]) > 20 and "contact_fz" in traces["cpu"][0]
    assert traces["cpu"] == traces["gl"]
    assert any(float(r[traces["cpu"][0].index("contact_fz")]) != 0 for r in traces["cpu"][1:])
