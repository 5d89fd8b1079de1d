"""hbake view (hbake/viz/viewer.py, docs/viewer.md) in headless Chromium, and the virtual device
it drives.

- a bundle's page: the 3-D canvas is not blank (pixel statistics of a screenshot), the
  reconstructed surface is made of the atlas's own positions, the toggles reach the scene;
- a live session of a scene file with the virtual device: a scripted drag (what the gizmo
  does) moves the probe into contact, and the force the page shows is the runtime's
  contact wrench of that frame (hrt.Runner, the same session as `hrt run`), digit for digit
  as displayed; the virtual device's output stays within the device's force limit;
- a replay of a committed small trace (tests/data/viewer, run by `hrt run` from its scene
  file): frame N's patch count and force as the trace has them, and the page carries the
  trace's sound;
- no console errors in any of them.

The virtual device's per-tick bounds (soft start, clamp) are checked with the other device
kinds in tests/integration/test_run_safety.py.
"""
from __future__ import annotations

import io
import re
import time
from pathlib import Path

import numpy as np
import pytest

import browser
import hrt  # built by make setup: a missing module is a failure, not a skip

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data" / "viewer"
GOLDEN = REPO / "tests" / "golden"


def _browser():
    return browser.chromium(webgl=True, console=True)


def _open(driver, url: str, want: str | None = None, timeout: float = 60.0):
    """Loads the page and waits until its panel shows `want` in some input (or any panel)."""
    driver.get(url)
    t0 = time.time()
    while time.time() - t0 < timeout:
        vals = _inputs(driver)
        if vals and (want is None or any(want in v for v in vals)):
            time.sleep(1.0)      # a few more frames for the canvas
            return
        time.sleep(0.25)
    raise AssertionError(f"the page did not show {want!r} within {timeout} s: {_inputs(driver)}")


def _inputs(driver) -> list[str]:
    return driver.execute_script("return Array.from(document.querySelectorAll('input')).map(e => e.value)")


def _field(driver, after: str) -> list[str]:
    """The panel's read-only text fields from the one whose value is `after` on: t, frame,
    patches, force, torque, depth, rate."""
    vals = _inputs(driver)
    i = vals.index(after)
    return vals[i:i + 7]


def _canvas_stats(driver, tmp_path: Path, name: str):
    """(fraction of non-background pixels, their luminance standard deviation) of the 3-D
    view: a screenshot's left part (the panel is on the right)."""
    from PIL import Image

    png = driver.get_screenshot_as_png()
    (tmp_path / f"{name}.png").write_bytes(png)
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float64)
    h, w, _ = img.shape
    view = img[: int(0.9 * h), : int(0.65 * w)]
    lum = view @ np.array([0.299, 0.587, 0.114])
    bg = np.median(lum[:10, :10])
    fg = np.abs(lum - bg) > 8
    return float(np.mean(fg)), float(np.std(lum[fg])) if np.any(fg) else 0.0


