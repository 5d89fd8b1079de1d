#!/usr/bin/env python3
"""Re-run the commands whose output README.md and docs/ quote, and fail when it drifted.

A fenced block that quotes a command's output (a ``$ COMMAND`` line followed by output
lines) must be declared by an HTML comment on the line just above its fence:

    <!-- check-output: fast -->     seconds; re-run with --fast too
    <!-- check-output: slow -->     minutes (bakes, sessions); re-run without --fast

The test suite (tests/docs/test_doc_outputs.py, in `make test`) re-runs both.

A quoted output without one of these is an error: quote only what is re-run here. Blocks
that list commands without output need no marker.

Each block's commands run in order with bash, in a scratch copy of the repository root
(its top-level entries linked, so what the commands write stays there), with ``.venv/bin``
first on PATH, ``../shared/models`` linked to the shared models (``$HBAKE_MODELS``, else
``../shared/models`` beside the repository), NO_COLOR=1 and COLUMNS=100. The blocks of one
file share the scratch directory, in order (a later block may use an earlier one's bundle).

Comparison, line by line (trailing blanks ignored) of stdout and stderr together:
``...`` inside a line matches any text (timings, peak memory, paths), and a line that is
only ``...`` matches any number of lines. A command whose quoted output is empty must
print nothing. Exit status: 0 when every checked block matches, 1 when one drifted (the
expected and actual lines are printed), 2 on a usage or markup error.

    .venv/bin/python tools/check_doc_outputs.py            # every block (minutes: bakes)
    .venv/bin/python tools/check_doc_outputs.py --fast     # the fast blocks only (seconds)
    .venv/bin/python tools/check_doc_outputs.py --show README.md   # print what they print now
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
#: The files checked. docs/bundle-format.md quotes no command output.
DEFAULT_FILES = ["README.md", *sorted(str(p.relative_to(REPO)) for p in (REPO / "docs").rglob("*.md"))]
MARKER = re.compile(r"^<!--\s*check-output:\s*(fast|slow)\s*-->\s*$")
FENCE = re.compile(r"^(```|~~~)")
SCRATCH_SKIP = {".git", "out"}


@dataclass
class Command:
    text: str          # the command, continuation lines joined
    line: int          # 1-based line of its "$ "
    expected: list[str] = field(default_factory=list)


@dataclass
class Block:
    path: str
    line: int          # 1-based line of the opening fence
    tier: str | None   # "fast", "slow" or None (no marker)
    commands: list[Command]

    @property
    def quotes_output(self) -> bool:
        return any(c.expected for c in self.commands)


def parse(path: Path, rel: str) -> list[Block]:
    """The fenced blocks of a Markdown file that contain ``$ `` command lines."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, start = m.group(1), i
        marker = MARKER.match(lines[i - 1]) if i > 0 else None
        body = []
        i += 1
        while i < len(lines) and not lines[i].startswith(fence):
            body.append((i + 1, lines[i]))
            i += 1
        i += 1
        cmds: list[Command] = []
        k = 0
        while k < len(body):
            no, text = body[k]
            if text.startswith("$ "):
                cmd = text[2:]
                while cmd.endswith("\\") and k + 1 < len(body):
                    k += 1
                    cmd = cmd + "\n" + body[k][1]
                cmds.append(Command(cmd, no))
            elif cmds:
                cmds[-1].expected.append(text.rstrip())
            k += 1
        if cmds:
            blocks.append(Block(rel, start + 1, marker.group(1) if marker else None, cmds))
    return blocks


