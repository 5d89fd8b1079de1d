"""`--json` of bake, validate and inspect (batch: tests/hbake/batch/test_batch.py):
one JSON document on stdout, the documented exit code, and on a user error the one line
on stderr plus {"ok": false, "error": {class, exit_code, message}} on stdout.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from batchcli import blob, one_error_line, run

GOLDEN = Path(__file__).resolve().parents[2] / "golden"
LOW_SETS = ["--target-faces", "60", "--atlas-size", "32", "--samples", "1000"]


def test_bake_json(tmp_path):
    src = blob(tmp_path / "b.ply")
    proc = run(["bake", src, "-o", tmp_path / "b.hbundle", "--json", *LOW_SETS])
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)                        # nothing else on stdout
    assert out["ok"] is True and out["output"] == str(tmp_path / "b.hbundle")
    manifest = json.loads((tmp_path / "b.hbundle" / "manifest.json").read_text())
    assert out["manifest"] == manifest
    assert set(out["timings"]) >= {"load", "simplify", "bake", "write"} and out["peak_rss_bytes"] > 0
    # The same, a second time without --force: exit 5 in JSON too.
    proc = run(["bake", src, "-o", tmp_path / "b.hbundle", "--json", *LOW_SETS])
    assert proc.returncode == 5
    err = json.loads(proc.stdout)
    assert err == {"ok": False, "error": {"class": "output-exists", "exit_code": 5,
                                          "message": err["error"]["message"]}}
    assert err["error"]["message"] in one_error_line(proc.stderr)


@pytest.mark.parametrize("case, code, cls", [("missing", 3, "input-missing"),
                                             ("bad_config", 8, "config")])
def test_bake_json_errors(tmp_path, case, code, cls):
    src = tmp_path / "none.ply"
    extra = []
    if case == "bad_config":
        src = blob(tmp_path / "b.ply")
        extra = ["--set", "simplify.nope=1"]
    proc = run(["bake", src, "-o", tmp_path / "x.hbundle", "--json", *extra])
    assert proc.returncode == code
    err = json.loads(proc.stdout)["error"]
    assert (err["class"], err["exit_code"]) == (cls, code)
    assert err["message"] in one_error_line(proc.stderr)
    assert not (tmp_path / "x.hbundle").exists()


def test_validate_json():
    proc = run(["validate", GOLDEN / "pebble.hbundle", "--json"])
    assert proc.returncode == 0
    assert json.loads(proc.stdout) == {"path": str(GOLDEN / "pebble.hbundle"), "valid": True,
                                       "exit_code": 0, "problems": [],
                                       "surface": {"quads": 241, "cut_quads": 0, "widest_cut": 0.0}}
    index = json.loads((GOLDEN / "corrupt" / "index.json").read_text())
    for case in index["variants"][:6]:
        bundle = GOLDEN / "corrupt" / case["bundle"]
        proc = run(["validate", bundle, "--json"])
        out = json.loads(proc.stdout)
        assert proc.returncode == case["exit_code"] == out["exit_code"], case
        assert out["valid"] is False and out["problems"][0]["class"] == case["class"]
        assert out["surface"] is None
        # The same problems as the text output, line for line.
        text = run(["validate", bundle]).stdout.splitlines()
        assert text == [f"{bundle}: {p['class']}: {p['message']}" for p in out["problems"]]


def test_inspect_json():
    proc = run(["inspect", GOLDEN / "ridged_box.hbundle", "--json"])
    assert proc.returncode == 0
    out = json.loads(proc.stdout)
    assert out["valid"] is True and out["manifest"]["format"] == "hbundle"
    proc = run(["inspect", GOLDEN / "nonexistent.hbundle", "--json"])
    assert proc.returncode == 10 and json.loads(proc.stdout)["problems"][0]["class"] == "io"
