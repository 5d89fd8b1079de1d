"""The documentation site: docs/ built by MkDocs with --strict (every page in the nav, no
broken link or anchor), and the README kept a front door that links into it."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_the_site_builds_strictly(tmp_path):
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                       cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    for page in ("index.html", "architecture/index.html", "guides/baking/index.html",
                 "guides/sessions/index.html", "reference/hrt-cli/index.html", "bundle-format/index.html"):
        assert (tmp_path / "site" / page).is_file(), page


def test_every_page_is_in_the_nav():
    nav = (REPO / "mkdocs.yml").read_text(encoding="utf-8")
    pages = sorted(str(p.relative_to(REPO / "docs")) for p in (REPO / "docs").rglob("*.md"))
    missing = [p for p in pages if p not in nav]
    assert not missing, f"pages the site's nav does not list: {missing}"


def test_the_readme_is_a_front_door():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < 250, "the README grew past 250 lines: move the detail into docs/"
    assert text.startswith("# "), "the README opens with its title"
    commands = text.split("\n```", 2)[1]
    assert "make demo" in commands and "make test" in commands, "the README opens with make demo and make test"
    for link in re.findall(r"\]\((docs/[^)#]+)", text):
        assert (REPO / link).exists(), f"the README links to {link}, which does not exist"


def test_user_docs_cite_no_issue_numbers():
    hits = []
    for p in [REPO / "README.md", *(REPO / "docs").rglob("*.md")]:
        for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1):
            if re.search(r"\bissue\s*#?\d+", line, re.I):
                hits.append(f"{p.relative_to(REPO)}:{i}")
    assert not hits, f"user docs name issues (history belongs in CHANGELOG.md): {hits}"
