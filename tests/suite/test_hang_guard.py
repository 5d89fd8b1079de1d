"""The suite's guard against a hung test (pyproject.toml's pytest-timeout settings and
tests/conftest.py's longer limit for the slow sweeps): a test past its limit fails with the
stack of every thread and the next test still runs; a slow test gets the longer limit.

Checked on an inner pytest run of throwaway tests, with the limit lowered to 3 s."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]


def test_the_default_suite_has_a_limit(request):
    assert float(request.config.getini("timeout")) > 0
    assert request.config.getini("timeout_method") == "signal"


def test_a_hung_test_fails_with_the_stacks_and_the_suite_goes_on(tmp_path):
    (tmp_path / "pytest.ini").write_text(
        "[pytest]\ntimeout = 3\ntimeout_method = signal\nmarkers =\n    slow: slow\n")
    # The repository's collection hook, loaded under another name (both files are "conftest").
    (tmp_path / "conftest.py").write_text(textwrap.dedent(f"""
        import importlib.util, sys
        sys.path.insert(0, {str(TESTS)!r})
        spec = importlib.util.spec_from_file_location("repo_conftest", {str(TESTS / "conftest.py")!r})
        repo = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(repo)
        pytest_collection_modifyitems = repo.pytest_collection_modifyitems
        """))
    (tmp_path / "test_inner.py").write_text(textwrap.dedent("""
        import threading, time
        import pytest

        def test_a_join_that_never_returns():
            t = threading.Thread(target=lambda: time.sleep(600), name="stuck-worker", daemon=True)
            t.start()
            t.join()

        def test_the_next_one():
            pass

        @pytest.mark.slow
        def test_a_slow_sweep_longer_than_the_default_limit():
            time.sleep(5)
        """))
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-rf", str(tmp_path)],
                       cwd=tmp_path, capture_output=True, text=True, timeout=120)
    out = r.stdout + r.stderr
    assert r.returncode == 1, out
    assert "1 failed, 2 passed" in out, out
    assert "FAILED test_inner.py::test_a_join_that_never_returns" in out, out
    assert "Failed: Timeout (>3.0s) from pytest-timeout" in out, out
    assert "Stack of stuck-worker" in out, out
