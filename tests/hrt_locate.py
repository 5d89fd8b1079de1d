"""Where the tests find the `hrt` binary (shared by the tests that run it)."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def hrt_binary(why: str = "") -> str:
    """The hrt binary: $HRT, else .venv/bin/hrt (make runtime), else PATH.

    Missing: the test fails under CI (which builds it) and is skipped elsewhere, with
    `why` added to the message."""
    for cand in (os.environ.get("HRT"), REPO / ".venv" / "bin" / "hrt", shutil.which("hrt")):
        if cand and Path(cand).is_file():
            return str(cand)
    if os.environ.get("CI"):
        pytest.fail("hrt is not built (make runtime), but CI must run this test")
    pytest.skip("hrt is not built: run `make runtime` or set HRT=/path/to/hrt" + (f"; {why}" if why else ""))
