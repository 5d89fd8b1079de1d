"""Fixtures shared by the test modules (pytest loads this file before them)."""
from __future__ import annotations

from pathlib import Path

import pytest

import fullsurface as FS
import hrt_locate
import sessions as S


@pytest.fixture(scope="session")
def hrt() -> str:
    """The hrt binary ($HRT, .venv/bin/hrt or PATH). Missing, a test fails under CI and is
    skipped elsewhere."""
    return hrt_locate.hrt_binary("this test runs hrt")


@pytest.fixture(scope="session")
def models(tmp_path_factory):
    """The full-surface scenes' bundles (tests/fullsurface.py: gratings, the bumpy sphere on a
    textured plate, the shared models when present), baked once per session. A module that
    needs other models defines its own `models`."""
    return FS.session_models(tmp_path_factory)


@pytest.fixture(scope="session")
def session_bakes(tmp_path_factory) -> dict:
    """The session tests' bodies (tests/sessions.py): the 4 mm tip, the block and the slab,
    baked once per session."""
    root = Path(tmp_path_factory.getbasetemp() / "sessions")
    return {n: S.bake(n, root) for n in ("tip", "block", "slab")}


#: Per-test limit of the sweeps behind the slow marker (pyproject.toml's `timeout`, 15
#: minutes, is for the default suite; one slow test bakes a shared model for minutes).
SLOW_TIMEOUT_S = 3600


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.get_closest_marker("slow") and not item.get_closest_marker("timeout"):
            item.add_marker(pytest.mark.timeout(SLOW_TIMEOUT_S))
