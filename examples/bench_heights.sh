#!/usr/bin/env bash
# Cost of the surface heights (docs/bundle-format.md "Heights on a texel
# column") against the literal Eq. 8 (--heights coarse) on the scraping
# benchmark of examples/bench_runtime.sh, as a ratio measured in one run:
# the two modes alternate ROUNDS times (this machine is shared and its
# timings drift), each printing the median texture-force time per frame;
# then instruction counts of the same frames under callgrind (deterministic),
# when valgrind is installed.
#
#   bash examples/bench_heights.sh [OUTDIR]    (default out/bench; bundles baked by bench_runtime.sh)
#
# Environment: HRT, ROUNDS (3), FRAMES (500), RESOLUTIONS (50,128),
# MODES ("coarse surface mesh": the --heights modes compared).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/bench}
if [ -z "${HRT:-}" ]; then
  if [ -x .venv/bin/hrt ]; then HRT=.venv/bin/hrt; else HRT=build/runtime/hrt; fi
fi
[ -d "$OUT/rasp.hbundle" ] && [ -d "$OUT/cad_part.hbundle" ] || {
  echo "bench_heights.sh: no bundles in $OUT (run: bash examples/bench_runtime.sh $OUT)" >&2; exit 2; }
ROUNDS=${ROUNDS:-3}
FRAMES=${FRAMES:-500}
RES=${RESOLUTIONS:-50,128}
MODES=${MODES:-coarse surface mesh}
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg)"
bench() {  # bench MODE [extra hrt bench options]
  local mode=$1
  shift
  "$HRT" bench --a "$OUT/rasp.hbundle" --b "$OUT/cad_part.hbundle" \
    --pose-a 0.1295 0.0345 0.0184 0 0 0 1 --pose-b 0 0 0 0 0 0 1 \
    --settle -1 1 -1 --settle-depth 5e-5 --path 0.02 0 0 --frames "$FRAMES" --passes 2 \
    --resolutions "$RES" --copies 1 --heights "$mode" "$@"
}
for r in $(seq "$ROUNDS"); do
  for mode in $MODES; do
    echo "--- round $r, --heights $mode"
    bench "$mode" | sed -n '/^Scraping path: median/,/^$/p'
  done
done
if command -v valgrind >/dev/null; then
  echo "--- instructions of hrt::frame over the frames (callgrind, FRAMES=100, one pass after warm-up)"
  for mode in $MODES; do
    IFS=, read -ra Ns <<<"$RES"
    for N in "${Ns[@]}"; do
      n=$(FRAMES=100 valgrind --tool=callgrind --callgrind-out-file=/dev/null --toggle-collect='hrt::frame*' \
            "$HRT" bench --a "$OUT/rasp.hbundle" --b "$OUT/cad_part.hbundle" \
            --pose-a 0.1295 0.0345 0.0184 0 0 0 1 --pose-b 0 0 0 0 0 0 1 --settle -1 1 -1 --settle-depth 5e-5 \
            --path 0.02 0 0 --frames 100 --passes 1 --resolutions "$N" --copies 1 --heights "$mode" 2>&1 \
          | sed -n 's/.*Collected : \([0-9]*\).*/\1/p')
      echo "N=$N --heights $mode: $n instructions"
    done
  done
fi
