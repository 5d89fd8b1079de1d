"""The example scenes for the UDP and plugin devices (examples/session/udp.toml,
plugin.toml) touch within a second as written: the same models as the worked session
(examples/session/run.sh bakes them), the scene files read from the repository with only
the output folder, the port and the build folder rewritten, and the device driven as a
user would (examples/udp_device.py's default circle; the example plugin)."""
from __future__ import annotations

import importlib.util
import json
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import sessions as S
import trace as T

REPO = S.REPO
TOUCH_WITHIN = 1.0   # s of session time from the first pose to the first patch

_spec = importlib.util.spec_from_file_location("udp_device", REPO / "examples" / "udp_device.py")
U = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(U)


@pytest.fixture(scope="module")
def session_models(tmp_path_factory):
    out = tmp_path_factory.mktemp("session")
    py = sys.executable
    subprocess.run([py, str(REPO / "examples" / "session" / "make_models.py"), str(out)], check=True,
                   capture_output=True)
    for name in ("ball", "grating"):
        subprocess.run([str(REPO / ".venv" / "bin" / "hbake"), "bake", str(out / f"{name}.ply"), "-o",
                        str(out / f"{name}.hbundle"), "-f", "-q", "--set", 'load.units="m"'], check=True)
    return out


def _scene(name: str, models: Path, tmp: Path, **subs) -> Path:
    text = (REPO / "examples" / "session" / f"{name}.toml").read_text()
    text = text.replace("../../out/session/", str(models) + "/")
    text = re.sub(r'path = "[^"]*-trace.csv"', f'path = "{tmp / (name + "-trace.csv")}"', text)
    for key, value in subs.items():
        text = re.sub(rf"^{key} = .*$", f"{key} = {value}", text, flags=re.M)
    p = tmp / f"{name}.toml"
    p.write_text(text)
    return p


def _first_touch(trace: Path) -> float:
    tr = T.read_trace(trace)
    hit = np.nonzero(tr["patches"] > 0)[0]
    assert len(hit), "no contact in the whole run"
    assert np.abs(tr.wrench("contact")[hit, 2]).max() > 0.05   # a real press, not a graze
    return float(tr["t"][hit[0]] - tr["t"][0])


def test_plugin_scene_touches_within_a_second(session_models, tmp_path):
    hrt = S.hrt_binary()
    plugin = Path(hrt).resolve().parent / "hrt_example_device.so"
    scene = _scene("plugin", session_models, tmp_path, plugin=json.dumps(str(plugin)))
    res = subprocess.run([hrt, "run", str(scene), "--duration", "1.5", "--json"], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    t = _first_touch(tmp_path / "plugin-trace.csv")
    print(f"plugin scene: first patch {t:.3f} s after the first frame")
    assert t <= TOUCH_WITHIN


def test_udp_scene_touches_within_a_second(session_models, tmp_path):
    hrt = S.hrt_binary()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    scene = _scene("udp", session_models, tmp_path, port=str(port))
    proc = subprocess.Popen([hrt, "run", str(scene), "--duration", "4", "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        while not (tmp_path / "udp-trace.csv.partial").exists():   # bound and running
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() - t0 < 60
            time.sleep(0.01)
        # The client as a user starts it: the default circle (20 mm, z = 0), 1.5 s.
        wrenches = U.run_client("127.0.0.1", port, U.path_poses(duration=1.5))
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert json.loads(out)["udp"]["accepted"] > 500
    assert any(np.linalg.norm(w["force"]) > 0.05 for w in wrenches)
    tr = T.read_trace(tmp_path / "udp-trace.csv")
    first_pose = tr["t"][0]   # the first frame runs on the first pose received
    t = _first_touch(tmp_path / "udp-trace.csv")
    print(f"udp scene: first patch {t:.3f} s after the first pose (frame at t = {first_pose:.3f} s)")
    assert t <= TOUCH_WITHIN
