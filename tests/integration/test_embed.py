"""The runtime as a library: `cmake --install` of the existing build, then an application
(examples/embed) built against the installed prefix with find_package(hrt) and with
pkg-config, whose results must equal `hrt query --json` on the same inputs, bit for bit.

The prefix is moved after installing (the package must be relocatable) and the
application sees no project source tree: only the prefix and system headers."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from hrt_locate import REPO, hrt_binary

BUILD = REPO / "build" / "runtime"
GOLDEN = REPO / "tests" / "golden"
PEBBLE, BLOB = GOLDEN / "pebble.hbundle", GOLDEN / "bumpy_blob.hbundle"
# A at rest 0.2 mm into the blob's top, and turned by 0.4 rad about (0.3, 0.2, 0.93) and
# moved off-centre: both give one covered patch (checked below).
POSES = [
    ["0", "0", "0.0168", "0", "0", "0", "1"],
    ["0.001", "-0.0005", "0.0167", "0.05975336508961", "0.03983557672640", "0.18523543177778", "0.98006657784124"],
]


def needs_build() -> None:
    if not (BUILD / "CMakeCache.txt").is_file():
        if os.environ.get("CI"):
            pytest.fail("build/runtime is not configured (make setup), but CI must run this test")
        pytest.skip("build/runtime is not configured: run `make setup`")


@pytest.fixture(scope="module")
def prefix(tmp_path_factory) -> Path:
    """hrt installed from the existing build, then moved elsewhere."""
    needs_build()
    first = tmp_path_factory.mktemp("install") / "prefix"
    r = subprocess.run(["cmake", "--install", str(BUILD), "--prefix", str(first)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    moved = tmp_path_factory.mktemp("moved") / "hrt"
    shutil.move(str(first), str(moved))
    return moved


def query(pose: list[str]) -> dict:
    r = subprocess.run([hrt_binary(), "query", str(PEBBLE), str(BLOB), "--pose-a", *pose,
                        "--pose-b", "0", "0", "0", "0", "0", "0", "1", "--json"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def run_embed(exe: Path, pose: list[str]) -> dict:
    r = subprocess.run([str(exe), str(PEBBLE), str(BLOB), *pose], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def same_as_query(exe: Path) -> None:
    for pose in POSES:
        got, want = run_embed(exe, pose), query(pose)
        assert len(want["contacts"]) >= 1
        assert got["force"] == want["force"] and got["torque"] == want["torque"]
        assert [c["delta"] for c in got["contacts"]] == [c["delta"] for c in want["contacts"]]
        assert [c["force"] for c in got["contacts"]] == [c["force"] for c in want["contacts"]]
        assert [c["n"] for c in got["contacts"]] == [c["n"] for c in want["contacts"]]


def project_version() -> str:
    text = (REPO / "runtime" / "CMakeLists.txt").read_text()
    return re.search(r"project\(hrt LANGUAGES [A-Z ]+ VERSION ([0-9.]+)\)", text).group(1)


def test_installed_layout(prefix):
    """Headers, library, CMake package and pkg-config file; nothing points into the
    source or build tree; version.h carries the project and bundle format versions."""
    for rel in ("include/hrt/hrt.h", "include/hrt/version.h", "include/hrt/scene.h", "lib/libhrtcore.a",
                "lib/cmake/hrt/hrtConfig.cmake", "lib/cmake/hrt/hrtConfigVersion.cmake",
                "lib/cmake/hrt/hrtTargets.cmake", "lib/pkgconfig/hrt.pc", "bin/hrt",
                "lib/hrt/plugins/hrt_example_device.so"):
        assert (prefix / rel).is_file(), rel
    for f in [*(prefix / "lib" / "cmake" / "hrt").iterdir(), prefix / "lib" / "pkgconfig" / "hrt.pc"]:
        text = f.read_text()
        assert str(REPO) not in text, f"{f.name} refers to the source tree"
        assert "HRT_SOURCE_DIR" not in text and "GTest" not in text and "CLI11" not in text, f.name
    version = (prefix / "include" / "hrt" / "version.h").read_text()
    assert f'#define HRT_VERSION_STRING "{project_version()}"' in version
    from hbake.bundle import FORMAT_VERSION
    major, minor = FORMAT_VERSION.split(".")
    assert f"#define HRT_BUNDLE_FORMAT_MAJOR {major}\n" in version
    assert f"#define HRT_BUNDLE_FORMAT_MINOR {minor}\n" in version


def test_find_package_application(prefix, tmp_path):
    """examples/embed built with find_package(hrt) against the moved prefix."""
    build = tmp_path / "embed"
    r = subprocess.run(["cmake", "-S", str(REPO / "examples" / "embed"), "-B", str(build),
                        f"-DCMAKE_PREFIX_PATH={prefix}"], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run(["cmake", "--build", str(build)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    # The compile lines name the prefix's headers, never the repository's.
    flags = "".join(p.read_text() for p in build.rglob("flags.make"))
    assert str(prefix / "include") in flags and str(REPO) not in flags
    exe = build / "embed"
    same_as_query(exe)
    assert run_embed(exe, POSES[0])["hrt_version"] == project_version()
    # Bad input: one line naming the file, the application's own exit code.
    r = subprocess.run([str(exe), str(tmp_path / "missing.hbundle"), str(BLOB), *POSES[0]], capture_output=True,
                       text=True)
    assert r.returncode == 3 and "missing.hbundle" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_version_mismatch_is_refused(prefix, tmp_path):
    """find_package(hrt 9.0) does not accept this 0.x package."""
    src = tmp_path / "src"
    src.mkdir()
    (src / "CMakeLists.txt").write_text("cmake_minimum_required(VERSION 3.16)\nproject(p CXX)\n"
                                        "find_package(hrt 9.0 REQUIRED)\n")
    r = subprocess.run(["cmake", "-S", str(src), "-B", str(tmp_path / "b"), f"-DCMAKE_PREFIX_PATH={prefix}"],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "hrt" in r.stderr


def test_pkg_config_application(prefix, tmp_path):
    """The same application compiled with `pkg-config --cflags --libs --static hrt`."""
    if not shutil.which("pkg-config"):
        pytest.fail("pkg-config is missing (make setup installs it)")
    env = dict(os.environ, PKG_CONFIG_PATH=str(prefix / "lib" / "pkgconfig"))
    r = subprocess.run(["pkg-config", "--cflags", "--libs", "--static", "hrt"], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    flags = r.stdout.split()
    assert any(f.startswith("-I") and Path(f[2:]).resolve() == (prefix / "include").resolve() for f in flags)
    exe = tmp_path / "embed_pc"
    r = subprocess.run(["g++", "-O2", "-o", str(exe), str(REPO / "examples" / "embed" / "main.cpp"), *flags,
                        "-std=c++17"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
    same_as_query(exe)


@pytest.mark.slow
def test_shared_library_application(tmp_path):
    """A shared libhrtcore (BUILD_SHARED_LIBS=ON, without the command and tests: no CLI11,
    no GTest), installed, then the same application against it. A full build of the
    library (minutes), so behind the slow marker."""
    build, pfx = tmp_path / "shared", tmp_path / "prefix"
    for cmd in (["cmake", "-S", str(REPO / "runtime"), "-B", str(build), "-DBUILD_SHARED_LIBS=ON",
                 "-DBUILD_TESTING=OFF", "-DHRT_BUILD_APPS=OFF"],
                ["cmake", "--build", str(build), "-j", str(os.cpu_count() or 2)],
                ["cmake", "--install", str(build), "--prefix", str(pfx)]):
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert (pfx / "lib" / "libhrtcore.so").exists() and not (pfx / "bin" / "hrt").exists()
    app = tmp_path / "embed"
    for cmd in (["cmake", "-S", str(REPO / "examples" / "embed"), "-B", str(app), f"-DCMAKE_PREFIX_PATH={pfx}"],
                ["cmake", "--build", str(app)]):
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    same_as_query(app / "embed")


@pytest.mark.slow
def test_build_without_gl(tmp_path):
    """-DHRT_WITH_GL=OFF: no libepoxy; `--backend gl` is the one-line GL error (exit 7),
    `--backend auto` keeps to the CPU with the same numbers."""
    build = tmp_path / "nogl"
    for cmd in (["cmake", "-S", str(REPO / "runtime"), "-B", str(build), "-DHRT_WITH_GL=OFF", "-DBUILD_TESTING=OFF"],
                ["cmake", "--build", str(build), "-j", str(os.cpu_count() or 2), "--target", "hrt"]):
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    exe = build / "hrt"
    assert "epoxy" not in subprocess.run(["ldd", str(exe)], capture_output=True, text=True).stdout
    args = [str(PEBBLE), str(BLOB), "--pose-a", *POSES[0], "--pose-b", "0", "0", "0", "0", "0", "0", "1"]
    r = subprocess.run([str(exe), "query", *args, "--backend", "gl"], capture_output=True, text=True)
    assert r.returncode == 7 and "HRT_WITH_GL=OFF" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = subprocess.run([str(exe), "query", *args, "--backend", "auto", "--json"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["force"] == query(POSES[0])["force"]
