#!/usr/bin/env python3
"""Fail when a runtime function is longer than 150 lines (the project's rule).

"No runtime function over 150 lines except DeviceLoop::tick with its numbered stages."
Length is lizard's: the lines from a function's signature to its closing brace. Every C
and C++ file under runtime/src, runtime/apps, runtime/python and runtime/include is read
(lizard's C/C++ reader); a longer function is split along the seams its comments name
(numbered steps, sections) into static or anonymous-namespace helpers.

    .venv/bin/python tools/check_function_length.py     # in `make lint`

Exit status: 0 when no function but the allowed one is over the limit, 1 when some are
(each listed as path:line name length), 2 when a folder is missing.
"""

from __future__ import annotations

import sys
from pathlib import Path

import lizard

MAX_LINES = 150
FOLDERS = ("runtime/src", "runtime/apps", "runtime/python", "runtime/include")
# The device loop's tick reads as its numbered stages in one place (one period of the
# loop, in order); the only function allowed over the limit. Do not add to this list.
ALLOWED = frozenset({"hrt::DeviceLoop::tick"})


def main() -> int:
    root = Path(__file__).resolve().parent.parent
    folders = [root / f for f in FOLDERS]
    missing = [str(f) for f in folders if not f.is_dir()]
    if missing:
        print(f"check_function_length: no folder {', '.join(missing)}", file=sys.stderr)
        return 2
    long = []
    for info in lizard.analyze([str(f) for f in folders], lans=["cpp"]):
        for fn in info.function_list:
            if fn.length > MAX_LINES and fn.name not in ALLOWED:
                path = Path(info.filename).resolve().relative_to(root)
                long.append(f"{path}:{fn.start_line} {fn.name} {fn.length} lines")
    if long:
        print(f"check_function_length: {len(long)} function(s) over {MAX_LINES} lines "
              "(split them along their stages):", file=sys.stderr)
        for line in sorted(long):
            print(f"  {line}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
