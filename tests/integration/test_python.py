"""The Python module `hrt` (nanobind bindings of the runtime, built by `make setup`) against
the `hrt` command on the same inputs: identical numbers, the same error classes and
messages, and no leak over many queries."""
from __future__ import annotations

import json
import os
import subprocess

from pathlib import Path

import numpy as np
import pytest

from hrt_locate import REPO, hrt_binary

try:
    import hrt
except ImportError as exc:  # make setup builds it and puts it on the venv's path
    if os.environ.get("CI"):
        raise AssertionError(f"the hrt Python module is not importable ({exc}), but CI must run these tests")
    pytest.skip(f"the hrt Python module is not built (make setup): {exc}", allow_module_level=True)

GOLDEN = REPO / "tests" / "golden"
PEBBLE, BLOB, RIDGED = GOLDEN / "pebble.hbundle", GOLDEN / "bumpy_blob.hbundle", GOLDEN / "ridged_box.hbundle"
IDENTITY = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
# The pebble 0.2 mm into the blob's top, and turned by 0.4 rad about (0.3, 0.2, 0.93) off-centre.
POSES_A = [
    [0.0, 0.0, 0.0168, 0.0, 0.0, 0.0, 1.0],
    [0.001, -0.0005, 0.0167, 0.05975336508961, 0.0398355767264, 0.18523543177778, 0.98006657784124],
]


