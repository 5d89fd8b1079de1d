"""Fail when a module of hbake grows past 700 lines (docs/guides/testing.md, "Lint").

A module that long holds more than one concern: split it by concern inside its package
(hbake/bundle is the example) rather than raising the limit. Run by `make lint`.
"""
from __future__ import annotations

import sys
from pathlib import Path

LIMIT = 700
ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    long = [(n, p) for p in sorted((ROOT / "hbake").rglob("*.py"))
            if (n := len(p.read_text("utf-8").splitlines())) > LIMIT]
    for n, p in long:
        print(f"{p.relative_to(ROOT)}: {n} lines, over the limit of {LIMIT}: split it by concern")
    return 1 if long else 0


if __name__ == "__main__":
    sys.exit(main())
