"""`hrt run` end to end: the UDP bridge
driven by examples/udp_device.py's encoder, the example device plugin loaded from a
scene file, lockstep reproducibility and replay of a trace, Ctrl-C, the error exits,
the 3-DoF torque policy and the soft start, all through the `hrt` binary on baked
bundles (tests/sessions.py: the "tip", a sphere of radius S.TIP_R, the "block",
12 x 8 x 4 mm, and the "slab", 160 x 60 x 6 mm, each centred on its origin, so the slab's
top is z = 3 mm; every height below is written from those constants).

The lockstep scenes run at `[force] resolution = 16` (a frame is ~10 times cheaper than
at N = 50): these tests are about the session's plumbing, not the texture force's
accuracy. The real-time ones (UDP, plugin) keep the default N = 50 on purpose: a real-time
session runs frames as fast as it can, and a cheap frame (tens of microseconds in contact,
a few without) would write a trace of tens of megabytes a second.

Tolerances are fixed below, each with its reason; the figures the tests print are for
the reader, never read back to size a bound.
"""
from __future__ import annotations

import importlib.util
import json
import math
import os
import signal
import socket
import struct
import subprocess
import time
from pathlib import Path

import numpy as np

import sessions as S
import trace as T
from sessioncli import (CRASH_MARKERS, RES, SLAB_TOP, assert_one_clean_line, example_plugin, hrt_run,  # noqa: F401
                        objects, still, write_scene)

MM = 1e-3




TIMING_COLUMNS = [c for c, unit, _, _ in T.spec_table(T.TRACE_SECTION) if unit == "us"]


_spec = importlib.util.spec_from_file_location("udp_device", S.REPO / "examples" / "udp_device.py")
U = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(U)


# ----------------------------------------------------------------------------
# Fixtures and helpers
# ----------------------------------------------------------------------------










def line_of(path: Path, needle: str) -> int:
    """1-based line of the first line of `path` starting with `needle`."""
    for i, line in enumerate(path.read_text().splitlines(), start=1):
        if line.startswith(needle):
            return i
    raise AssertionError(f"{needle!r} not in {path}")




def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def non_loopback_ipv4():
    """An IPv4 address of this machine that is not 127.x, or None."""
    cands = []
    for target in ("192.0.2.1", "10.255.255.255", "8.8.8.8"):  # connect() on UDP sends nothing
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.connect((target, 9))
                cands.append(s.getsockname()[0])
        except OSError:
            pass
    try:
        cands += socket.gethostbyname_ex(socket.gethostname())[2]
    except OSError:
        pass
    for a in cands:
        if not a.startswith("127.") and a != "0.0.0.0":
            try:  # really ours: bindable
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                    s.bind((a, 0))
                return a
            except OSError:
                continue
    return None




# ----------------------------------------------------------------------------
# a. The UDP bridge end to end
# ----------------------------------------------------------------------------

# The tip comes down from 0.1 mm clear of the slab (several times the contact margin, 0.1 %
# of the tip's bbox diagonal: 14 um at a 4 mm radius; not higher, since every free frame is
# a trace row) to a target 0.5 mm inside it. Statically the coupling (k_c = 2000 N/m, the device's
# default max_stiffness) and the contact (k = 1000 N/m) share that 0.5 mm in series: the
# tip sits 1/3 mm deep and the device feels k k_c / (k + k_c) * 0.5 mm = 0.33 N upwards.
UDP_Z0, UDP_Z1 = SLAB_TOP + S.TIP_R + 0.1 * MM, SLAB_TOP + S.TIP_R - 0.5 * MM
UDP_RATE = 500.0                      # Hz, the client's pose rate (below hrt's 1 kHz loop)
UDP_DESCENT, UDP_HOLD = 150, 450      # client periods (0.3 s down, 0.9 s held): with hrt's
                                      # start-up, well inside its 3 s even on a loaded machine
# Floors of "a force of plausible size pointing away from the slab" on the replies sent
# once the tip has been held 0.2 s (the soft start is 0.1 s, the coupling settles in a
# few ms): at least 0.05 N (a sixth of the static 0.33 N, room for the contact model's
# details), at most the 10 N limit, and lateral parts below 30 % of the normal one.
UDP_MIN_FORCE, UDP_MAX_LATERAL = 0.05, 0.3


