"""Speed of the CPU backend per contact patch, on three scenes, for one or two binaries.

    .venv/bin/python examples/bench_speed.py [--hrt NEW] [--hrt-old OLD] [options]

Scenes (all through ``hrt bench``, whose JSON this reads):

- ``scraping``: the rasp over the CAD part, examples/bench_runtime.sh's path (2-4
  patches per frame);
- ``copies K``: the same scene with K copies of the part spread along the path (more
  patches, every one a real contact);
- ``steep``: the procedural grating (``hbake generate grating``: ridges at 23 degrees,
  slope up to 0.63), baked at default settings, turned face down about its ridge
  direction and pressed on itself by 0.05 mm, then slid 2 mm across its ridges. The
  coarse mesh follows its relief only in part, so the surface heights' fixed point
  iterates where atlas points lie beside their column.

For each scene and resolution N it prints:

- wall medians (median over the rounds of each run's per-frame median): texture force
  per patch, collision per piece pair, clustering, the frame, and the frame's split;
- the thread scaling: the texture force per frame on one thread and on every thread;
- with ``--hrt-old``, old/new ratios of the texture force per frame on one and every thread;
- instructions per patch (callgrind, one thread; the stable figure on a shared machine):
  the frame's and the texture force's (inclusive cost of ``hrt::compute_depth_gradient``)
  over the sweep's patches. Valgrind runs the code path it can emulate, so report the
  wall times too.

The binaries and thread counts alternate inside each round (a shared machine's speed
drifts), so ``--hrt-old`` (for example a build of an earlier commit) gives
old/new ratios measured side by side.

The bundles come from out/bench: rasp and cad_part are baked by
examples/bench_runtime.sh (run first); the grating is generated and baked here when it
is missing (about 20 s).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# The scraping scene of examples/bench_runtime.sh.
SCRAPING = ["--pose-a", "0.1295", "0.0345", "0.0184", "0", "0", "0", "1", "--pose-b", "0", "0", "0", "0", "0", "0", "1",
            "--settle", "-1", "1", "-1", "--settle-depth", "5e-5", "--path", "0.02", "0", "0"]
# The grating (60 x 60 mm block, top at 20 +- 0.5 mm, ridges along (-sin 23, cos 23, 0))
# turned 180 degrees about its ridge direction, its footprint over B's, 1 mm above it;
# settled straight down; slid 2 mm across the ridges, along (cos 23, sin 23, 0).
STEEP = ["--pose-a", "0.0724199451", "0.0307404429", "0.042", "-0.3907311285", "0.9205048535", "0", "0",
         "--pose-b", "0", "0", "0", "0", "0", "0", "1",
         "--settle", "0", "0", "-1", "--settle-depth", "5e-5", "--path", "0.0018410", "0.00078146", "0"]


def fail(msg: str) -> None:
    print(f"bench_speed.py: {msg}", file=sys.stderr)
    sys.exit(2)


def default_hrt() -> str:
    for p in (ROOT / ".venv/bin/hrt", ROOT / "build/runtime/hrt"):
        if p.exists():
            return str(p)
    fail("no hrt binary (run 'make setup' first)")
    return ""


def ensure_bundles(out: Path, hbake: str) -> dict[str, Path]:
    rasp, part, grating = out / "rasp.hbundle", out / "cad_part.hbundle", out / "grating.hbundle"
    if not (rasp.is_dir() and part.is_dir()):
        fail(f"no rasp/cad_part bundles in {out} (run: bash examples/bench_runtime.sh {out})")
    if not grating.is_dir():
        print(f"baking {grating} (hbake generate grating, default settings) ...", flush=True)
        ply = out / "grating.ply"
        subprocess.run([hbake, "generate", "grating", str(ply)], check=True)
        subprocess.run([hbake, "bake", str(ply), "-o", str(grating), "--units", "m"], check=True,
                       stdout=subprocess.DEVNULL)
    return {"rasp": rasp, "part": part, "grating": grating}


def bench(hrt: str, a: Path, b: Path, scene: list[str], *, resolutions: str, copies: str, frames: int, passes: int,
          threads: int, prefix: list[str] | None = None) -> dict:
    cmd = [*(prefix or []), hrt, "bench", "--a", str(a), "--b", str(b), *scene, "--frames", str(frames),
           "--passes", str(passes), "--resolutions", resolutions, "--copies", copies, "--threads", str(threads),
           "--json"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr.strip()[-500:]}")
    return json.loads(r.stdout)


def results(j: dict, scene: str) -> dict[tuple[str, int], dict]:
    """(scene label, N) -> hrt bench's summary of that sweep."""
    out = {}
    for r in j["path_results"]:
        out[(scene, int(r["resolution"]))] = r
    if scene == "scraping":
        for c in j["copies"]:
            if int(c["copies"]) == 1:
                continue
            for n, r in c["results"].items():
                out[(f"copies {c['copies']}", int(n))] = r
    return out


