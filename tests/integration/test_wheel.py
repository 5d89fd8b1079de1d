"""`pip install .`: the wheel scikit-build-core builds from this checkout holds hbake (with
its schema), the Python module hrt (extension, type stubs, py.typed) and the hrt command,
and both runtime parts work from the unpacked wheel: the same numbers as the development
build's `hrt query --json`.

The wheel is built with the venv's scikit-build-core and nanobind (no build isolation:
nothing is downloaded) in a temporary build directory; ccache (installed by make setup)
makes its compilation of the library a cache hit after the development build."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from hrt_locate import REPO, hrt_binary

GOLDEN = REPO / "tests" / "golden"
POSE = ["--pose-a", "0", "0", "0.0168", "0", "0", "0", "1", "--pose-b", "0", "0", "0", "0", "0", "0", "1"]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    build = tmp_path_factory.mktemp("wheel-build")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(out),
                        "-C", f"build-dir={build}", str(REPO)], capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-4000:]
    wheels = list(out.glob("hbake-*.whl"))
    assert len(wheels) == 1, list(out.iterdir())
    return wheels[0]


def test_wheel_contents(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    for want in ("hbake/__init__.py", "hbake/cli/main.py", "hbake/schema/manifest.schema.json", "hrt/__init__.py",
                 "hrt/_hrt.pyi", "hrt/py.typed"):
        assert want in names, want
    assert any(n.startswith("hrt/_hrt.") and n.endswith(".so") for n in names)
    assert any(n.endswith(".data/scripts/hrt") for n in names)
    # Only the Python parts: no C++ headers, static library or CMake package.
    assert not any(n.endswith((".h", ".a", ".cmake", ".pc")) for n in names)
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "hbake = hbake.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()


def test_wheel_runtime_works(wheel, tmp_path):
    """The unpacked wheel's module and command against the development build's hrt."""
    root = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(root)
    want = json.loads(subprocess.run([hrt_binary(), "query", str(GOLDEN / "pebble.hbundle"),
                                      str(GOLDEN / "bumpy_blob.hbundle"), *POSE, "--json"],
                                     capture_output=True, text=True, check=True).stdout)
    script = next(root.glob("*.data/scripts/hrt"))
    script.chmod(0o755)
    got = json.loads(subprocess.run([str(script), "query", str(GOLDEN / "pebble.hbundle"),
                                     str(GOLDEN / "bumpy_blob.hbundle"), *POSE, "--json"],
                                    capture_output=True, text=True, check=True).stdout)
    assert got["force"] == want["force"] and got["torque"] == want["torque"]
    code = ("import json, sys, numpy as np, hrt\n"
            "assert hrt.__file__.startswith(sys.argv[1]), hrt.__file__\n"
            "s = hrt.Scene([hrt.load_bundle(sys.argv[2]), hrt.load_bundle(sys.argv[3])])\n"
            "r = s.query(np.array([[0, 0, 0.0168, 0, 0, 0, 1], [0, 0, 0, 0, 0, 0, 1.0]]))\n"
            "print(json.dumps({'force': r['force'].tolist(), 'torque': r['torque'].tolist()}))\n")
    env = dict(os.environ, PYTHONPATH=str(root), PYTHONNOUSERSITE="1")
    # -S: no site-packages (the venv's .pth points at the development build); numpy
    # comes back through PYTHONPATH's second entry.
    import numpy
    env["PYTHONPATH"] = os.pathsep.join([str(root), str(Path(numpy.__file__).parents[1])])
    r = subprocess.run([sys.executable, "-S", "-c", code, str(root), str(GOLDEN / "pebble.hbundle"),
                        str(GOLDEN / "bumpy_blob.hbundle")], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == {"force": want["force"], "torque": want["torque"]}
