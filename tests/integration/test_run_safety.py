"""What `hrt run` (and `hrt query`) guarantee whatever a scene, a plugin or a command line does,
through the real binaries on baked bundles (tests/sessions.py: the "tip", a sphere of radius
S.TIP_R, the "block", 12 x 8 x 4 mm, the "slab", 160 x 60 x 6 mm, each centred on its origin):

- the device's output is bounded at every tick by the ramp times the limit (soft start), and
  never above the limit, not even by one unit in the last place;
- a plugin whose call blocks ends the session (exit 5, the trace written) within a second, and
  a truncated plugin library is refused before it is loaded;
- a FIFO or a device file as an input is refused by name, never read;
- no output path, from the command line or the scene, may be an input;
- every size a value implies is checked before it is allocated (no accepted value takes a
  session or a query past 1 GiB), real-time traces are thinned and capped;
- meaningless values are refused with their documented range;
- messages are one printable line of bounded length;
- the summary reports the achieved rates, not only the nominal ones.

Every bound below is fixed from the scene's own numbers before the run.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import sessions as S
import trace as T
from sessioncli import (CRASH_MARKERS, RES, SLAB_TOP, assert_one_clean_line, example_plugin,  # noqa: F401
                              hrt_run, objects, still, write_scene)

MM = 1e-3
GIB = 1 << 30


def _tables(session_bakes, tmp_path, **over):
    z = SLAB_TOP + S.TIP_R + 1 * MM
    t = {
        "run": {"duration": 0.05, "lockstep": True},
        "object": objects(session_bakes, "tip", (0.0, 0.0, z)),
        "force": {"resolution": RES},
        "device": {"trajectory": still(tmp_path / "still.csv", (0.0, 0.0, z))},
    }
    t.update(over)
    return t


def _failed(res, code, *needles):
    assert res.returncode == code, f"exit {res.returncode}, want {code}: {res.stderr}"
    line = assert_one_clean_line(res.stderr)
    for n in needles:
        assert str(n) in line, f"{n!r} not in {line!r}"
    return line


# Forks and execs the command from a fresh interpreter and reports the child's ru_maxrss:
# Linux carries a process's high-water mark across fork and exec, so a child forked
# straight from pytest (1-2 GB after the whole suite) would report pytest's peak, not its
# own. The fresh interpreter's own mm is small when it forks the command.
_WRAPPER = """
import os, sys
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[2], sys.argv[2:])
_, status, ru = os.wait4(pid, 0)
with open(sys.argv[1], "w") as f:
    f.write(str(ru.ru_maxrss))
