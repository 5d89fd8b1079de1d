"""The runtime guide's figure (docs/guides/runtime.md): the runtime's depth error against the full meshes.

Bakes the scenes of tests/integration/test_fullsurface_depth.py (angled gratings pressed together at
six offsets, a bumpy sphere on a textured plate, three ../shared/models -- rocker arm,
fandisk, Stanford bunny -- on a textured plate and a plain box), runs `hrt query --json` at
N = 50 and 128 and prints, per group and over all scenes, the patches compared, the
kept fraction and the median and worst |delta_hrt - delta_full| in atlas texels (the
larger texel of the pair), with the worst bound; the last line is the runtime guide's figure
(median and worst over all scenes, with the command).

    HRT=build/tests8/hrt .venv/bin/python examples/depth_error_report.py [--patches] [--json FILE]

FULLSURFACE_CACHE=DIR keeps the bakes across runs; FULLSURFACE_HBAKE_SRC=DIR bakes with
another hbake checkout (see tests/fullsurface.py). `.venv/bin/python -m pytest -s
tests/integration/test_fullsurface_depth.py` prints the same figure (test_readme_figure).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

import fullsurface as FS  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--patches", action="store_true", help="print every patch")
    ap.add_argument("--json", type=Path, help="write the summaries as JSON")
    ap.add_argument("--hrt", default=os.environ.get("HRT") or str(REPO / ".venv" / "bin" / "hrt"))
    args = ap.parse_args()
    if not Path(args.hrt).is_file():
        print(f"error: no hrt at {args.hrt} (make runtime, or --hrt / HRT=PATH)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    root = Path(os.environ.get("FULLSURFACE_CACHE") or tempfile.mkdtemp(prefix="fullsurface-"))
    groups = ["gratings", "sphere"]
    if FS.shared_present():
        groups.append("models")
    else:
        print(f"note: {FS.SHARED_MODELS} lacks {FS.SHARED}: no shared-model scenes "
              "(the figure is then not the README's)", file=sys.stderr)
    models = FS.load_models(root)
    print("bakes: " + ", ".join(f"{n} {m.bake_s:.1f} s (texel {m.texel * 1e6:.1f} um)" for n, m in models.items()))
    all_runs, out = [], []
    for g in groups:
        runs = FS.group_runs(args.hrt, models, g, verbose=False)
        all_runs += runs
        if args.patches:
            for r in runs:
                for p in r.patches:
                    print("  " + p.line())
        for N in FS.RESOLUTIONS:
            s = FS.summarize(f"{g} N={N}", [r for r in runs if r.N == N])
            out.append(s)
            print(FS.format_summary(s))
    for N in FS.RESOLUTIONS:
        s = FS.summarize(f"all scenes N={N}", [r for r in all_runs if r.N == N])
        out.append(s)
        print(FS.format_summary(s))
    s = FS.summarize("all scenes", all_runs)
    out.append(s)
    print(FS.format_summary(s))
    print(f"({time.perf_counter() - t0:.0f} s, hrt {args.hrt})")
    print("README: " + FS.readme_figure(all_runs))
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
