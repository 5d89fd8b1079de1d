#!/usr/bin/env bash
# Runtime benchmark of the paper's hardest case (Sec. 6.4, Fig. 9): a file
# (the procedural rasp) scraping a CAD part (the procedural milled bracket).
#
#   bash examples/bench_runtime.sh [OUTDIR]        (default OUTDIR: out/bench)
#
# 1. generates the two procedural models (hbake generate rasp / cad_part),
# 2. bakes them (hbake bake; skipped when the bundle exists, FORCE=1 re-bakes):
#    the rasp at 632 coarse triangles and the CAD part at 720 (the paper's
#    Table 1), the CAD part with a finer convex decomposition (CoACD threshold
#    0.02) so that many pieces sit under the tool,
# 3. runs `hrt bench`: the rasp starts beside the bracket's corner (plate top,
#    upright wall, boss), settles along (-1, 1, -1) until its deepest patch
#    penetrates 0.05 mm, then scrapes 20 mm along +x and back (500 poses per
#    pass), timed at N = 32, 50, 64, 128; plus scenes with K copies of the
#    part spread along the path (more patches, every one a real contact).
#
# Environment: HBAKE, HRT (the commands; default .venv/bin/hbake and
# .venv/bin/hrt, else build/runtime/hrt), FORCE=1 (re-bake), FRAMES (500),
# PASSES (3), RESOLUTIONS (32,50,64,128), COPIES (1,2,4,7,8,12,16) -- e.g.
# FRAMES=100 PASSES=2 RESOLUTIONS=50 COPIES=1,7 for a quick run -- and
# BENCH_ARGS (more hrt bench options, e.g. --json or --shortcut).
# Baking the 650k-triangle CAD part takes a few minutes.
set -euo pipefail

cd "$(dirname "$0")/.."
OUT=${1:-out/bench}
HBAKE=${HBAKE:-.venv/bin/hbake}
if [ -z "${HRT:-}" ]; then
  if [ -x .venv/bin/hrt ]; then HRT=.venv/bin/hrt; else HRT=build/runtime/hrt; fi
fi
for tool in "$HBAKE" "$HRT"; do
  if ! command -v "$tool" >/dev/null 2>&1 && [ ! -x "$tool" ]; then
    echo "bench_runtime.sh: $tool not found (run 'make setup' first)" >&2
    exit 2
  fi
done
mkdir -p "$OUT"

bake() {  # bake NAME BUNDLE [hbake bake options...]
  local name=$1 bundle=$2
  shift 2
  if [ -d "$bundle" ] && [ "${FORCE:-0}" != 1 ]; then
    echo "using existing $bundle"
    return
  fi
  [ -f "$OUT/$name.ply" ] || "$HBAKE" generate "$name" "$OUT/$name.ply"
  echo "baking $bundle ..."
  "$HBAKE" bake "$OUT/$name.ply" -o "$bundle" --units m --force --quiet "$@"
}

RASP=$OUT/rasp.hbundle
PART=$OUT/cad_part.hbundle
bake rasp "$RASP" --target-faces 632
bake cad_part "$PART" --target-faces 720 --set decompose.threshold=0.02

# The rasp (long axis x, 160 x 20 x 6.8 mm, centred on its origin) starts
# 3 mm out of the corner formed by the bracket's plate top (z = 12 mm), its
# upright's wall (y = 48 mm) and its boss (centre x = 30 mm, radius 16 mm),
# then settles into it.
# shellcheck disable=SC2086
"$HRT" bench --a "$RASP" --b "$PART" \
  --pose-a 0.1295 0.0345 0.0184 0 0 0 1 --pose-b 0 0 0 0 0 0 1 \
  --settle -1 1 -1 --settle-depth 5e-5 \
  --path 0.02 0 0 --frames "${FRAMES:-500}" --passes "${PASSES:-3}" \
  --resolutions "${RESOLUTIONS:-32,50,64,128}" --copies "${COPIES:-1,2,4,7,8,12,16}" ${BENCH_ARGS:-}
