"""The README's picture of the viewer, from a real run: the knurled hammer on the wrinkled
torus (paper Fig. 6c) replayed by `hbake view` at one frame, in headless Chromium.

    .venv/bin/python examples/viewer_screenshot.py [OUT.png] [--frame N]

Bakes and runs the hammer experiment first when its trace is missing
(examples/experiments/run.sh hammer). Default output: docs/images/viewer.png.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", type=Path, default=REPO / "docs" / "images" / "viewer.png")
    ap.add_argument("--frame", type=int, default=700, help="trace row to show [700: the head on the torus]")
    ap.add_argument("--size", default="1400,900", help="window size W,H in pixels")
    ap.add_argument("--max-triangles", type=int, default=150_000,
                    help="per object (the CPU rasterizer of a headless browser is slow with more)")
    a = ap.parse_args()
    scene = REPO / "examples" / "experiments" / "hammer.toml"
    trace = REPO / "out" / "experiments" / "hammer.trace.csv"
    if not trace.exists():
        subprocess.run(["bash", str(REPO / "examples" / "experiments" / "run.sh"), "hammer"], check=True)

    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    from hbake.viz.viewer import Viewer

    v = Viewer(scene, trace, port=0, max_triangles=a.max_triangles)
    v.show_frame(a.frame)
    # The camera on the contact: the first patch's point on the torus, from above and aside.
    import numpy as np
    from hbake.viz.viewer import MM
    c = v.last["contacts"]
    focus = np.asarray(c["p_b"][0]) * MM if len(c["delta"]) else np.asarray(v.last["probe"][:3]) * MM
    cam = v.server.initial_camera
    cam.look_at = tuple(focus)
    cam.position = tuple(focus + np.array([0.35, -0.55, 0.35]) * v.extent)
    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={a.size}",
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--hide-scrollbars"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(executable_path=shutil.which("chromedriver") or "/usr/bin/chromedriver"),
                              options=opts)
    driver.set_page_load_timeout(300)
    try:
        driver.get(v.url)
        want = f"{v.last['t']:.4f} s"
        t0 = time.time()
        while time.time() - t0 < 120:
            vals = driver.execute_script("return Array.from(document.querySelectorAll('input')).map(e => e.value)")
            if want in vals:
                break
            time.sleep(0.5)
        time.sleep(5)  # the software renderer's first frames
        # The "software WebGL" notice is about this headless browser, not the page.
        driver.execute_script("document.querySelectorAll('.mantine-Notification-root').forEach(e => e.remove())")
        time.sleep(0.5)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(a.out))
    finally:
        driver.quit()
        v.close()
    print(a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