def cli_query(pose_a: list[float], *options: str) -> dict:
    r = subprocess.run([hrt_binary(), "query", str(PEBBLE), str(BLOB), "--pose-a", *map(repr, pose_a),
                        "--pose-b", *map(repr, IDENTITY), "--json", *options], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def models():
    return hrt.load_bundle(str(PEBBLE)), hrt.load_bundle(str(BLOB))


@pytest.mark.parametrize("options,kwargs", [
    ((), {}),
    (("--resolution", "64", "--heights", "coarse"), {"resolution": 64, "heights": "coarse"}),
    (("--stiffness", "2500", "--shortcut"), {"stiffness": 2500.0, "shortcut": True}),
])
def test_query_equals_cli(models, options, kwargs):
    scene = hrt.Scene(list(models), **kwargs)
    for pose_a in POSES_A:
        scene.reset()  # `hrt query` runs a first frame
        got = scene.query(np.array([pose_a, IDENTITY]))
        want = cli_query(pose_a, *options)
        assert len(want["contacts"]) >= 1
        assert got["force"].tolist() == want["force"] and got["torque"].tolist() == want["torque"]
        assert got["pairs"] == want["pairs"]
        p = got["patches"]
        assert p["delta"].tolist() == [c["delta"] for c in want["contacts"]]
        assert p["n"].tolist() == [c["n"] for c in want["contacts"]]
        assert p["grad"].tolist() == [c["grad"] for c in want["contacts"]]
        assert p["force"].tolist() == [c["force"] for c in want["contacts"]]
        assert p["torque"].tolist() == [c["torque"] for c in want["contacts"]]
        assert p["delta_bound"].tolist() == [c["delta_bound"] for c in want["contacts"]]
        assert list(p["covered"]) == [c["covered"] for c in want["contacts"]]
        assert got["wrench_b"][1].tolist() == want["wrench_b"][0]["force"] + want["wrench_b"][0]["torque"]


def test_model_properties(models):
    a, _ = models
    assert a.format_version == f"{hrt.BUNDLE_FORMAT_MAJOR}.{hrt.BUNDLE_FORMAT_MINOR}"
    assert a.vertices.shape == (14, 3) and a.vertices.dtype == np.float64 and a.num_faces == 24
    assert a.center_of_mass.shape == (3,) and a.volume > 0
    assert "pebble" in repr(a)


def test_a_model_used_twice_and_outliving_its_names():
    """The scene keeps its models alive; the same model may be several objects."""
    scene = hrt.Scene([hrt.load_bundle(str(PEBBLE)), hrt.load_bundle(str(BLOB))])
    r = scene.query(np.array([POSES_A[0], IDENTITY]))
    assert r["patches"]["delta"].shape == (1,)
    blob = hrt.load_bundle(str(BLOB))
    two = hrt.Scene([hrt.load_bundle(str(PEBBLE)), blob, blob])
    assert two.size == 3
    r2 = two.query(np.array([POSES_A[0], IDENTITY, [1.0, 0, 0, 0, 0, 0, 1]]))
    assert r2["force"].tolist() == r["force"].tolist()


def test_successive_queries_track_patches(models):
    """Queries on one Scene are frames of one session (patch ids kept); reset() starts over."""
    scene = hrt.Scene(list(models))
    first = scene.query(np.array([POSES_A[0], IDENTITY]))
    again = scene.query(np.array([POSES_A[0], IDENTITY]))
    assert again["patches"]["id"] == first["patches"]["id"]
    moved = scene.query(np.array([POSES_A[1], IDENTITY]))
    scene.reset()
    fresh = scene.query(np.array([POSES_A[1], IDENTITY]))
    assert fresh["force"].tolist() == cli_query(POSES_A[1])["force"]
    assert moved["patches"]["delta"].shape == fresh["patches"]["delta"].shape


def test_bundle_errors_match_the_cli():
    """Every corrupt golden bundle: hrt.BundleError with the CLI's class and message."""
    index = json.loads((GOLDEN / "corrupt" / "index.json").read_text())
    for v in index["variants"]:
        path = str(GOLDEN / "corrupt" / v["bundle"])
        with pytest.raises(hrt.BundleError) as e:
            hrt.load_bundle(path)
        assert isinstance(e.value, ValueError)
        assert e.value.error_class == v["class"], v["name"]
        r = subprocess.run([hrt_binary(), "check", path], capture_output=True, text=True)
        assert r.returncode == 3  # hrt: a bundle that cannot be loaded
        assert r.stderr.strip().splitlines()[-1] == f"hrt: error: {e.value.error_class}: {e.value}", v["name"]
    with pytest.raises(hrt.BundleError, match="does not exist") as e:
        hrt.load_bundle(str(REPO / "no-such.hbundle"))
    assert e.value.error_class == "io"


def test_bad_arguments_raise_value_errors(models):
    scene = hrt.Scene(list(models))
    with pytest.raises(ValueError, match=r"shape \(2, 7\)"):
        scene.query(np.zeros((3, 7)))
    with pytest.raises(ValueError, match="unit quaternion"):
        scene.query(np.array([[0, 0, 0, 0, 0, 0, 2.0], IDENTITY]))
    with pytest.raises(ValueError, match="not finite"):
        scene.query(np.array([[np.nan, 0, 0, 0, 0, 0, 1.0], IDENTITY]))
    with pytest.raises(ValueError, match="heights"):
        hrt.Scene(list(models), heights="fine")
    with pytest.raises(ValueError, match="resolution"):
        hrt.Scene(list(models), resolution=4)
    with pytest.raises(ValueError, match="at least one other object"):
        hrt.Scene([models[0]])
    with pytest.raises(IndexError):
        scene.tolerance(5)


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def test_no_leak_over_many_queries(models):
    """RSS grows by at most 10 MB over 10,000 queries after 1,000 warm-up queries."""
    scene = hrt.Scene(list(models))
    poses = [np.array([p, IDENTITY]) for p in POSES_A]
    for k in range(1000):
        scene.query(poses[k % 2])
    before = rss_bytes()
    for k in range(10000):
        r = scene.query(poses[k % 2])
    grown = rss_bytes() - before
    assert r["patches"]["delta"].shape == (1,)
    assert grown <= 10 * 2**20, f"RSS grew by {grown / 2**20:.1f} MB"


# ----------------------------------------------------------------------------
# Sessions: hrt.Runner against `hrt run --lockstep`
# ----------------------------------------------------------------------------


def session_scene(tmp_path, name: str) -> Path:
    """The pebble pressed into the bumpy blob and slid 2 mm across it at a 23-degree heading,
    turned by 0.3 rad, over 0.3 s (a scripted device; friction on)."""
    import sessions as S
    q = S.quat([0.2, 0.1, 1.0], 0.3)
    times = np.linspace(0.0, 0.3, 31)
    s = np.clip((times - 0.05) / 0.25, 0.0, 1.0)
    head = np.array([np.cos(np.radians(23)), np.sin(np.radians(23)), 0.0])
    positions = [[0.0, 0.0, 0.0172 - 0.0005 * min(t / 0.05, 1.0)] + 0.002 * si * head for t, si in zip(times, s)]
    traj = S.write_trajectory(tmp_path / f"{name}.csv", times, positions, [q] * len(times))
    tables = {
        "run": {"duration": 0.3, "lockstep": True},
        "object": [{"name": "pebble", "bundle": str(PEBBLE), "position": [0.0, 0.0, 0.0172],
                    "orientation": q},
                   {"name": "blob", "bundle": str(BLOB)}],
        "force": {"resolution": 24},
        "friction": {"enabled": True, "mu_static": 0.3, "mu_dynamic": 0.2},
        "device": {"type": "scripted", "trajectory": str(traj), "max_force": 8.0},
        "trace": {"path": str(tmp_path / f"{name}.trace.csv")},
    }
    path = tmp_path / f"{name}.toml"
    path.write_text(S.scene_toml(tables))
    return path


def trace_without_timings(path) -> list[list[str]]:
    import trace as T
    timing = {c for c, unit, _, _ in T.spec_table(T.TRACE_SECTION) if unit == "us"}
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    header = lines[0].split(",")
    keep = [i for i, c in enumerate(header) if c not in timing]
    return [[row.split(",")[i] for i in keep] for row in lines]


def test_lockstep_session_equals_hrt_run(tmp_path):
    """The same scene through hrt.Runner and `hrt run --lockstep`: the same trace, bit for
    bit but the wall-clock timing columns, and the frames as arrays equal the trace's."""
    scene = session_scene(tmp_path, "slide")
    cli_trace, py_trace = tmp_path / "cli.csv", tmp_path / "py.csv"
    r = subprocess.run([hrt_binary(), "run", str(scene), "--lockstep", "--trace", str(cli_trace), "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    run = hrt.Runner(str(scene), trace=str(py_trace))
    first = run.step()
    assert first is not None and first["probe"].shape == (7,)
    run.run()
    assert run.done and run.step() is None
    assert trace_without_timings(py_trace) == trace_without_timings(cli_trace)
    frames = run.frames
    assert len(frames["t"]) == summary["frames"] and max(frames["patches"]) == summary["simulation"]["max_patches"]
    assert max(frames["patches"]) >= 1, "the scene must make contact"
    assert run.device_loop["ticks"] == summary["device_loop"]["ticks"]
    table = trace_without_timings(cli_trace)
    ti = table[0].index("t")
    t_cli = [float(row[ti]) for row in table[1:]]
    assert frames["t"].tolist() == t_cli


def test_runner_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[run]\nduration = -1\n")
    with pytest.raises(hrt.SceneFileError, match="bad.toml"):
        hrt.Runner(str(bad))
    scene = session_scene(tmp_path, "errors")
    with pytest.raises(hrt.SceneFileError):
        hrt.Runner(str(scene), trace=str(scene))  # an output may never overwrite an input
    with pytest.raises(hrt.SceneFileError, match="--duration"):
        hrt.Runner(str(scene), duration=-2.0)


def test_gl_backend_equals_cli(models):
    """backend='gl' (headless EGL; llvmpipe here) gives `hrt query --backend gl`'s numbers;
    two GL scenes live side by side, and ending one leaves the other working."""
    poses = np.array([POSES_A[1], IDENTITY])
    gl = hrt.Scene(list(models), backend="gl")
    assert gl.backend == "gl" and "gl" in gl.backend_message
    want = cli_query(POSES_A[1], "--backend", "gl")
    got = gl.query(poses)
    assert got["force"].tolist() == want["force"] and got["torque"].tolist() == want["torque"]
    assert got["patches"]["delta"].tolist() == [c["delta"] for c in want["contacts"]]
    other = hrt.Scene(list(models), backend="gl", gl_search="occlusion")
    assert other.query(poses)["patches"]["delta"].shape == (1,)
    del other
    gl.reset()
    assert gl.query(poses)["force"].tolist() == want["force"]
    # auto keeps to the cpu on a software renderer, and always with the shortcut.
    assert hrt.Scene(list(models), backend="auto", shortcut=True).backend == "cpu"
    with pytest.raises(ValueError, match="shortcut"):
        hrt.Scene(list(models), backend="gl", shortcut=True)
    with pytest.raises(ValueError, match="backend"):
        hrt.Scene(list(models), backend="vulkan")
    with pytest.raises(ValueError, match="gl_search"):
        hrt.Scene(list(models), backend="gl", gl_search="binary")
