"""Headless Chromium for the page tests (tests/hbake/viz/test_report.py, tests/integration/test_viewer.py), through
selenium with the Debian chromium-driver's path given, so nothing is downloaded."""
from __future__ import annotations

import os
import shutil

import pytest

CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


def chromium(webgl: bool = False, console: bool = False):
    """A headless browser 1200 x 900. webgl: WebGL on the CPU (SwiftShader), for a
    three.js canvas; console: keep the browser's console messages (driver.get_log)."""
    if not (os.path.exists(CHROMEDRIVER) and os.path.exists(CHROMIUM)):
        if os.environ.get("CI"):
            pytest.fail("chromium and chromium-driver are not installed (make setup installs them)")
        pytest.skip("chromium / chromium-driver not installed")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    args = ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1200,900"]
    args += ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"] if webgl else ["--disable-gpu"]
    for a in args:
        opts.add_argument(a)
    if console:
        opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