def matches(expected: list[str], actual: list[str]) -> bool:
    """``expected`` against ``actual`` with ``...`` wildcards (see the module doc)."""
    def line_re(e: str) -> re.Pattern:
        return re.compile("^" + ".*".join(re.escape(p) for p in e.split("...")) + "$")

    pats = [None if e.strip() == "..." else line_re(e) for e in expected]

    memo: dict[tuple[int, int], bool] = {}

    def go(i: int, j: int) -> bool:
        key = (i, j)
        if key in memo:
            return memo[key]
        if i == len(pats):
            r = j == len(actual)
        elif pats[i] is None:
            r = any(go(i + 1, jj) for jj in range(j, len(actual) + 1))
        else:
            r = j < len(actual) and bool(pats[i].match(actual[j])) and go(i + 1, j + 1)
        memo[key] = r
        return r

    return go(0, 0)


def scratch_root(tmp: Path) -> Path:
    """A scratch repository root: the repository's top-level entries linked, ../shared/models
    linked to the shared models."""
    root = tmp / "repo"
    root.mkdir()
    for entry in REPO.iterdir():
        if entry.name not in SCRATCH_SKIP:
            (root / entry.name).symlink_to(entry)
    models = Path(os.environ.get("HBAKE_MODELS") or REPO.parent / "shared" / "models")
    (tmp / "shared").mkdir()
    if models.exists():
        (tmp / "shared" / "models").symlink_to(models.resolve())
    return root


def run(cmd: str, cwd: Path, timeout: float) -> list[str]:
    env = dict(os.environ, NO_COLOR="1", COLUMNS="100", TERM="dumb")
    env["PATH"] = f"{REPO / '.venv' / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env.pop("HBAKE_DEBUG", None)
    env.pop("HBAKE_MODELS", None)      # the commands use ../shared/models, linked above
    env.pop("FORCE_COLOR", None)
    r = subprocess.run(["bash", "-c", cmd], cwd=cwd, env=env, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True, timeout=timeout)
    return [ln.rstrip() for ln in r.stdout.splitlines()]


def check(files: list[str], tier: str, show: bool, timeout: float, out=None) -> int:
    out = out or sys.stdout
    errors = 0
    checked = 0
    for rel in files:
        path = REPO / rel
        blocks = parse(path, rel)
        for b in blocks:
            if b.quotes_output and b.tier is None:
                print(f"{rel}:{b.line}: a quoted command output without a "
                      f"'<!-- check-output: fast|slow -->' marker", file=out)
                errors += 1
        todo = [b for b in blocks if b.tier is not None and (tier == "slow" or b.tier == "fast")]
        if not todo:
            continue
        with tempfile.TemporaryDirectory(prefix="docout-") as tmp:
            cwd = scratch_root(Path(tmp))
            for b in todo:
                for c in b.commands:
                    actual = run(c.text, cwd, timeout)
                    checked += 1
                    if show:
                        print(f"--- {rel}:{c.line}: $ {c.text}", file=out)
                        print("\n".join(actual), file=out)
                        continue
                    if not matches(c.expected, actual):
                        errors += 1
                        print(f"{rel}:{c.line}: the output of `{c.text}` drifted\n"
                              f"  quoted:\n" + "".join(f"    {e}\n" for e in c.expected) +
                              "  now:\n" + "".join(f"    {a}\n" for a in actual), file=out)
    if not show:
        print(f"check_doc_outputs: {checked} command(s) re-run, {errors} problem(s)", file=out)
    return 1 if errors else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="*", help="Markdown files, relative to the repository root "
                                              "[default: README.md and docs/**/*.md]")
    ap.add_argument("--fast", action="store_true", help="only the blocks marked fast")
    ap.add_argument("--show", action="store_true", help="print the commands' output now, compare nothing")
    ap.add_argument("--timeout", type=float, default=900, help="seconds per command [900]")
    a = ap.parse_args(argv)
    files = a.files or DEFAULT_FILES
    for f in files:
        if not (REPO / f).is_file():
            print(f"check_doc_outputs: {f}: no such file under {REPO}", file=sys.stderr)
            return 2
    return check(files, "fast" if a.fast else "slow", a.show, a.timeout)


if __name__ == "__main__":
    sys.exit(main())
