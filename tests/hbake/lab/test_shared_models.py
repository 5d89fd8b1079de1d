"""The shared models' folder is one setting (``HBAKE_MODELS``, or ``--models-dir`` /
``MODELS=``), and every tool that needs it says so loudly when it is missing, instead of
doing nothing and exiting 0: ``hbake bench``, ``make -C examples``, the experiments'
``models.py``."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
HBAKE = REPO / ".venv" / "bin" / "hbake"


def _env(**extra):
    env = dict(os.environ)
    env.update(extra)
    return env


def test_bench_fails_loudly_without_the_shared_models(tmp_path):
    missing = tmp_path / "no-models"
    for args, env in ((["--models-dir", str(missing)], _env()), ([], _env(HBAKE_MODELS=str(missing)))):
        r = subprocess.run([sys.executable, "-m", "hbake.cli", "bench", "--out-dir", str(tmp_path / "o"), *args],
                           capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
        assert r.returncode != 0, r.stdout
        assert "Traceback" not in r.stderr
        assert str(missing) in r.stderr and "HBAKE_MODELS" in r.stderr, r.stderr
        assert not (tmp_path / "o" / "cad_part.ply").exists()  # stopped before any work


def test_bench_names_the_models_a_folder_lacks(tmp_path):
    partial = tmp_path / "some"
    partial.mkdir()
    (partial / "armadillo.obj").write_text("v 0 0 0\n")
    r = subprocess.run([sys.executable, "-m", "hbake.cli", "bench", "--models-dir", str(partial),
                        "--out-dir", str(tmp_path / "o")], capture_output=True, text=True, timeout=120,
                       cwd=tmp_path)
    assert r.returncode != 0
    assert "lacks" in r.stderr and "fandisk.obj" in r.stderr and "armadillo.obj," not in r.stderr, r.stderr


@pytest.mark.skipif(shutil.which("make") is None and not os.environ.get("CI"), reason="no make here")
def test_examples_makefile_fails_without_models(tmp_path):
    for var in ("MODELS", "HBAKE_MODELS"):
        r = subprocess.run(["make", "-C", str(REPO / "examples"), f"{var}={tmp_path / 'none'}",
                            f"OUT={tmp_path / 'out'}"], capture_output=True, text=True, timeout=60)
        assert r.returncode != 0
        assert "is not a folder" in r.stderr and "HBAKE_MODELS" in r.stderr, r.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    r = subprocess.run(["make", "-C", str(REPO / "examples"), f"MODELS={empty}", f"OUT={tmp_path / 'out'}"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "holds no mesh" in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


def test_experiment_models_name_the_setting(tmp_path):
    r = subprocess.run([sys.executable, str(REPO / "examples" / "experiments" / "models.py"), str(tmp_path / "o"),
                        "cad"], capture_output=True, text=True, timeout=60,
                       env=_env(HBAKE_MODELS=str(tmp_path / "none"), HBAKE=str(HBAKE)))
    assert r.returncode != 0
    assert "HBAKE_MODELS" in r.stderr and str(tmp_path / "none") in r.stderr, r.stderr