def med(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else float("nan")


def callgrind(hrt: str, bundles: dict, resolutions: list[int], copies: list[int], frames: int) -> dict:
    """(scene, N) -> (frame Ir per patch, texture-force Ir per patch, patches): one
    valgrind run per scene and N, collecting only inside the sweep timed for that scene
    (hrt bench's path_sweep, or copies_sweep for the copies scenes), so that loading and
    settling are not counted."""
    out = {}
    runs = [("scraping", bundles["rasp"], bundles["part"], SCRAPING, 1, "path_sweep")]
    runs += [(f"copies {k}", bundles["rasp"], bundles["part"], SCRAPING, k, "copies_sweep") for k in copies]
    runs += [("steep", bundles["grating"], bundles["grating"], STEEP, 1, "path_sweep")]
    for scene, a, b, args, k, fn in runs:
        for n in resolutions:
            with tempfile.TemporaryDirectory() as tmp:
                dump = os.path.join(tmp, "callgrind.out")
                j = bench(hrt, a, b, args, resolutions=str(n), copies=str(k), frames=frames, passes=1, threads=1,
                          prefix=["valgrind", "--tool=callgrind", f"--callgrind-out-file={dump}",
                                  "--collect-atstart=no", f"--toggle-collect=*{fn}*"])
                if fn == "path_sweep":
                    r = next(x for x in j["path_results"] if int(x["resolution"]) == n)
                else:
                    r = next(c for c in j["copies"] if int(c["copies"]) == k)["results"][str(n)]
                total, force = annotate(dump)
            patches = r["patches"]["total"]
            out[(scene, n)] = (total / patches if patches else float("nan"),
                               force / patches if patches else float("nan"), patches)
            print(f"  callgrind {scene} N={n} done", flush=True)
    return out


def annotate(dump: str) -> tuple[int, int]:
    """Total Ir of a dump and the inclusive Ir of hrt::compute_depth_gradient."""
    r = subprocess.run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", dump], capture_output=True,
                       text=True, check=True)
    total = force = 0
    for line in r.stdout.splitlines():
        m = re.match(r"\s*([\d,]+)\s+(\([^)]*\)\s+)?(PROGRAM TOTALS|\S.*)", line)
        if not m:
            continue
        ir = int(m.group(1).replace(",", ""))
        what = m.group(3)
        if what.startswith("PROGRAM TOTALS"):
            total = ir
        elif "hrt::compute_depth_gradient(" in what and force == 0:
            force = ir
    return total, force


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hrt", default=None, help="the binary measured (default .venv/bin/hrt, else build/runtime/hrt)")
    ap.add_argument("--hrt-old", default=None, help="a second binary, alternated with --hrt in every round")
    ap.add_argument("--hbake", default=str(ROOT / ".venv/bin/hbake"), help="hbake, to bake the grating when missing")
    ap.add_argument("--out", default=str(ROOT / "out/bench"), help="the bundles' folder (default out/bench)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of alternated runs (default 3)")
    ap.add_argument("--frames", type=int, default=100, help="poses per pass of the timed sweeps (default 100)")
    ap.add_argument("--resolutions", default="32,50,64,128", help="grid resolutions N (default 32,50,64,128)")
    ap.add_argument("--copies", default="4,16", help="K of the copies scenes (default 4,16)")
    ap.add_argument("--callgrind-frames", type=int, default=20,
                    help="poses of each sweep under callgrind (default 20; 0 skips callgrind)")
    args = ap.parse_args()
    hrt = args.hrt or default_hrt()
    bins = [("new", hrt)] + ([("old", args.hrt_old)] if args.hrt_old else [])
    for name, path in bins:
        if not (shutil.which(path) or (os.path.isfile(path) and os.access(path, os.X_OK))):
            fail(f"{path}: not an executable hrt binary (--hrt{'-old' if name == 'old' else ''})")
    if args.rounds < 1 or args.frames < 1 or args.callgrind_frames < 0:
        fail("--rounds and --frames must be at least 1, --callgrind-frames at least 0")
    resolutions = [int(x) for x in args.resolutions.split(",")]
    copies = [int(x) for x in args.copies.split(",") if x.strip() and int(x) != 1]
    bundles = ensure_bundles(Path(args.out), args.hbake)
    cores = os.cpu_count() or 1
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    load = open("/proc/loadavg").read().split()[:3] if os.path.exists("/proc/loadavg") else ["?"]
    print(f"machine: {cpu}, {cores} logical cores, load {' '.join(load)}; rounds {args.rounds}, "
          f"{args.frames} poses per pass")
    for name, path in bins:
        print(f"  {name}: {path}")

    threads = [1, 0] if cores > 1 else [1]
    # (binary, threads, scene, N) -> list of per-run summaries
    runs: dict[tuple, list[dict]] = {}
    for rnd in range(args.rounds):
        for name, path in bins:
            for t in threads:
                for scene, a, b, sc, cps in (
                        ("scraping", bundles["rasp"], bundles["part"], SCRAPING, ",".join(map(str, [1, *copies]))),
                        ("steep", bundles["grating"], bundles["grating"], STEEP, "1")):
                    j = bench(path, a, b, sc, resolutions=args.resolutions, copies=cps, frames=args.frames,
                              passes=2, threads=t)
                    for key, r in results(j, scene).items():
                        runs.setdefault((name, t, *key), []).append(r)
        print(f"round {rnd + 1} of {args.rounds} done", flush=True)

    scenes = ["scraping", *[f"copies {k}" for k in copies], "steep"]
    print("\nWall medians, one thread (us): texture force per patch, collision per pair, clustering, frame; "
          "the frame's split (collision / clustering / texture force)")
    hdr = f"{'scene':10} {'N':>4} {'binary':6} {'patches':>7} {'force/patch':>11} {'coll/pair':>9} {'cluster':>8} " \
          f"{'frame':>8}  split"
    print(hdr)
    for scene in scenes:
        for n in resolutions:
            for name, _ in bins:
                rs = runs.get((name, 1, scene, n), [])
                if not rs:
                    continue
                fp = med([r["force_per_patch_us"] for r in rs])
                cp = med([r["collision_per_pair_us"] for r in rs])
                cl = med([r["clustering_us"] for r in rs])
                co = med([r["collision_us"] for r in rs])
                fo = med([r["force_us"] for r in rs])
                to = med([r["total_us"] for r in rs])
                pm = rs[0]["patches"]["median"]
                split = f"{co / to:.0%} / {cl / to:.0%} / {fo / to:.0%}" if to > 0 else "-"
                print(f"{scene:10} {n:>4} {name:6} {pm:>7g} {fp:>11.1f} {cp:>9.2f} {cl:>8.1f} {to:>8.1f}  {split}")
    if len(bins) > 1:
        for t in threads:
            label = "one thread" if t == 1 else f"{cores} threads"
            print(f"\nold / new, texture force per frame, {label} (ratio of medians; > 1: new is faster)")
            for scene in scenes:
                line = [f"{scene:10}"]
                for n in resolutions:
                    new = med([r["force_us"] for r in runs.get(("new", t, scene, n), [])])
                    old = med([r["force_us"] for r in runs.get(("old", t, scene, n), [])])
                    line.append(f"N={n}: {old / new:.2f}")
                print("  ".join(line))
    if len(threads) > 1:
        print(f"\nThread scaling, texture force per frame (us), binary 'new': 1 thread vs {cores} (every core)")
        for scene in scenes:
            for n in resolutions:
                one = med([r["force_us"] for r in runs.get(("new", 1, scene, n), [])])
                alln = med([r["force_us"] for r in runs.get(("new", 0, scene, n), [])])
                pm = runs[("new", 1, scene, n)][0]["patches"]["median"]
                print(f"{scene:10} N={n:<4} patches {pm:<4g} {one:9.1f} -> {alln:9.1f}  x{one / alln:.2f}")
    if args.callgrind_frames > 0:
        if not (shutil.which("valgrind") and shutil.which("callgrind_annotate")):
            print("\n(valgrind not installed: no instruction counts)")
            return
        print(f"\nInstructions per patch (callgrind, one thread, {args.callgrind_frames} poses per sweep): "
              "the frame's, the texture force's")
        for name, path in bins:
            cg = callgrind(path, bundles, resolutions, copies, args.callgrind_frames)
            for scene in scenes:
                for n in resolutions:
                    if (scene, n) in cg:
                        tot, force, patches = cg[(scene, n)]
                        print(f"{scene:10} N={n:<4} {name:4} {tot / 1e3:9.0f} k  {force / 1e3:9.0f} k  "
                              f"({patches} patches)")


if __name__ == "__main__":
    main()
