#!/usr/bin/env python3
"""Table 1 of the paper beside ours: make and bake the benchmark
models (examples/experiments/models.py) into OUT and print their complexity.

    .venv/bin/python examples/experiments/table.py OUT [--force] [--markdown FILE]

Columns: full-resolution triangles, coarse triangles and convex pieces, ours and the
paper's; the bake time (`hbake bake`'s total, this machine; noted with `nproc` and the
CPU model, since timings mean nothing without the machine). Bundles already in OUT are
reused (their recorded bake time is printed); --force rebakes.
"""
from __future__ import annotations

import os
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import models as M  # noqa: E402

PAPER_NAMES = {"block": "Block", "gear": "Gear", "hammer": "Hammer", "cad": "CAD Part",
               "file": "File", "torus": "Torus"}


def cpu_model() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def main(argv):
    args = [a for a in argv if not a.startswith("-")]
    if not args:
        sys.exit(__doc__)
    out = Path(args[0])
    out.mkdir(parents=True, exist_ok=True)
    md = None
    if "--markdown" in argv:
        md = Path(argv[argv.index("--markdown") + 1])
        args = [a for a in args if Path(a) != md]
    rows = [M.bake(n, out, "--force" in argv) for n in M.MODELS]
    head = ("model", "full tris (paper)", "coarse tris (paper)", "pieces (paper)", "bake s", "mesh s")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        pf, pc, pp = r["paper"]
        lines.append(f"| {PAPER_NAMES[r['name']]} | {r['full']:,} ({pf:,}) | {r['coarse']:,} ({pc:,}) | "
                     f"{r['pieces']} ({pp}) | {r['bake_s']:.1f} | {r['make_s']:.1f} |")
    machine = f"{cpu_model()}, {os.cpu_count()} cores (bake times of `hbake bake` on it; mesh s: making the full mesh)"
    text = "\n".join(lines) + f"\n\nMachine: {machine}\n"
    print(text)
    if md:
        md.write_text(text)


if __name__ == "__main__":
    main(sys.argv[1:])