sys.exit(os.waitstatus_to_exitcode(status))
"""


def _peak_rss(cmd, timeout=300):
    """(returncode, stderr, peak RSS bytes) of one run of ``cmd`` (Linux: ru_maxrss in KiB)."""
    import tempfile

    with tempfile.NamedTemporaryFile("r", suffix=".rss") as out:
        r = subprocess.run([sys.executable, "-c", _WRAPPER, out.name, *map(str, cmd)], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True, timeout=timeout)
        kib = int(open(out.name).read() or 0)
    return r.returncode, r.stderr, kib * 1024


# ----------------------------------------------------------------------------
# 1-2. The output bound: ramp x limit at every tick, never above the limit by rounding
# ----------------------------------------------------------------------------

MAX_F, MAX_T, SOFT = 4.0, 0.05, 0.5


@pytest.mark.parametrize("kind", ["scripted", "virtual"])
def test_soft_start_bounds_the_output_at_every_tick_with_the_probe_deep_inside(session_bakes, hrt, tmp_path, kind):
    # The block's target 5 mm inside the slab from t = 0, the block itself starting 0.05 mm in,
    # tilted 0.02 rad so the contact has a torque. A stiff contact (1e5 N/m: 5 N at 50 um)
    # holds the block near the surface, so the coupling (2000 N/m) asks for about
    # 2000 x 5 mm = 10 N, more than twice the 4 N limit, from the first frame. The handle is
    # a scripted device holding still there, or a virtual one (the viewer's) left there.
    q = S.quat([1, 0.3, 0], 0.02)
    lift = (S.BLOCK[1] / 2) * math.sin(0.02) + (S.BLOCK[2] / 2) * math.cos(0.02)
    z = SLAB_TOP + lift
    log_path, trace_path = tmp_path / "ticks.csv", tmp_path / "trace.csv"
    scene = write_scene(tmp_path, "deep", {
        "run": {"duration": 0.8, "lockstep": True},
        "object": objects(session_bakes, "block", (0.0, 0.0, z - 0.05 * MM), q),
        "force": {"resolution": RES, "stiffness": 1e5},
        "device": {**({"trajectory": still(tmp_path / "deep.csv", (0.0, 0.0, z - 5 * MM), q)} if kind == "scripted"
                      else {"type": "virtual", "start_position": [0.0, 0.0, z - 5 * MM], "start_orientation": q}),
                   "max_force": MAX_F, "max_torque": MAX_T},
        "loop": {"soft_start": SOFT},
        "trace": {"path": trace_path, "device_log": log_path},
    })
    res = hrt_run(hrt, scene, "--json")
    assert res.returncode == 0, res.stderr
    log = np.genfromtxt(log_path, delimiter=",", names=True)
    t = log["t"]
    f = np.sqrt(log["fx"] ** 2 + log["fy"] ** 2 + log["fz"] ** 2)
    tq = np.sqrt(log["tx"] ** 2 + log["ty"] ** 2 + log["tz"] ** 2)
    ramp = np.clip(t / SOFT, 0.0, 1.0)  # the soft start begins at the first command, t >= 0
    over_f = f - ramp * MAX_F
    over_t = tq - ramp * MAX_T
    print(f"{len(t)} ticks; worst |F| - ramp x max {over_f.max():.3e} N, |T| - ramp x max {over_t.max():.3e} N m; "
          f"|F| at 0.05 / 0.25 / 0.7 s: {f[np.searchsorted(t, 0.05)]:.3f} / {f[np.searchsorted(t, 0.25)]:.3f} / "
          f"{f[np.searchsorted(t, 0.7)]:.3f} N")
    assert len(t) >= 0.8 / 1e-3
    assert np.all(over_f <= 0.0), f"force above ramp x limit at t = {t[np.argmax(over_f)]}"
    assert np.all(over_t <= 0.0), f"torque above ramp x limit at t = {t[np.argmax(over_t)]}"
    # Not vacuous: the request is far above the limit, so the output rides the bound.
    assert f[np.searchsorted(t, 0.7)] > 0.99 * MAX_F
    assert f[np.searchsorted(t, 0.25)] > 0.45 * MAX_F
    # The trace's written wrench (the device's output when each frame ran) obeys it too.
    tr = T.read_trace(trace_path)
    ft = np.linalg.norm(tr.wrench()[:, :3], axis=1)
    assert np.all(ft <= np.clip(tr["device_t"] / SOFT, 0, 1) * MAX_F)


def test_the_force_clamp_never_exceeds_the_limit_by_rounding(session_bakes, hrt, tmp_path):
    # The tip's target dragged 4 mm deep along a circle over a stiff contact (1e5 N/m): the
    # coupling asks for about 2000 N/m x 4 mm = 8 N, the clamp bites for most of the 0.6 s with
    # the direction turning. Every written force's norm, computed four ways, is <= 5 N exactly
    # (the C++ test TheClampNeverExceedsTheLimitByRounding covers directions over the sphere).
    z = SLAB_TOP + S.TIP_R - 4 * MM
    ts = np.linspace(0.0, 0.6, 61)
    pos = [(3 * MM * math.cos(20 * t), 3 * MM * math.sin(20 * t), z) for t in ts]
    traj = S.write_trajectory(tmp_path / "circle.csv", ts, pos, [(0, 0, 0, 1)] * len(ts))
    log_path = tmp_path / "clamp.csv"
    scene = write_scene(tmp_path, "clamp", {
        "run": {"duration": 0.6, "lockstep": True},
        "object": objects(session_bakes, "tip", (3 * MM, 0.0, SLAB_TOP + S.TIP_R - 0.05 * MM)),
        "force": {"resolution": RES, "stiffness": 1e5},
        "device": {"trajectory": traj, "max_force": 5.0},
        "loop": {"soft_start": 0.01},
        "trace": {"device_log": log_path},
    })
    res = hrt_run(hrt, scene, "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["device_loop"]["force_clamps"] > 300
    rows = [line.split(",") for line in log_path.read_text().splitlines()[1:]]
    worst = 0.0
    for r in rows:
        fx, fy, fz = (float(v) for v in r[8:11])
        for n in (math.sqrt(fx * fx + fy * fy + fz * fz), math.sqrt(fz * fz + fy * fy + fx * fx),
                  math.hypot(fx, fy, fz), float(np.linalg.norm([fx, fy, fz]))):
            worst = max(worst, n)
    print(f"{len(rows)} ticks, largest |F| {worst!r} N against 5.0")
    assert worst <= 5.0


# ----------------------------------------------------------------------------
# 3-4. Plugins that block or are truncated
# ----------------------------------------------------------------------------


def _test_plugin(hrt, case: str) -> Path:
    p = Path(hrt).resolve().parent / f"hrt_test_plugin_{case}.so"
    if not p.is_file():
        pytest.fail(f"the test plugin {case} is not built ({p})")
    return p


def _plugin_scene(session_bakes, tmp_path, plugin, name="plugin", duration=10.0, trace=True, config=""):
    # The test plugins hold the handle at the device's origin: the workspace offset puts
    # that 5 cm above the slab, clear of it.
    z = 0.05
    t = {
        "run": {"duration": duration},
        "object": objects(session_bakes, "tip", (0.0, 0.0, z)),
        "force": {"resolution": RES},
        "workspace": {"offset_position": [0.0, 0.0, z]},
        "device": {"type": "plugin", "plugin": plugin, "config": config},
    }
    if trace:
        t["trace"] = {"path": tmp_path / f"{name}-trace.csv"}
    return write_scene(tmp_path, name, t)


def test_a_plugin_whose_read_blocks_ends_the_session_with_exit_5(session_bakes, hrt, tmp_path):
    plugin = _test_plugin(hrt, "blocking_read")
    scene = _plugin_scene(session_bakes, tmp_path, plugin, "blocking", duration=300.0)
    t0 = time.monotonic()
    res = hrt_run(hrt, scene, "--realtime", timeout=120)
    wall = time.monotonic() - t0
    line = _failed(res, 5, plugin, "read()")
    print(f"{wall:.2f} s: {line}")
    # The plugin blocks on its first read after 0.3 s of poses (bad_plugin.c); the 300 s session
    # ends within the read deadline plus a second (measured 0.85 s with start-up). The bound
    # leaves a wide margin for a loaded machine and still fails a session that runs its course.
    assert wall < 60.0
    assert (tmp_path / "blocking-trace.csv").is_file()  # the trace of what ran is written


def test_sigterm_before_the_stall_is_exit_130(session_bakes, hrt, tmp_path):
    plugin = _test_plugin(hrt, "blocking_read")
    # block_after=20: the plugin gives poses for 20 s of session time; SIGTERM comes first,
    # once the session runs (its trace's .partial exists).
    scene = _plugin_scene(session_bakes, tmp_path, plugin, "term", duration=30.0, config="block_after=20")
    p = subprocess.Popen([hrt, "run", str(scene), "--realtime", "--quiet"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    while not (tmp_path / "term-trace.csv.partial").exists():
        assert p.poll() is None, p.communicate()
        assert time.monotonic() - t0 < 30
        time.sleep(0.01)
    time.sleep(0.5)
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=10)
    assert p.returncode == 130, err
    assert "interrupted" in assert_one_clean_line(err)
    assert (tmp_path / "term-trace.csv").is_file()


@pytest.mark.parametrize("size", ["2000", "half", "minus1"])
def test_a_truncated_plugin_is_refused_before_loading(session_bakes, hrt, tmp_path, size):
    src = example_plugin(hrt)
    cut = tmp_path / "cut.so"
    shutil.copy(src, cut)
    n = {"2000": 2000, "half": src.stat().st_size // 2, "minus1": src.stat().st_size - 1}[size]
    os.truncate(cut, n)
    scene = _plugin_scene(session_bakes, tmp_path, cut, "cut", duration=0.2, trace=False)
    res = hrt_run(hrt, scene, "--realtime", timeout=30)
    _failed(res, 5, cut)


# ----------------------------------------------------------------------------
# 5. FIFOs and device files as inputs
# ----------------------------------------------------------------------------


def test_fifo_and_device_inputs_are_refused_by_name(session_bakes, hrt, tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    # The scene itself.
    _failed(hrt_run(hrt, fifo, timeout=10), 4, fifo, "is a FIFO")
    _failed(hrt_run(hrt, "/dev/zero", timeout=10), 4, "/dev/zero", "is a character device")
    # The device's trajectory, an object's trajectory, the plugin.
    t = _tables(session_bakes, tmp_path)
    t["device"]["trajectory"] = fifo
    _failed(hrt_run(hrt, write_scene(tmp_path, "tfifo", t), timeout=10), 4, "device.trajectory", "is a FIFO")
    t = _tables(session_bakes, tmp_path)
    t["object"][1]["trajectory"] = "/dev/zero"
    _failed(hrt_run(hrt, write_scene(tmp_path, "ozero", t), timeout=10), 4, "object[1].trajectory",
            "is a character device")
    t = _tables(session_bakes, tmp_path)
    t["run"] = {"duration": 0.05}
    t["device"] = {"type": "plugin", "plugin": fifo}
    _failed(hrt_run(hrt, write_scene(tmp_path, "pfifo", t), timeout=10), 4, "device.plugin", "is a FIFO")


# ----------------------------------------------------------------------------
# 6. Outputs never overwrite inputs
# ----------------------------------------------------------------------------


def test_no_output_may_be_an_input(session_bakes, hrt, tmp_path):
    t = _tables(session_bakes, tmp_path)
    traj = Path(t["device"]["trajectory"])
    scene = write_scene(tmp_path, "guard", t)
    before = {p: p.read_bytes() for p in (traj, scene)}
    manifest = Path(session_bakes["slab"].bundle) / "manifest.json"
    manifest_bytes = manifest.read_bytes()
    # From the command line: the device's trajectory, the scene, a bundle's file, via a symlink.
    link = tmp_path / "link.csv"
    link.symlink_to(traj)
    for args, needle in ((["--trace", str(traj)], "the device's trajectory"),
                         (["--device-log", str(scene)], "the scene file"),
                         (["--trace", str(manifest)], "bundle"),
                         (["--trace", str(link)], "the device's trajectory"),
                         (["--trace", str(traj) + ".partial"], "")):
        res = hrt_run(hrt, scene, *args)
        if needle == "":  # PATH.partial of an input is not the input: allowed, and nothing clobbered
            assert res.returncode == 0, res.stderr
            continue
        _failed(res, 6, args[1], needle, "would destroy an input")
    # From the scene file: [trace] path = the scene itself, device_log = a manifest.
    t2 = _tables(session_bakes, tmp_path)
    t2["trace"] = {"path": tmp_path / "self.toml"}
    selfscene = write_scene(tmp_path, "self", t2)
    _failed(hrt_run(hrt, selfscene), 6, "trace.path", "the scene file")
    t3 = _tables(session_bakes, tmp_path)
    t3["trace"] = {"device_log": manifest}
    _failed(hrt_run(hrt, write_scene(tmp_path, "man", t3)), 6, "trace.device_log", "bundle")
    # A hard link to the trajectory is the same file.
    hard = tmp_path / "hard.csv"
    os.link(traj, hard)
    _failed(hrt_run(hrt, scene, "--trace", str(hard)), 6, "the device's trajectory")
    # Nothing was written over any of them.
    for p, b in before.items():
        assert p.read_bytes() == b, p
    assert manifest.read_bytes() == manifest_bytes
    assert selfscene.read_text().startswith("[run]")


# ----------------------------------------------------------------------------
# 7. Sizes implied by values: checked before allocating; no accepted value passes 1 GiB
# ----------------------------------------------------------------------------


def test_sizes_are_checked_before_allocating(session_bakes, hrt, tmp_path):
    t = _tables(session_bakes, tmp_path)
    t["trace"] = {"device_log": tmp_path / "log.csv"}
    scene = write_scene(tmp_path, "sizes", t)
    # --duration on the command line cannot bypass the device-log limit.
    _failed(hrt_run(hrt, scene, "--duration", "20000", timeout=30), 2, "--duration", "log_capacity", "2000000")
    # A period of 1 ns (2e8 ticks for 0.2 s) and a 10^7-row log are outside their ranges.
    t = _tables(session_bakes, tmp_path)
    t["loop"] = {"period": 1e-9}
    _failed(hrt_run(hrt, write_scene(tmp_path, "period", t), timeout=30), 4, "loop.period", "between")
    t = _tables(session_bakes, tmp_path)
    t["loop"] = {"log_capacity": 10_000_000}
    _failed(hrt_run(hrt, write_scene(tmp_path, "cap", t), timeout=30), 4, "loop.log_capacity", "between")
    t = _tables(session_bakes, tmp_path)
    t["run"]["duration"] = 3e5
    _failed(hrt_run(hrt, write_scene(tmp_path, "long", t), timeout=30), 4, "run.duration", "between")
    # hrt query: a resolution past the limit is a usage error, not 2 GB.
    b = session_bakes["slab"].bundle
    res = subprocess.run([hrt, "query", str(b), str(b), "--pose-a", *"0 0 0 0 0 0 1".split(),
                          "--pose-b", *"0 0 0.005 0 0 0 1".split(), "--resolution", "4096"],
                         capture_output=True, text=True, timeout=60)
    _failed(res, 2, "resolution", "1024")


def test_the_largest_accepted_values_stay_under_a_gibibyte(session_bakes, hrt, tmp_path):
    # The largest device log the reader accepts, for a 0.2 s session: allocated for the
    # session's ticks, not for the capacity.
    t = _tables(session_bakes, tmp_path)
    t["run"]["duration"] = 0.2
    t["loop"] = {"log_capacity": 2_000_000}
    t["trace"] = {"device_log": tmp_path / "biglog.csv"}
    rc, err, rss = _peak_rss([hrt, "run", str(write_scene(tmp_path, "biglog", t)), "--quiet"])
    assert rc == 0, err
    print(f"log_capacity = 2e6, 0.2 s: peak RSS {rss / 2**20:.0f} MiB")
    assert rss < GIB
    # The largest resolution hrt query accepts, on the tip pressed into the slab.
    tip, slab = session_bakes["tip"].bundle, session_bakes["slab"].bundle
    z = SLAB_TOP + S.TIP_R - 0.3 * MM
    rc, err, rss = _peak_rss([hrt, "query", str(tip), str(slab), "--pose-a", "0", "0", repr(z), "0", "0", "0", "1",
                              "--pose-b", *"0 0 0 0 0 0 1".split(), "--resolution", "1024"])
    assert rc == 0, err
    print(f"hrt query --resolution 1024: peak RSS {rss / 2**20:.0f} MiB")
    assert rss < GIB


def test_realtime_traces_are_thinned_to_the_rate_and_capped(session_bakes, hrt, tmp_path):
    t = _tables(session_bakes, tmp_path)
    t["run"] = {"duration": 1.0}  # real time: frames out of contact run at several kHz
    trace_path = tmp_path / "rt.csv"
    t["trace"] = {"path": trace_path}
    res = hrt_run(hrt, write_scene(tmp_path, "rt", t), "--json", timeout=60)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    rows = T.read_trace(trace_path)
    print(f"{summary['frames']} frames, {len(rows)} trace rows in {summary['wall_s']:.2f} s")
    # At most 1 kHz of session time (+1 for the first row), whatever the frame rate.
    assert len(rows) <= 1000 * 1.0 + 1
    assert summary["trace_rows"] == len(rows)
    assert np.all(np.diff(rows["t"]) >= 1e-3 * (1 - 1e-9))
    # A size cap ends the trace with a warning, not the session.
    t["trace"] = {"path": trace_path, "max_bytes": 1_000_000, "rate": 100000}
    res = hrt_run(hrt, write_scene(tmp_path, "capped", t), "--json", timeout=60)
    assert res.returncode == 0, res.stderr
    assert "max_bytes" in res.stderr and "the session ran on" in res.stderr
    assert json.loads(res.stdout)["trace_truncated"] is True
    assert trace_path.stat().st_size <= 1_000_000
    assert len(T.read_trace(trace_path)) > 100


# ----------------------------------------------------------------------------
# 8. Meaningless values are refused with their range
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("table,key,value", [
    ("device", "max_stiffness", 1e308), ("device", "max_stiffness", 0.5), ("device", "max_force", 1e6),
    ("device", "max_torque", 1e-9), ("force", "stiffness", 1e12), ("probe", "density", 1e9),
    ("loop", "soft_start", 1e5), ("loop", "watchdog", 1e-6), ("workspace", "scale", 1e9),
    ("friction", "mu_static", 1e3), ("force", "fade_time", 1e4), ("loop", "max_force_rate", 1e300),
])
def test_values_outside_their_documented_range_are_refused(session_bakes, hrt, tmp_path, table, key, value):
    t = _tables(session_bakes, tmp_path)
    t.setdefault(table, {})[key] = value
    line = _failed(hrt_run(hrt, write_scene(tmp_path, f"{table}-{key}", t)), 4, f"{table}.{key}", "between")
    # The range is the one docs/scene-format.md gives.
    doc = (S.REPO / "docs" / "scene-format.md").read_text()
    row = next(r for r in doc.splitlines() if r.startswith(f"| `{key}` |"))
    lo_hi = line.split("between ")[1].split(",")[0]
    lo, hi = lo_hi.split(" and ")
    assert lo in row and hi.split()[0] in row, (row, line)


# ----------------------------------------------------------------------------
# 9. Messages: one printable line of bounded length
# ----------------------------------------------------------------------------


def test_messages_are_short_and_printable(session_bakes, hrt, tmp_path):
    t = _tables(session_bakes, tmp_path)
    t["run"]["backend"] = "x" * 900_000  # under the 1 MiB scene limit
    line = _failed(hrt_run(hrt, write_scene(tmp_path, "big", t)), 4, "run.backend")
    assert len(line) < 1200
    traj = tmp_path / "nul.csv"
    traj.write_bytes(b"t,x,y,z,qx,qy,qz,qw\n0,0,0,0\x00\x1b[31m,0,0,0,1\n")
    t = _tables(session_bakes, tmp_path)
    t["device"]["trajectory"] = traj
    res = subprocess.run([hrt, "run", str(write_scene(tmp_path, "nul", t))], capture_output=True, timeout=30)
    assert res.returncode == 4
    assert b"\x00" not in res.stderr and b"\x1b" not in res.stderr
    assert b"\\x00" in res.stderr
    # Bundle errors name their class first, from every command (hrt query, hrt run, hrt check).
    missing = tmp_path / "nowhere.hbundle"
    pose = "0 0 0 0 0 0 1".split()
    res = subprocess.run([hrt, "query", str(missing), str(missing), "--pose-a", *pose, "--pose-b", *pose],
                         capture_output=True, text=True, timeout=30)
    assert _failed(res, 3).startswith(f"hrt: error: io: {missing}: ")
    res = subprocess.run([hrt, "check", str(missing)], capture_output=True, text=True, timeout=30)
    assert _failed(res, 3).startswith(f"hrt: error: io: {missing}: ")
    # A scene larger than its limit is refused before it is read.
    big = tmp_path / "huge.toml"
    big.write_bytes(b"#" * (2 << 20))
    _failed(hrt_run(hrt, big), 4, "bytes, more than the limit")


# ----------------------------------------------------------------------------
# 10. Achieved rates
# ----------------------------------------------------------------------------


def test_the_summary_reports_achieved_rates(session_bakes, hrt, tmp_path):
    t = _tables(session_bakes, tmp_path)
    t["run"] = {"duration": 1.0}
    scene = write_scene(tmp_path, "rates", t)
    res = hrt_run(hrt, scene, "--json", timeout=60)
    assert res.returncode == 0, res.stderr
    j = json.loads(res.stdout)
    dl = j["device_loop"]
    assert dl["achieved_rate_hz"] == pytest.approx(dl["ticks"] / j["wall_s"], rel=1e-9)
    assert dl["nominal_rate_hz"] == 1000.0
    assert dl["missed_deadlines"] >= 0
    assert j["simulation"]["achieved_rate_hz"] == pytest.approx(j["frames"] / j["wall_s"], rel=1e-9)
    res = hrt_run(hrt, scene, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "Hz achieved of 1000 Hz" in res.stdout and "missed deadlines" in res.stdout