def _bad_packets(seq: int, t: float, last_seq: int):
    """(class, datagram) of every kind of bad packet; the poses in them are far from the
    valid stream's (x = 30 mm, z = 50 mm), so one that got through would show in the trace."""
    far = (0.03, 0.0, 0.05)
    good = U.encode_pose(seq, t, far)
    nan, inf = float("nan"), float("inf")
    rng = np.random.default_rng(seq)
    garbage = bytearray(rng.integers(0, 256, 88, dtype=np.uint8).tobytes())
    garbage[:4] = b"XHRT"
    wrong_version = bytearray(good)
    wrong_version[4:6] = struct.pack("<H", 2)
    inf_time = bytearray(good)
    inf_time[16:24] = struct.pack("<d", inf)
    return [
        ("bad_size", b"HRTU\x01\x00\x01\x00\x07\x00"),                       # 10 bytes: no header
        ("bad_size", good[:87]),                                              # one byte short of a pose
        ("bad_size", good + b"\x00"),                                         # one byte long
        ("bad_size", bytes(23)),                                              # just below a header
        ("bad_magic", bytes(garbage)),
        ("bad_magic", b"HRTV" + good[4:]),
        ("bad_magic", bytes(88)),
        ("bad_version", bytes(wrong_version)),
        ("bad_version", b"HRTU" + struct.pack("<H", 0) + good[6:]),
        ("bad_version", b"HRTU" + struct.pack("<H", 0xFFFF) + good[6:]),
        ("non_finite", U.encode_pose(seq, t, (nan, 0.0, 0.05))),
        ("non_finite", U.encode_pose(seq, t, (0.0, 0.0, 0.05), (0.0, inf, 0.0, 1.0))),
        ("non_finite", bytes(inf_time)),
        ("non_finite", U.encode_pose(seq, t, far, (0.0, 0.0, 0.0, 0.0))),    # zero quaternion (doc: non_finite)
        ("out_of_order", U.encode_pose(last_seq, t, far)),                    # duplicate of the last accepted
        ("out_of_order", U.encode_pose(last_seq - 10, t, far)),               # late
        ("out_of_order", U.encode_pose(last_seq - 2**31 + 1, t, far)),         # far behind (RFC 1982)
    ]