def _severe(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def _numbers(text: str) -> np.ndarray:
    return np.array([float(x) for x in re.findall(r"[-+]?\d+\.\d+(?:e[-+]?\d+)?", text)])


# ----------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["bumpy_blob", "pebble"])
def test_the_drawn_surface_is_closed_and_holds_the_full_meshs_volume(name):
    """The displaced coarse mesh the page draws: closed and consistently wound (no crack at
    the charts' seams), its triangle count within the budget, and its volume the full
    mesh's (the manifest's mass.volume, computed by the bake from the full-resolution
    mesh) to within the area times a quarter of an atlas texel: the atlas's lookups lie a
    few hundredths of a texel from the full surface (the bake's quality figures), so a
    mean offset of a quarter texel is far above that and far below a missing or doubled
    chart."""
    import trimesh

    from hbake.bundle import read_bundle
    from hbake.viz.viewer import surface_mesh

    b = read_bundle(GOLDEN / f"{name}.hbundle")
    v, f = surface_mesh(b.coarse_faces, b.coarse_uvs, b.atlas)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    texel = b.manifest["atlas"]["texel_size"]
    full = b.manifest["mass"]["volume"]
    print(f"{name}: {len(f)} triangles, volume {m.volume:.4e} against {full:.4e} m^3 "
          f"(mean offset {abs(m.volume - full) / m.area / texel:.3f} texel)")
    assert abs(m.volume - full) <= 0.25 * texel * m.area
    assert len(f) <= 400_000
    v2, f2 = surface_mesh(b.coarse_faces, b.coarse_uvs, b.atlas, max_triangles=1000)
    assert len(f2) <= 1000 < len(f)
    assert trimesh.Trimesh(v2, f2, process=False).is_watertight


def test_bundle_page_draws_and_toggles(tmp_path):
    from hbake.viz.viewer import Viewer

    v = Viewer(GOLDEN / "bumpy_blob.hbundle", port=0)
    driver = _browser()
    try:
        _open(driver, v.url)
        frac, std = _canvas_stats(driver, tmp_path, "bundle")
        print(f"bundle page: {frac:.1%} of the view drawn, luminance std {std:.1f}")
        assert frac > 0.03 and std > 3.0      # a lit surface, not a flat fill
        assert v.groups["coarse"] and not any(h.visible for h in v.groups["coarse"])
        # Clicking "coarse mesh" in the page shows it in the scene.
        driver.execute_script("""
            const label = Array.from(document.querySelectorAll('label, p, div'))
                .find(e => e.childElementCount === 0 && e.textContent.trim() === 'coarse mesh');
            const row = label.closest('div').parentElement;
            row.querySelector('input[type=checkbox]').click();""")
        t0 = time.time()
        while time.time() - t0 < 10 and not all(h.visible for h in v.groups["coarse"]):
            time.sleep(0.1)
        assert all(h.visible for h in v.groups["coarse"])
        assert _severe(driver) == []
    finally:
        driver.quit()
        v.close()


def test_live_page_drag_into_contact_shows_the_runtime_wrench(tmp_path):
    from hbake.viz.viewer import Viewer

    scene = tmp_path / "live.toml"
    scene.write_text(f"""
[run]
duration = 10.0
lockstep = true
[[object]]
name = "pebble"
bundle = "{GOLDEN / 'pebble.hbundle'}"
position = [0.0, 0.0, 0.0175]
[[object]]
name = "blob"
bundle = "{GOLDEN / 'bumpy_blob.hbundle'}"
[device]
type = "virtual"
max_force = 0.5
[loop]
soft_start = 0.05
""")
    v = Viewer(scene, port=0, realtime=False)
    driver = _browser()
    try:
        assert v.last["patches"] == 0 or np.all(v.last["contacts"]["delta"] <= 0)
        # The drag: the target 1.5 mm lower, turned 7 degrees about a tilted axis.
        a = np.radians(7.0)
        axis = np.array([0.3, 0.8, 0.2]) / np.linalg.norm([0.3, 0.8, 0.2])
        q = np.concatenate([axis * np.sin(a / 2), [np.cos(a / 2)]])
        v.drag_to([0.0003, -0.0002, 0.0160], q)
        L = v.step(250)
        assert L["patches"] >= 1 and np.max(L["contacts"]["delta"]) > 0
        assert np.linalg.norm(L["force"]) > 0.05
        # The device output is the device's limit (0.5 N, the soft start over), not the
        # contact's 0.75 N: the drag goes through the device loop's clamp.
        assert np.linalg.norm(L["force"]) > 0.6
        assert 0.5 * 0.999 < np.linalg.norm(L["device_output"][:3]) <= 0.5
        _open(driver, v.url, want=f"{L['t']:.4f} s")
        t_, frame, patches, force, torque, depth, rate = _field(driver, f"{L['t']:.4f} s")
        assert int(frame) == L["frame"] and int(patches) == L["patches"]
        assert np.array_equal(_numbers(force), np.round(L["force"], 4))
        assert np.array_equal(_numbers(torque), np.round(L["torque"], 4))
        assert np.allclose(_numbers(depth), np.round(np.asarray(L["contacts"]["delta"]) * 1e3, 4))
        frac, std = _canvas_stats(driver, tmp_path, "live")
        print(f"live page at t = {L['t']} s: force {force}, {frac:.1%} drawn, std {std:.1f}")
        assert frac > 0.03 and std > 3.0
        # The same session as the runtime's own: a Runner given the same poses.
        r = hrt.Runner(str(scene), device="virtual")
        fr = r.step()
        r.set_device_pose(r.target_to_device(np.concatenate([[0.0003, -0.0002, 0.0160], q])))
        for _ in range(250):
            fr = r.step()
        assert fr["frame"] == L["frame"] and np.array_equal(fr["contact"][:3], L["force"])
        # The sound of the last seconds, asked for in the page: a WAV of the session's
        # vibration (its samples as hbake/viz/sound.py makes them from the frames shown).
        driver.execute_script("""
            Array.from(document.querySelectorAll('button'))
                .find(b => b.textContent.trim() === 'sound of the last seconds').click();""")
        t0 = time.time()
        src = None
        while time.time() - t0 < 20 and not src:
            src = driver.execute_script("const a = document.getElementById('hbake-audio'); return a ? a.src : null")
            time.sleep(0.2)
        assert src and src.startswith("data:audio/wav;base64,")
        import base64
        import wave
        with wave.open(io.BytesIO(base64.b64decode(src.split(",", 1)[1]))) as w:
            assert w.getframerate() == 44100 and w.getnchannels() == 1
            assert abs(w.getnframes() / 44100 - L["t"]) < 0.01   # the whole 0.25 s so far (< 3 s)
        assert _severe(driver) == []
    finally:
        driver.quit()
        v.close()


def test_replay_page_shows_the_trace_frame_and_its_sound(tmp_path):
    from hbake.viz.plot import Trace
    from hbake.viz.viewer import Viewer

    tr = Trace(DATA / "press.trace.csv")
    v = Viewer(DATA / "press.toml", DATA / "press.trace.csv", port=0)
    driver = _browser()
    try:
        k = 37
        v.show_frame(k)
        t = float(tr["t"][k])
        _open(driver, v.url, want=f"{t:.4f} s")
        t_, frame, patches, force, torque, depth, rate = _field(driver, f"{t:.4f} s")
        assert int(frame) == int(tr["frame"][k]) and int(patches) == int(tr["patches"][k]) >= 1
        want = np.round([tr["contact_fx"][k], tr["contact_fy"][k], tr["contact_fz"][k]], 4)
        assert np.array_equal(_numbers(force), want)
        assert rate == "replay"
        src = driver.execute_script("const a = document.getElementById('hbake-audio'); return a ? a.src : null")
        assert src and src.startswith("data:audio/wav;base64,")
        frac, std = _canvas_stats(driver, tmp_path, "replay")
        assert frac > 0.03 and std > 3.0
        assert _severe(driver) == []
    finally:
        driver.quit()
        v.close()


def test_the_command_serves_until_sigterm_and_refuses_bad_input(tmp_path):
    """`hbake view`: one line and a distinct exit for bad input; the page served (the
    client's index.html, from the installed viser: no network), exit 0 on SIGTERM."""
    import signal
    import subprocess
    import urllib.request

    exe = str(REPO / ".venv" / "bin" / "hbake")
    r = subprocess.run([exe, "view", str(tmp_path / "none.toml")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 3 and r.stderr.count("\n") == 1 and "none.toml" in r.stderr
    r = subprocess.run([exe, "view", str(GOLDEN / "pebble.hbundle"), "--trace", str(DATA / "press.trace.csv")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "pebble.hbundle" in r.stderr
    bad = tmp_path / "bad.toml"
    scene = (DATA / "press.toml").read_text().replace("../../golden", str(GOLDEN))
    bad.write_text(scene.replace("[run]", "[run]\nspeed = 3", 1))
    r = subprocess.run([exe, "view", str(bad)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 4 and r.stderr.count("\n") == 1 and "run.speed" in r.stderr, r.stderr
    # A corrupt bundle (a NaN texel, which the structural read alone lets through): one line.
    r = subprocess.run([exe, "view", str(GOLDEN / "corrupt" / "nan_texel.hbundle")], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 4 and r.stderr.count("\n") == 1 and "non-finite" in r.stderr, r.stderr
    bad.write_text(scene.replace("pebble.hbundle", "nothing.hbundle"))
    r = subprocess.run([exe, "view", str(bad)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 3 and r.stderr.count("\n") == 1 and "nothing.hbundle" in r.stderr, r.stderr
    p = subprocess.Popen([exe, "view", str(DATA / "press.toml"), "--trace", str(DATA / "press.trace.csv"),
                          "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = p.stderr.readline()
        m = re.search(r"replay at (http://127\.0\.0\.1:\d+/)", line)
        assert m, line
        html = urllib.request.urlopen(m.group(1), timeout=30).read()
        assert b"<html" in html.lower() and b"https://" not in html   # the built client, nothing fetched
        p.send_signal(signal.SIGTERM)
        assert p.wait(timeout=30) == 0
    finally:
        if p.poll() is None:
            p.kill()


def test_replay_plays_at_the_speed_asked():
    """Play at 0.1x: the replay's session time advances by a tenth of the wall time, so
    the frame shown is the trace's frame at that time (5 ms frames: 20 rows per second),
    whatever the display rate; the wall time is measured, the bound is two rows either way
    (the display's 33 ms ticks and the rows' 5 ms)."""
    from hbake.viz.plot import Trace
    from hbake.viz.viewer import Viewer

    tr = Trace(DATA / "press.trace.csv")
    v = Viewer(DATA / "press.toml", DATA / "press.trace.csv", port=0)
    try:
        v.show_frame(3)
        v.speed.value = 0.1
        t0 = time.perf_counter()
        v.play_cb.value = True
        time.sleep(1.5)
        row = v.last["row"]
        wall = time.perf_counter() - t0
        v.play_cb.value = False
        want = float(tr["t"][3]) + 0.1 * wall
        k = int(np.searchsorted(tr["t"], want, side="right")) - 1
        print(f"after {wall:.2f} s at 0.1x: row {row}, expected about {k}")
        assert abs(row - k) <= 2 and row > 3 + 20
    finally:
        v.close()
