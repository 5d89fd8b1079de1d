"""Helpers of the tests that drive `hrt run` on the session bakes (tests/sessions.py): scene
files, the run itself, and the one-clean-line check of an error exit."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

import sessions as S


SLAB_TOP = S.SLAB[2] / 2           # 3 mm: the slab is centred on its origin


RES = 16                           # [force] resolution of every scene here


# Text on stderr that only a crash or an uncaught exception prints.
CRASH_MARKERS = ("Traceback", "terminate called", "what():", "Aborted", "core dumped", "Segmentation",
                 "internal error", "#0 ", "stack")


def objects(session_bakes, probe, position, orientation=(0.0, 0.0, 0.0, 1.0)):
    return [{"name": probe, "bundle": session_bakes[probe].bundle, "position": list(position),
             "orientation": list(orientation)},
            {"name": "slab", "bundle": session_bakes["slab"].bundle}]


def write_scene(folder: Path, name: str, tables: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    path.write_text(S.scene_toml(tables))
    return path


def hrt_run(hrt, scene, *args, timeout=120):
    return subprocess.run([hrt, "run", str(scene), *args], capture_output=True, text=True, timeout=timeout)


def assert_one_clean_line(stderr: str) -> str:
    lines = stderr.strip("\n").splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{stderr}"
    for m in CRASH_MARKERS:
        assert m not in stderr, f"crash text {m!r} on stderr: {stderr}"
    return lines[0]


def still(path: Path, position, quaternion=(0.0, 0.0, 0.0, 1.0)) -> Path:
    return S.write_trajectory(path, [0.0, 1.0], [position, position], [quaternion, quaternion])


def example_plugin(hrt) -> Path:
    """The example plugin the build makes (runtime/CMakeLists.txt: MODULE hrt_example_device,
    no prefix, in the build folder beside hrt): $HRT_PLUGIN, else next to $HRT."""
    cands = [os.environ.get("HRT_PLUGIN"), Path(hrt).resolve().parent / "hrt_example_device.so"]
    for c in cands:
        if c and Path(c).is_file():
            return Path(c)
    if os.environ.get("CI"):
        pytest.fail(f"the example plugin is not built (looked at {cands})")
    pytest.skip(f"the example plugin is not built (looked at {cands}); set HRT_PLUGIN")
