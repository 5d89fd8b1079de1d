"""`hbake report`: the HTML page and its PNGs, checked in headless Chromium
(Debian's chromium + chromium-driver through selenium): the page loads, every image is
decoded (naturalWidth > 0), and every figure on the page equals the manifest's value.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import browser
from batchcli import LOW, blob, one_error_line, run



@pytest.fixture(scope="session")
def baked(tmp_path_factory):
    """(bundle, its source) of one tiny bake with two convex pieces' worth of shape."""
    d = tmp_path_factory.mktemp("report")
    src = blob(d / "blob.ply", 40.0)
    cfg = d / "low.toml"
    cfg.write_text(LOW)
    proc = run(["batch", src, "-o", d / "out", "-c", cfg, "-q"])
    assert proc.returncode == 0, proc.stderr
    return d / "out" / "blob.hbundle", src


@pytest.fixture(scope="session")
def report_dir(baked, tmp_path_factory):
    bundle, src = baked
    out = tmp_path_factory.mktemp("rep") / "blob-report"
    proc = run(["report", bundle, "-o", out, "--source", src, "--samples", "5000", "--json"])
    assert proc.returncode == 0, proc.stderr
    return out, json.loads(proc.stdout)


IMAGES = ["pieces.png", "atlas_positions.png", "atlas_height.png", "error_histogram.png",
          "error_map.png"]


def test_report_writes_page_and_pngs(report_dir, baked):
    out, result = report_dir
    assert result["ok"] and Path(result["page"]) == out / "index.html"
    assert sorted(Path(p).name for p in result["images"]) == sorted(IMAGES)
    for name in IMAGES:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The recomputed error (other samples) is close to the manifest's figure.
    m = json.loads((baked[0] / "manifest.json").read_text())
    want = m["quality"]["reconstruction"]["coarse_to_full"]["mean"]
    assert abs(result["errors"]["mean"] - want) <= 0.25 * want + 1e-7
    # The height map: a height at exactly the covered texels, relief of both signs
    # (the blob's bumps), none larger than the part.
    from hbake.bundle import read_bundle
    from hbake.viz.report import texel_heights

    b = read_bundle(baked[0])
    h = texel_heights(b)
    assert (np.isfinite(h) == (b.atlas[..., 3] == 1.0)).all()
    assert np.nanmin(h) < 0 < np.nanmax(h)
    assert np.nanmax(np.abs(h)) < m["quality"]["bbox_diagonal"]
    assert result["heights"] == {"height_min": float(np.nanmin(h)), "height_max": float(np.nanmax(h))}
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]


def test_report_is_deterministic(report_dir, baked, tmp_path):
    out, _ = report_dir
    again = tmp_path / "again"
    proc = run(["report", baked[0], "-o", again, "--source", baked[1], "--samples", "5000"])
    assert proc.returncode == 0, proc.stderr
    for name in IMAGES + ["index.html"]:
        assert (again / name).read_bytes() == (out / name).read_bytes(), name


def test_report_user_errors(baked, tmp_path, report_dir):
    bundle, src = baked
    proc = run(["report", bundle, "-o", report_dir[0]])
    assert proc.returncode == 5 and "already exists" in one_error_line(proc.stderr)
    other = blob(tmp_path / "other.ply", 10.0)
    proc = run(["report", bundle, "-o", tmp_path / "r", "--source", other])
    assert proc.returncode == 2 and "other.ply" in one_error_line(proc.stderr)
    broken = tmp_path / "broken.hbundle"
    shutil.copytree(bundle, broken)
    (broken / "atlas.exr").unlink()
    proc = run(["report", broken, "-o", tmp_path / "r2"])
    assert proc.returncode == 10 and "atlas.exr" in one_error_line(proc.stderr)
    assert not (tmp_path / "r").exists() and not (tmp_path / "r2").exists()


def _browser():
    return browser.chromium()


def test_report_page_in_headless_chromium(report_dir, baked, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    from hbake.viz.report import flatten_figures

    out, _ = report_dir
    manifest = json.loads((baked[0] / "manifest.json").read_text())
    driver = _browser()
    try:
        driver.get((out / "index.html").resolve().as_uri())
        WebDriverWait(driver, 30).until(
            lambda d: d.execute_script("return document.readyState") == "complete")
        WebDriverWait(driver, 30).until(lambda d: d.execute_script(
            "return Array.from(document.images).every(i => i.complete)"))
        images = driver.execute_script(
            "return Array.from(document.images).map(i => [i.getAttribute('src'), i.naturalWidth, i.naturalHeight])")
        assert sorted(src for src, _, _ in images) == sorted(IMAGES)
        for src, w, h in images:
            assert w > 0 and h > 0, f"{src} did not load"
        assert blob_title(driver) == "blob.hbundle"
        cells = driver.find_elements(By.CSS_SELECTOR, "#figures td[data-key]")
        shown = {c.get_attribute("data-key"): (json.loads(c.get_attribute("data-value")), c.text)
                 for c in cells}
        want = dict(flatten_figures(manifest))
        assert set(shown) == set(want)
        assert "quality.reconstruction.coarse_to_full.p95" in shown
        for key, value in want.items():
            assert shown[key][0] == value, key
            if isinstance(value, float):            # the text shows the same number
                assert float(shown[key][1]) == pytest.approx(value, rel=1e-5, abs=0), key
            elif isinstance(value, int) and not isinstance(value, bool):
                assert int(shown[key][1].replace(",", "")) == value, key
        warnings = [li.text for li in driver.find_elements(By.CSS_SELECTOR, "#warnings li")]
        assert warnings == (manifest["warnings"] or ["none"])
        png = tmp_path / "screenshot.png"
        driver.save_screenshot(str(png))
        assert png.stat().st_size > 10_000
    finally:
        driver.quit()


def blob_title(driver) -> str:
    from selenium.webdriver.common.by import By

    return driver.find_element(By.TAG_NAME, "h1").text
