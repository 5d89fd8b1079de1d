#!/usr/bin/env bash
# Thread scaling of the texture force (the CPU backend's pool, `--threads`):
# the scraping scene of examples/bench_runtime.sh and its K-copies variant,
# `hrt bench --json` once per thread count per round, the thread counts
# alternated within each round (a shared machine's load then hits all of them
# alike), and a table of the medians over the rounds: the texture force per
# frame, its speed-up over one thread, and the scene's patches.
#
#   bash examples/bench_threads.sh [OUTDIR]     (default OUTDIR: out/bench)
#
# Environment: THREADS (1,2: the counts to compare), ROUNDS (5), FRAMES (100),
# RESOLUTIONS (50), COPIES (1,4,8,16), HRT, HBAKE as for bench_runtime.sh
# (whose bundles it bakes first when missing: a few minutes).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/bench}
if [ -z "${HRT:-}" ]; then
  if [ -x .venv/bin/hrt ]; then HRT=.venv/bin/hrt; else HRT=build/runtime/hrt; fi
fi
if [ ! -d "$OUT/rasp.hbundle" ] || [ ! -d "$OUT/cad_part.hbundle" ]; then
  FRAMES=2 PASSES=2 RESOLUTIONS=50 COPIES=1 bash examples/bench_runtime.sh "$OUT" >/dev/null
fi
PY=${PY:-.venv/bin/python}
[ -x "$PY" ] || PY=python3
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
IFS=, read -r -a counts <<< "${THREADS:-1,2}"
for r in $(seq 1 "${ROUNDS:-5}"); do
  for t in "${counts[@]}"; do
    "$HRT" bench --a "$OUT/rasp.hbundle" --b "$OUT/cad_part.hbundle" \
      --pose-a 0.1295 0.0345 0.0184 0 0 0 1 --pose-b 0 0 0 0 0 0 1 \
      --settle -1 1 -1 --settle-depth 5e-5 --path 0.02 0 0 --frames "${FRAMES:-100}" --passes 2 \
      --resolutions "${RESOLUTIONS:-50}" --copies "${COPIES:-1,4,8,16}" --threads "$t" --json \
      > "$TMP/r$r-t$t.json" 2>/dev/null
    echo "round $r, $t thread(s) done" >&2
  done
done
"$PY" - "$TMP" "${counts[@]}" <<'PYEOF'
import glob, json, statistics, sys
tmp, counts = sys.argv[1], [int(c) for c in sys.argv[2:]]
runs = {t: [json.load(open(p)) for p in sorted(glob.glob(f"{tmp}/r*-t{t}.json"))] for t in counts}
m = runs[counts[0]][0]["machine"]
print(f"machine: {m['cpu']}, {m['cores']} logical cores, compiler {m['compiler']}; "
      f"{len(runs[counts[0]])} rounds, thread counts alternated; medians over the rounds")
print(f"{'K':>3} {'N':>4} {'patches':>8} " + " ".join(f"{f'force us ({t} thr)':>18} {'x':>5}" for t in counts))
for ci, c in enumerate(runs[counts[0]][0]["copies"]):
    for n in sorted(c["results"], key=int):
        base = None
        line = f"{c['copies']:>3} {n:>4} {c['results'][n]['patches']['median']:>8.0f} "
        for t in counts:
            v = statistics.median(r["copies"][ci]["results"][n]["force_us"] for r in runs[t])
            base = base or v
            line += f"{v:>18.0f} {base / v:>5.2f} "
        print(line)
PYEOF