def test_udp_device_end_to_end(session_bakes, hrt, tmp_path):
    port = free_udp_port()
    trace_path = tmp_path / "udp-trace.csv"
    scene = write_scene(tmp_path, "udp", {
        "run": {"duration": 3.0},
        "object": objects(session_bakes, "tip", (0.0, 0.0, UDP_Z0)),
        "device": {"type": "udp", "port": port, "bind": "127.0.0.1"},
        "loop": {"soft_start": 0.1},
        "trace": {"path": trace_path},
    })
    proc = subprocess.Popen([hrt, "run", str(scene), "--realtime", "--duration", "3", "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    addr = ("127.0.0.1", port)
    outside = non_loopback_ipv4()
    sent = {k: 0 for k in ("bad_size", "bad_magic", "bad_version", "non_finite", "out_of_order")}
    sent_z = {}                     # seq -> z of every valid pose sent
    wrenches = []
    seq = 0

    def drain():
        U.drain_wrenches(sock, wrenches)

    def send(z, t):
        nonlocal seq
        sock.sendto(U.encode_pose(seq, t, (0.0, 0.0, z), restart=(seq == 0)), addr)
        sent_z[seq] = z
        seq += 1

    try:
        # Until hrt answers: still poses at the start (nothing counted as bad yet).
        t0 = time.monotonic()
        while not wrenches:
            assert proc.poll() is None, f"hrt exited early: {proc.communicate()[1]}"
            assert time.monotonic() - t0 < 20, "no wrench packet from hrt within 20 s"
            try:
                send(UDP_Z0, time.monotonic() - t0)
            except ConnectionRefusedError:
                pass
            time.sleep(1.0 / UDP_RATE)
            drain()
        first_main = seq
        # Down onto the slab and held, a bad packet every 20 periods, in order of class.
        bad_i = 0
        start = time.monotonic()
        for i in range(UDP_DESCENT + UDP_HOLD):
            t = time.monotonic() - t0
            z = UDP_Z0 + (UDP_Z1 - UDP_Z0) * min(1.0, i / UDP_DESCENT)
            send(z, t)
            if i % 20 == 10:
                bad = _bad_packets(seq, t, seq - 1)
                if bad_i < len(bad):
                    cls, data = bad[bad_i]
                    sock.sendto(data, addr)
                    sent[cls] += 1
                    bad_i += 1
            drain()
            delay = start + (i + 1) / UDP_RATE - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        assert bad_i == len(_bad_packets(0, 0.0, 0)), "not every bad packet was sent"
        # The replies of the session proper: after this, hrt holds the last pose until its
        # duration ends and then ramps out (replies that would fail the checks below).
        drain()
        n_main = len(wrenches)
        # Nothing listens beyond loopback: a wrench-type packet (bad_type, which the
        # loopback stream never sends) and valid poses to this machine's other address.
        outside_replies = []
        if outside is not None:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as o:
                o.bind((outside, 0))
                o.settimeout(0.05)
                wrench = U.HEADER.pack(U.MAGIC, 1, U.TYPE_WRENCH, 0, 0, 0, 0.0) + U.WRENCH_BODY.pack(0, 0, *[0.0] * 6)
                o.sendto(wrench, (outside, port))
                for k in range(3):
                    o.sendto(U.encode_pose(k, 0.0, (0.03, 0.0, 0.05), restart=(k == 0)), (outside, port))
                    time.sleep(0.01)
                try:
                    outside_replies.append(o.recv(65536))
                except (socket.timeout, ConnectionRefusedError):
                    pass
        client_done = time.monotonic() - t0
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        sock.close()

    assert proc.returncode == 0, stderr
    summary = json.loads(stdout)
    udp = summary["udp"]
    print(f"udp counters {udp}; sent bad {sent}; {len(wrenches)} wrenches; outside address {outside}; "
          f"client done {client_done:.2f} s after hrt's start, hrt ran {summary['wall_s']:.2f} s")
    # Counts below assume the whole stream reached a running hrt: say so if it did not.
    assert client_done < summary["wall_s"], "the client outlived hrt's session: counts would be short"
    assert udp["port"] == port
    for cls, n in sent.items():
        assert udp[cls] == n, f"{cls}: hrt counted {udp[cls]}, the test sent {n}"
    assert udp["bad_type"] == 0, "a packet sent to a non-loopback address reached hrt's socket"
    assert udp["received"] == udp["accepted"] + sum(udp[k] for k in (
        "bad_size", "bad_magic", "bad_version", "bad_type", "non_finite", "out_of_order"))
    assert udp["accepted"] >= UDP_DESCENT + UDP_HOLD     # every valid pose of the main phase
    assert udp["sent_wrenches"] >= len(wrenches) >= n_main > 500
    assert not outside_replies, "hrt answered a pose sent to a non-loopback address"

    # Wrenches: zero while the tip hangs where it started; up, once held in the slab.
    before = [w for w in wrenches if w["answers"] < first_main]
    assert before and all(max(map(abs, w["force"])) < 1e-9 for w in before)
    held_from = first_main + UDP_DESCENT + int(0.2 * UDP_RATE)
    held = [w for w in wrenches[:n_main] if w["answers"] >= held_from]
    assert len(held) > 200, f"{len(held)} wrenches while the tip was held in the slab"
    f = np.array([w["force"] for w in held])
    print(f"held in the slab: fz median {np.median(f[:, 2]):.4f} N, min {f[:, 2].min():.4f} N, "
          f"max lateral {np.abs(f[:, :2]).max():.2e} N")
    assert np.all(f[:, 2] > UDP_MIN_FORCE)
    assert np.all(np.linalg.norm(f, axis=1) <= 10.0 + 1e-9)
    assert np.all(np.linalg.norm(f[:, :2], axis=1) < UDP_MAX_LATERAL * f[:, 2])

    # The trace: the device pose is always one of the valid poses (never a bad packet's),
    # and the probe followed it down into the slab.
    tr = T.read_trace(trace_path)
    assert not Path(str(trace_path) + ".partial").exists()
    valid_z = set(sent_z.values())
    assert np.all(tr["device_x"] == 0.0) and np.all(tr["device_y"] == 0.0)
    assert set(tr["device_z"].tolist()) <= valid_z
    # The first frame may come a few client periods into the descent (the device loop
    # answers before the simulation's first frame): within a tenth of it.
    near_top = 0.1 * (UDP_Z0 - UDP_Z1)
    assert tr["device_z"].max() <= UDP_Z0 and tr["device_z"][0] >= UDP_Z0 - near_top
    assert tr["device_z"].min() == UDP_Z1
    assert np.all(np.abs(tr["probe_x"]) < 0.1 * MM) and np.all(np.abs(tr["probe_y"]) < 0.1 * MM)
    assert abs(tr["probe_z"][0] - UDP_Z0) < near_top
    rows = np.flatnonzero(tr["device_z"] == UDP_Z1)
    late = rows[tr["t"][rows] > tr["t"][rows[0]] + 0.2]
    assert len(late) > 10
    # Pressed in: above the target (the contact holds it), below first touch (5 mm).
    contact_z = SLAB_TOP + S.TIP_R
    assert np.all(tr["probe_z"][late] > UDP_Z1) and np.all(tr["probe_z"][late] < contact_z)
    assert np.all(tr["patches"][late] >= 1) and np.all(tr["fz"][late] > UDP_MIN_FORCE)


# ----------------------------------------------------------------------------
# b. The example plugin through a scene
# ----------------------------------------------------------------------------

# The handle's line: +-10 mm along x, period 0.5 s, the tip's centre 0.2 mm lower than
# touching, so that it slides 0.2 mm deep in the slab (a contact in every frame keeps the
# frames at N = 50's cost, see the top).
PLUGIN_R, PLUGIN_T, PLUGIN_Z = 0.01, 0.5, SLAB_TOP + S.TIP_R - 0.2 * MM


def test_plugin_device_through_a_scene(session_bakes, hrt, tmp_path):
    plugin = example_plugin(hrt)
    trace_path = tmp_path / "plugin-trace.csv"
    scene = write_scene(tmp_path, "plugin", {
        "object": objects(session_bakes, "tip", (0.0, 0.0, PLUGIN_Z)),
        "device": {"type": "plugin", "plugin": plugin,
                   "config": f"path=line radius={PLUGIN_R} period={PLUGIN_T} z={PLUGIN_Z} name=itest-line"},
        "loop": {"soft_start": 0.05},
        "trace": {"path": trace_path},
    })
    res = hrt_run(hrt, scene, "--realtime", "--duration", "1", "--json")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["device"]["type"] == "plugin"
    assert summary["device"]["name"] == "itest-line"     # the plugin's own name (from its config)
    tr = T.read_trace(trace_path)
    assert len(tr) > 50
    # The plugin's path (example_device.c): x = r sin(2 pi t / T), y = 0, z, identity
    # orientation, at the session time the loop read it (device_t). 1e-12 m: the same
    # formula in double; t is written as shortest round-trip text, so only libm's sin
    # (the same libm) and the order of the operations could differ, by an ulp.
    want_x = PLUGIN_R * np.sin(2 * math.pi * tr["device_t"] / PLUGIN_T)
    assert np.max(np.abs(tr["device_x"] - want_x)) < 1e-12
    assert np.all(tr["device_y"] == 0.0) and np.all(tr["device_z"] == PLUGIN_Z)
    assert np.all(tr.pose("device")[:, 3:] == [0.0, 0.0, 0.0, 1.0])
    assert tr["device_t"].max() > 0.9 * PLUGIN_T        # at least most of a stroke
    assert np.ptp(tr["device_x"]) > 1.5 * PLUGIN_R
    # The probe follows the handle over the frictionless slab: it spans most of the stroke
    # and stays within 2 mm of it (a 1500 N/m coupling, the plugin's max_stiffness, on a
    # tip of at most a few grams lags by far less at 2 Hz); pressed in, it touches the
    # slab all along.
    print(f"{len(tr)} frames; probe lag max {np.max(np.abs(tr['probe_x'] - tr['target_x'])) * 1e3:.3f} mm")
    assert np.ptp(tr["probe_x"]) > 1.5 * PLUGIN_R
    assert np.max(np.abs(tr["probe_x"] - tr["target_x"])) < 2 * MM
    assert np.mean(tr["patches"] >= 1) > 0.9


# ----------------------------------------------------------------------------
# c. Lockstep reproducibility and replay of a trace
# ----------------------------------------------------------------------------


TIP_UP, TIP_DOWN = SLAB_TOP + S.TIP_R + 0.2 * MM, SLAB_TOP + S.TIP_R - 0.4 * MM  # tip centre heights


def _slide(session_bakes, folder: Path, trace_path: Path, trajectory: Path, prefix: str = "") -> Path:
    device = {"trajectory": trajectory}
    if prefix:
        device["trajectory_prefix"] = prefix
    return write_scene(folder, trace_path.stem, {
        "run": {"duration": 0.3, "lockstep": True},
        "object": objects(session_bakes, "tip", (0.0, 0.0, TIP_UP)),
        "force": {"resolution": RES},
        "device": device,
        "loop": {"soft_start": 0.05},
        "trace": {"path": trace_path},
    })


def _fields(path: Path):
    lines = path.read_text().splitlines()
    return lines[0].split(","), [line.split(",") for line in lines[1:]]


def test_lockstep_is_reproducible_and_a_trace_replays(session_bakes, hrt, tmp_path):
    # From 0.2 mm above the slab to 0.4 mm into it in 0.1 s, then 10 mm along x.
    traj = S.write_trajectory(tmp_path / "slide.csv", [0.0, 0.1, 0.3],
                              [(0, 0, TIP_UP), (0, 0, TIP_DOWN), (10 * MM, 0, TIP_DOWN)], [(0, 0, 0, 1)] * 3)
    one, two, replay = tmp_path / "one.csv", tmp_path / "two.csv", tmp_path / "replay.csv"
    for path in (one, two):
        res = hrt_run(hrt, _slide(session_bakes, tmp_path, path, traj), "--quiet")
        assert res.returncode == 0, res.stderr
    # Byte for byte, except the six per-stage wall-clock timings (docs/trace-format.md:
    # "wall-clock time of ..., never used as physics"), which no two runs share.
    head1, rows1 = _fields(one)
    head2, rows2 = _fields(two)
    assert head1 == head2 and len(rows1) == len(rows2) == 301
    keep = [i for i, c in enumerate(head1) if c not in TIMING_COLUMNS]
    assert len(keep) == len(head1) - 6
    for r, (a, b) in enumerate(zip(rows1, rows2)):
        assert [a[i] for i in keep] == [b[i] for i in keep], f"row {r + 2} differs"
    tr = T.read_trace(one)
    assert np.sum(tr["patches"] >= 1) > 150 and np.ptp(tr["probe_x"]) > 5 * MM  # a real slide
    assert np.max(np.abs(tr["fz"])) > 0.05

    # Replay: the first trace's device poses are the trajectory (its t column the time).
    res = hrt_run(hrt, _slide(session_bakes, tmp_path, replay, one, prefix="device_"), "--quiet")
    assert res.returncode == 0, res.stderr
    rp = T.read_trace(replay)
    assert len(rp) == len(tr)
    # Bit-exact: the trace writes each double as its shortest round-trip text, the
    # replay samples the trajectory exactly at its knots (t = i * period, the same
    # doubles), where the interpolation returns the knot's own pose, and the lockstep
    # chain from those poses on is deterministic. Anything else is a lost bit somewhere
    # (a rounded write, an interpolation that does not hit its knots).
    for c in ("t", "device_t", *[f"device_{k}" for k in ("x", "y", "z", "qx", "qy", "qz", "qw")]):
        assert np.array_equal(rp[c], tr[c]), c
    for prefix in ("probe", "target"):
        assert np.array_equal(rp.pose(prefix), tr.pose(prefix)), prefix
    for prefix in ("", "contact", "coupling", "command"):
        assert np.array_equal(rp.wrench(prefix), tr.wrench(prefix)), prefix or "device wrench"


# ----------------------------------------------------------------------------
# d. Ctrl-C
# ----------------------------------------------------------------------------


def test_ctrl_c_ramps_to_zero_and_writes_the_trace(session_bakes, hrt, tmp_path):
    # The block pressed into the slab by a still device 0.2 mm in: the coupling (2000 N/m)
    # and the contact (1000 N/m) in series hold it 0.133 mm deep, a steady 0.133 N.
    z = SLAB_TOP + S.BLOCK[2] / 2
    trace_path, log_path = tmp_path / "int-trace.csv", tmp_path / "int-device.csv"
    scene = write_scene(tmp_path, "interrupt", {
        "run": {"duration": 30.0},
        "object": objects(session_bakes, "block", (0.0, 0.0, z - 0.1 * MM)),
        "force": {"resolution": RES},
        "device": {"trajectory": still(tmp_path / "still.csv", (0.0, 0.0, z - 0.2 * MM))},
        "loop": {"soft_start": 0.1, "watchdog_ramp": 0.01},
        "trace": {"path": trace_path, "device_log": log_path},
    })
    proc = subprocess.Popen([hrt, "run", str(scene), "--realtime", "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    # The trace's .partial appears just before hrt installs its signal handlers and
    # starts the session; 1 s later the force has long settled (soft start 0.1 s).
    t0 = time.monotonic()
    while not Path(str(trace_path) + ".partial").exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < 30, "hrt did not start its session within 30 s"
        time.sleep(0.01)
    time.sleep(1.0)
    assert proc.poll() is None, proc.communicate()
    t_sig = time.monotonic()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=30)
    print(f"stopped {time.monotonic() - t_sig:.3f} s after SIGINT")
    assert proc.returncode == 130
    line = assert_one_clean_line(stderr)
    assert "interrupted" in line
    assert json.loads(stdout)["interrupted"] is True
    for p in (trace_path, log_path):
        assert p.is_file() and not Path(str(p) + ".partial").exists()
    tr = T.read_trace(trace_path)
    assert len(tr) > 100 and 0.2 < tr["t"][-1] < 30.0
    # Real time writes at most [trace] rate = 1 kHz of rows (the frames run faster): frames
    # increase, rows are at least 1 ms of session time apart, no torn row.
    assert np.all(np.diff(tr["frame"]) >= 1) and tr["frame"][0] == 1
    assert np.all(np.diff(tr["t"]) >= 1e-3 * (1 - 1e-9))

    # The ramp happens after the last simulation frame, so the trace cannot show it; the
    # device log (every tick, ramp ticks included) does: the held force, then
    # watchdog_ramp / period = 10 ticks, each 1/10 lower, the last one zero. The stop
    # ramp is counted in periods, so its factors are exact; the command under it is the
    # last frame's, of a state settled for over a second (its transients decayed by
    # e^-100s), so the force it scales differs from the held one by rounding only:
    # 1e-6 relative.
    log = T.read_device_log(log_path)
    f = np.linalg.norm(np.column_stack([log["fx"], log["fy"], log["fz"]]), axis=1)
    print(f"device log: {len(log)} ticks, last 12 |F| {np.round(f[-12:], 6)}")
    assert f[-1] == 0.0 and np.all(log.wrench()[-1] == 0.0)
    held = f[-11]
    assert held > 0.1, "no force held at the interrupt: the ramp would be invisible"
    want = held * (1.0 - np.arange(11) / 10.0)
    assert np.allclose(f[-11:], want, rtol=1e-6, atol=1e-12), f"ramp {f[-11:]} want {want}"
    assert np.all(np.abs(f[-30:-11] - held) <= 1e-6 * held)   # held steady up to the ramp
    assert log["t"][-1] >= tr["t"][-1]


# ----------------------------------------------------------------------------
# e. Errors
# ----------------------------------------------------------------------------


def _base(session_bakes, tmp_path, **device):
    z = SLAB_TOP + S.TIP_R + 1 * MM
    dev = device or {"trajectory": still(tmp_path / "still.csv", (0.0, 0.0, z))}
    return {
        "run": {"duration": 0.05},
        "object": objects(session_bakes, "tip", (0.0, 0.0, z)),
        "force": {"resolution": RES},
        "device": dev,
        "trace": {"path": tmp_path / "out" / "trace.csv"},
    }


def _assert_failed(res, code, *needles):
    assert res.returncode == code, f"exit {res.returncode}, want {code}: {res.stderr}"
    line = assert_one_clean_line(res.stderr)
    for n in needles:
        assert str(n) in line, f"{n!r} not in {line!r}"
    assert res.stdout == ""
    return line


def _assert_no_output(tables):
    p = Path(tables["trace"]["path"])
    assert not p.exists() and not Path(str(p) + ".partial").exists()
    if p.parent.is_dir():
        assert list(p.parent.iterdir()) == []


def test_scene_errors_exit_4_with_one_line_naming_file_key_and_line(session_bakes, hrt, tmp_path):
    (tmp_path / "out").mkdir()
    # Unknown key (a typo).
    t = _base(session_bakes, tmp_path)
    t["force"]["stifness"] = 1000.0
    scene = write_scene(tmp_path, "typo", t)
    _assert_failed(hrt_run(hrt, scene), 4, scene, "force.stifness", "unknown key", '"stiffness"',
                   f"(line {line_of(scene, 'stifness')})")
    _assert_no_output(t)
    # Missing bundle.
    t = _base(session_bakes, tmp_path)
    t["object"][1]["bundle"] = tmp_path / "nowhere.hbundle"
    scene = write_scene(tmp_path, "nobundle", t)
    _assert_failed(hrt_run(hrt, scene), 4, scene, "object[1].bundle", "nowhere.hbundle",
                   f"(line {line_of(scene, 'bundle = ' + json.dumps(str(tmp_path / 'nowhere.hbundle')))})")
    _assert_no_output(t)
    # A quaternion of norm 2 (w, x, y, z or no rotation).
    t = _base(session_bakes, tmp_path)
    t["object"][0]["orientation"] = [0.0, 0.0, 0.0, 2.0]
    scene = write_scene(tmp_path, "quat", t)
    _assert_failed(hrt_run(hrt, scene), 4, scene, "object[0].orientation", "norm 2",
                   f"(line {line_of(scene, 'orientation = [0.0, 0.0, 0.0, 2.0]')})")
    _assert_no_output(t)
    # A trajectory whose time does not increase (line 4 repeats line 3's time): the
    # message names the trajectory file and its line.
    traj = tmp_path / "back.csv"
    traj.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0.006,0,0,0,1\n0.5,0,0,0.006,0,0,0,1\n0.5,0,0,0.006,0,0,0,1\n")
    t = _base(session_bakes, tmp_path, trajectory=traj)
    scene = write_scene(tmp_path, "back", t)
    _assert_failed(hrt_run(hrt, scene), 4, traj, "line 4", "not after")
    _assert_no_output(t)
    # The trace's folder does not exist: checked when the scene is read (scene-format.md).
    t = _base(session_bakes, tmp_path)
    t["trace"]["path"] = tmp_path / "missing" / "trace.csv"
    scene = write_scene(tmp_path, "nofolder", t)
    _assert_failed(hrt_run(hrt, scene), 4, scene, "trace.path", "does not exist")
    assert not (tmp_path / "missing").exists()


def test_device_and_output_errors(session_bakes, hrt, tmp_path):
    (tmp_path / "out").mkdir()
    # A UDP port in use (hrt sets no SO_REUSEADDR): exit 5 naming the address and port.
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        t = _base(session_bakes, tmp_path, type="udp", port=port)
        scene = write_scene(tmp_path, "busy", t)
        _assert_failed(hrt_run(hrt, scene, "--realtime"), 5, f"127.0.0.1:{port}")
        _assert_no_output(t)
        # --lockstep needs a scripted device: a usage error (2), before anything is opened.
        _assert_failed(hrt_run(hrt, scene, "--lockstep"), 2, "--lockstep", "scripted")
        _assert_no_output(t)
    # A --duration that is not a positive number: a usage error (2), nothing run.
    t = _base(session_bakes, tmp_path)
    scene = write_scene(tmp_path, "duration", t)
    for bad in ("-3", "0", "soon"):
        _assert_failed(hrt_run(hrt, scene, "--duration", bad), 2, "--duration")
        _assert_no_output(t)
    # A trace that cannot be written although its folder exists (/proc takes no new
    # files, even for root, for whom permission bits would not stop anything): exit 6.
    t = _base(session_bakes, tmp_path)
    t["trace"]["path"] = Path("/proc") / f"hrt-itest-{os.getpid()}.csv"
    scene = write_scene(tmp_path, "unwritable", t)
    _assert_failed(hrt_run(hrt, scene), 6, t["trace"]["path"])
    assert not Path(str(t["trace"]["path"]) + ".partial").exists()


# ----------------------------------------------------------------------------
# f. The 3-DoF torque policy
# ----------------------------------------------------------------------------


def _tilted_press(session_bakes, hrt, tmp_path, dof):
    # The block turned 0.05 rad about y, its low edge 0.3 mm into the slab, held there by a
    # still device: the contact at one edge, 6 mm from the centre of mass, has a torque
    # about it (~6 mm x 0.3 N ~ 2e-3 N m) that the coupling's angular spring answers.
    a = 0.05
    q = S.quat([0, 1, 0], a)
    z = SLAB_TOP + (S.BLOCK[0] / 2) * math.sin(a) + (S.BLOCK[2] / 2) * math.cos(a) - 0.3 * MM
    trace_path = tmp_path / f"dof{dof}.csv"
    scene = write_scene(tmp_path, f"dof{dof}", {
        "run": {"duration": 0.25, "lockstep": True},
        "object": objects(session_bakes, "block", (0.0, 0.0, z), q),
        "force": {"resolution": RES},
        "device": {"trajectory": still(tmp_path / "tilted.csv", (0.0, 0.0, z), q), "dof_actuated": dof},
        "loop": {"soft_start": 0.05},
        "trace": {"path": trace_path},
    })
    res = hrt_run(hrt, scene, "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["device"]["dof_actuated"] == dof
    return T.read_trace(trace_path)


# A torque "there" is at least 1e-5 N m (the estimate above is 2e-3 N m; the written
# torque ramps in over the soft start, so its maximum over the run is the full one).
TORQUE_FLOOR = 1e-5


def test_three_dof_device_gets_the_force_only(session_bakes, hrt, tmp_path):
    six, three = _tilted_press(session_bakes, hrt, tmp_path, 6), _tilted_press(session_bakes, hrt, tmp_path, 3)
    t6, t3 = six.wrench()[:, 3:], three.wrench()[:, 3:]
    print(f"max |torque| written: 6-DoF {np.abs(t6).max():.3e} N m, 3-DoF {np.abs(t3).max():.3e} N m; "
          f"max |contact torque| {np.abs(three.wrench('contact')[:, 3:]).max():.3e} N m")
    # The scene has a torque to display (contact, command), in both runs.
    assert np.abs(three.wrench("contact")[:, 3:]).max() > TORQUE_FLOOR
    assert np.abs(three.wrench("command")[:, 3:]).max() > TORQUE_FLOOR
    assert np.abs(t6).max() > TORQUE_FLOOR
    # 3-DoF: not one bit of torque is written, while the force is.
    assert np.all(t3 == 0.0)
    assert np.linalg.norm(three.wrench()[:, :3], axis=1).max() > 0.05
    # The policy drops the torque only: the simulation and the written force are those
    # of the 6-DoF run (the device's output does not feed back into a lockstep session).
    assert np.array_equal(three.wrench()[:, :3], six.wrench()[:, :3])
    assert np.array_equal(three.wrench("command"), six.wrench("command"))


# ----------------------------------------------------------------------------
# g. Soft start
# ----------------------------------------------------------------------------

SOFT = 0.2   # s, [loop] soft_start
# Allowance over the linear ramp s(t) F_final: the ramp starts at the first command
# (one or two periods after t = 0: the first frame runs after the first tick), worth
# F_final x 2 ms / 0.2 s = 1 %; and W0 of the frames themselves, which starts within a
# few % of its final value (the block starts at the coupling/contact equilibrium, up to
# the model's details) and settles in milliseconds: 3 % of F_final.
SOFT_ALLOW = 0.04


def test_soft_start_ramps_the_force_in_linearly(session_bakes, hrt, tmp_path):
    # Target 0.3 mm into the slab; the block starts at the series equilibrium of the
    # coupling (2000 N/m) and the contact (1000 N/m): 0.2 mm in, F = 0.2 N from t = 0.
    z = SLAB_TOP + S.BLOCK[2] / 2
    trace_path = tmp_path / "soft.csv"
    scene = write_scene(tmp_path, "soft", {
        "run": {"duration": 0.4, "lockstep": True},
        "object": objects(session_bakes, "block", (0.0, 0.0, z - 0.2 * MM)),
        "force": {"resolution": RES},
        "device": {"trajectory": still(tmp_path / "press.csv", (0.0, 0.0, z - 0.3 * MM))},
        "loop": {"soft_start": SOFT},
        "trace": {"path": trace_path},
    })
    res = hrt_run(hrt, scene, "--quiet")
    assert res.returncode == 0, res.stderr
    tr = T.read_trace(trace_path)
    t = tr["t"]
    f = np.linalg.norm(tr.wrench()[:, :3], axis=1)
    final = float(np.median(f[t >= SOFT + 0.05]))
    print(f"final |F| {final:.5f} N; |F| at 0.05, 0.1, 0.15 s: "
          f"{[round(float(f[np.searchsorted(t, x)]) / final, 4) for x in (0.05, 0.1, 0.15)]} of it")
    assert final > 0.1
    assert np.all(tr["patches"] >= 1)
    ramp = np.clip(t / SOFT, 0.0, 1.0)
    assert np.all(f <= ramp * final + SOFT_ALLOW * final), "the force got ahead of the ramp"
    assert np.all(f >= ramp * final - SOFT_ALLOW * final), "the force lagged the ramp"
    assert f[0] == 0.0
    # In full after the ramp: within 1 % of the final value (W0 has settled).
    after = t >= SOFT + 0.01
    assert np.all(np.abs(f[after] - final) <= 0.01 * final)


# ----------------------------------------------------------------------------
# The GL backend in a session
# ----------------------------------------------------------------------------


def test_gl_backend_session_equals_cpu(session_bakes, hrt, tmp_path):
    # The slide above with --backend gl (the compute reduction): the GL backend computes
    # every delta of the CPU's to the last bit (tests/integration/test_gl_backend.py,
    # runtime/tests/test_gl_depth.cpp), so the lockstep trace, which feeds each frame's
    # forces into the next frame's poses, must equal the CPU's except the timings.
    traj = S.write_trajectory(tmp_path / "slide.csv", [0.0, 0.1, 0.3],
                              [(0, 0, TIP_UP), (0, 0, TIP_DOWN), (10 * MM, 0, TIP_DOWN)], [(0, 0, 0, 1)] * 3)
    cpu, gl = tmp_path / "cpu.csv", tmp_path / "gl.csv"
    res = hrt_run(hrt, _slide(session_bakes, tmp_path, cpu, traj), "--quiet", "--backend", "cpu")
    assert res.returncode == 0, res.stderr
    res = hrt_run(hrt, _slide(session_bakes, tmp_path, gl, traj), "--backend", "gl", "--json", timeout=600)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["backend"]["name"] == "gl", summary["backend"]
    head1, rows1 = _fields(cpu)
    head2, rows2 = _fields(gl)
    assert head1 == head2 and len(rows1) == len(rows2) == 301
    keep = [i for i, c in enumerate(head1) if c not in TIMING_COLUMNS]
    for r, (a, b) in enumerate(zip(rows1, rows2)):
        assert [a[i] for i in keep] == [b[i] for i in keep], f"row {r + 2} differs"
    tr = T.read_trace(gl)
    assert np.sum(tr["patches"] >= 1) > 150 and np.max(np.abs(tr["fz"])) > 0.05  # in contact most of the slide
