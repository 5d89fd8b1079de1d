#!/usr/bin/env bash
# Does every bundle that validates also run? Bakes the shared models and the
# procedural ones with several CoACD seeds (CoACD's pieces decide which piece
# pairs the narrow phase meets) and queries each bundle against itself twice:
# far apart (Scene construction only) and coincident (every adjacent piece
# pair overlapping, the narrow phase on all of them). Prints one line per
# bundle with both exit codes; any non-zero one is a finding (134 = abort).
#
#   bash examples/seed_sweep.sh [OUTDIR] [SEEDS]    (default out/seed_sweep, "0 1 2 3")
#
# Environment: HBAKE, HRT (default .venv/bin/hbake, .venv/bin/hrt), SAMPLES
# (quality samples per bake, default 2000: the sweep needs pieces, not figures).
# A run of 52 bundles takes about 25 minutes on a 2-core machine.
set -uo pipefail

cd "$(dirname "$0")/.."
OUT=${1:-out/seed_sweep}
SEEDS=${2:-"0 1 2 3"}
HBAKE=${HBAKE:-.venv/bin/hbake}
HRT=${HRT:-.venv/bin/hrt}
SAMPLES=${SAMPLES:-2000}
SHARED=${HBAKE_MODELS:-../shared/models}  # the shared models: $HBAKE_MODELS, else beside the repository
mkdir -p "$OUT"

inputs=()
for g in ridged_block ridged_gear wrinkled_torus grating rasp; do
  [ -f "$OUT/$g.ply" ] || "$HBAKE" generate "$g" "$OUT/$g.ply" || exit 1
  inputs+=("$OUT/$g.ply")
done
if [ -d "$SHARED" ]; then
  for m in stanford_bunny.obj armadillo.obj fandisk.obj rocker_arm.obj hammer_scan.obj mountain_terrain.obj planetary_gears.stl; do
    inputs+=("$SHARED/$m")
  done
else
  echo "seed_sweep.sh: $SHARED not found; sweeping the procedural models only" >&2
fi

bad=0
for s in $SEEDS; do
  for m in "${inputs[@]}"; do
    name=$(basename "$m"); name=${name%.*}
    bundle="$OUT/${name}_s$s.hbundle"
    extra=()
    # The settings the bench uses for the 7-body gear set (docs/guides/baking.md, "Bake benchmark").
    [ "$name" = planetary_gears ] && extra=(--target-faces 1200 --set decompose.threshold=0.1)
    if [ ! -d "$bundle" ]; then
      "$HBAKE" bake "$m" --units m -o "$bundle" --seed "$s" --samples "$SAMPLES" -q "${extra[@]}" \
        || { echo "$bundle bake failed (exit $?)"; bad=1; continue; }
    fi
    "$HRT" query "$bundle" "$bundle" --pose-a 0 0 0 0 0 0 1 --pose-b 50 0 0 0 0 0 1 >/dev/null 2>&1
    far=$?
    "$HRT" query "$bundle" "$bundle" --pose-a 0 0 0 0 0 0 1 --pose-b 0.0001 0.0002 0 0 0 0 1 >/dev/null 2>&1
    coincident=$?
    echo "$bundle far=$far coincident=$coincident"
    [ "$far" = 0 ] && [ "$coincident" = 0 ] || bad=1
  done
done
exit $bad
