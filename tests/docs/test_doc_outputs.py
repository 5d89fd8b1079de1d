"""The README and docs/ against the code: quoted outputs, scene keys, the format version.

* Every fenced block that quotes a command's output is re-run by tools/check_doc_outputs.py
  (marked ``<!-- check-output: fast|slow -->``); all of them are re-run here, the slow ones
  (bakes of shared models, sessions) too.
* Every scene key the docs name (``[table] key``, the tables of docs/scene-format.md, the
  TOML examples) is one that runtime/src/scene_file/run_config.cpp reads, and no doc names a
  key with a unit glued on (``display_rate_hz`` for ``display_rate``).
* The README names no bundle format version of its own (it points at the spec, which another
  change may bump), outside the quoted outputs the script re-runs.
"""
from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))
import check_doc_outputs as cdo  # noqa: E402

DOCS = [REPO / "README.md", *sorted(p for p in (REPO / "docs").rglob("*.md") if p.name != "bundle-format.md")]


def known_scene_keys() -> dict[str, set[str]]:
    src = (REPO / "runtime/src/scene_file/run_config.cpp").read_text()
    body = src[src.index("known_keys()"):]
    body = body[:body.index("return k;")]
    keys = {}
    for table, items in re.findall(r'\{"(\w+)",\s*\{([^}]*)\}\}', body, re.S):
        keys[table] = set(re.findall(r'"(\w+)"', items))
    assert {"run", "object", "force", "device", "loop", "trace"} <= set(keys), keys
    return keys


def test_every_quoted_output_is_rerun():
    unmarked = [f"{b.path}:{b.line}" for p in DOCS for b in cdo.parse(p, str(p.relative_to(REPO)))
                if b.quotes_output and b.tier is None]
    assert not unmarked, f"quoted outputs that tools/check_doc_outputs.py does not re-run: {unmarked}"


def test_the_wildcards():
    assert cdo.matches(["a ... b", "...", "end"], ["a 1.5 s b", "x", "y", "end"])
    assert cdo.matches(["...", "end"], ["end"])
    assert not cdo.matches(["a ... b"], ["a 1 c"])
    assert not cdo.matches(["one"], ["one", "two"])
    assert cdo.matches([], [])


def test_quoted_outputs_match_a_real_run(capsys):
    """Every quoted output, the slow ones too (the bakes of the shared hammer by both routes
    and the worked session: about 2 minutes on 2 cores), so that a drift fails `make test`.
    Without ../shared/models the bakes fail their commands; outside CI that is a skip."""
    import os
    models = Path(os.environ.get("HBAKE_MODELS") or REPO.parent / "shared" / "models")
    if not (models / "hammer_scan.obj").is_file():
        msg = f"the quoted bakes need the shared models ({models} has no hammer_scan.obj)"
        if os.environ.get("CI"):
            pytest.fail(msg)
        rc = cdo.main(["--fast"])
        out = capsys.readouterr().out
        assert rc == 0, out
        pytest.skip(msg + "; the fast outputs matched")
    rc = cdo.main([])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert re.search(r"([1-9]\d*) command\(s\) re-run, 0 problem", out), out


def test_docs_name_only_real_scene_keys():
    known = known_scene_keys()
    every = set().union(*known.values())
    units = {"hz", "s", "ms", "us", "n", "nm", "m", "mm", "deg", "rad", "bytes", "kg"}
    problems = []
    for p in DOCS:
        text = p.read_text(encoding="utf-8")
        rel = p.relative_to(REPO)
        for table, key in re.findall(r"`\[\[?(\w+)\]\]?\s+(\w+)", text):
            if table in known and key not in known[table]:
                problems.append(f"{rel}: [{table}] {key}")
        for tok in set(re.findall(r"`(\w+)`", text)):
            head, _, tail = tok.rpartition("_")
            if tok not in every and head in every and tail.lower() in units:
                problems.append(f"{rel}: `{tok}` (the key is `{head}`)")
        for block in re.findall(r"```toml\n(.*?)```", text, re.S):
            try:
                doc = tomllib.loads(block)
            except tomllib.TOMLDecodeError:
                continue            # an abridged sketch, not a file
            for table, value in doc.items():
                if table not in known:
                    continue
                for entry in value if isinstance(value, list) else [value]:
                    for key in entry:
                        if key not in known[table]:
                            problems.append(f"{rel}: toml example [{table}] {key}")
    # docs/scene-format.md lists each table's keys exactly.
    sf = (REPO / "docs/scene-format.md").read_text(encoding="utf-8")
    for m in re.finditer(r"^## `\[\[?(\w+)\]\]?`.*?(?=^## )", sf, re.M | re.S):
        listed = set(re.findall(r"^\| `(\w+)` \|", m.group(0), re.M))
        if listed != known[m.group(1)]:
            problems.append(f"docs/scene-format.md [{m.group(1)}]: lists {sorted(listed ^ known[m.group(1)])} "
                            f"wrongly (missing or unknown)")
    assert not problems, "\n".join(problems)


def test_readme_names_no_format_version_of_its_own():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    # Quoted outputs are re-run by the script: they may show what a command prints.
    text = re.sub(r"<!-- check-output: \w+ -->\n```.*?\n```", "", text, flags=re.S)
    stale = re.findall(r"[Ff]ormat(?: version)?[^.\n]{0,12}\b1\.[1-9]\b|\b1\.[1-9] bundles?\b", text)
    assert not stale, f"the README names bundle format versions ({stale}): point at docs/bundle-format.md"
