#!/usr/bin/env bash
# The GL depth backend against the CPU backend on the
# scraping scene of examples/bench_runtime.sh (the rasp on the CAD part, as
# in the paper's Fig. 9), with K copies of the part along the path so that
# the number of patches per frame grows: per backend, the median frame time
# by patch count and, for gl, its split (upload, draw, resolve, reduce,
# read-back; profiled: a wait after each stage) and round trips.
#
#   bash examples/bench_gl.sh [OUTDIR]    (default out/bench; bundles baked by bench_runtime.sh)
#
# Environment: HRT, FRAMES (100), PASSES (3, the first a warm-up), RESOLUTIONS (50),
# COPIES (1,2,4), HEIGHTS (surface,mesh: the height modes, each on every backend;
# the mesh heights draw every atlas quad of the faces in reach, the work a GPU is
# made for). On a machine with only a software renderer (llvmpipe) the GL
# figures are CPU-bound: they measure Mesa's rasterizer, not a GPU.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/bench}
if [ -z "${HRT:-}" ]; then
  if [ -x .venv/bin/hrt ]; then HRT=.venv/bin/hrt; else HRT=build/runtime/hrt; fi
fi
[ -d "$OUT/rasp.hbundle" ] && [ -d "$OUT/cad_part.hbundle" ] || {
  echo "bench_gl.sh: no bundles in $OUT (run: bash examples/bench_runtime.sh $OUT)" >&2; exit 2; }
FRAMES=${FRAMES:-100}
PASSES=${PASSES:-3}
RES=${RESOLUTIONS:-50}
COPIES=${COPIES:-1,2,4}
"$HRT" gl-info || true
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg)"
bench() {
  "$HRT" bench --a "$OUT/rasp.hbundle" --b "$OUT/cad_part.hbundle" \
    --pose-a 0.1295 0.0345 0.0184 0 0 0 1 --pose-b 0 0 0 0 0 0 1 \
    --settle -1 1 -1 --settle-depth 5e-5 --path 0.02 0 0 --frames "$FRAMES" --passes "$PASSES" \
    --resolutions "$RES" --copies "$COPIES" "$@"
}
IFS=, read -r -a MODES <<< "${HEIGHTS:-surface,mesh}"
for h in "${MODES[@]}"; do
  for b in "--backend cpu" "--backend gl" "--backend gl --gl-search occlusion"; do
    echo "=== --heights $h $b"
    # shellcheck disable=SC2086
    bench --heights "$h" $b 2>&1 | sed -n '/^machine/p;/^Scraping path by patch count/,$p'
  done
done
