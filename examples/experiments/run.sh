#!/usr/bin/env bash
# The paper's experiments (Sec. 6) end to end: bake the models an experiment needs
# (models.py, once), run its scene with `hrt run` (lockstep, CPU backend, scripted
# device), and draw its figures from the trace (`hbake plot`).
#
#   bash examples/experiments/run.sh [translation|rotation|scraping|scraping_dense|hammer|all] [hrt run options]
#
# Bundles, traces and figures go to out/experiments (figures in out/experiments/figures).
# HRT=path overrides the hrt binary (default .venv/bin/hrt, built by `make runtime`).
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
HRT=${HRT:-.venv/bin/hrt}
OUT=out/experiments
FIG=$OUT/figures
what=${1:-all}
[ $# -gt 0 ] && shift
mkdir -p "$FIG"

run_one() {  # name, models..., then the figures of `hbake plot`
  local name=$1; shift
  local models=() figs=()
  while [ $# -gt 0 ] && [ "$1" != "--" ]; do models+=("$1"); shift; done
  shift
  figs=("$@")
  $PY examples/experiments/models.py "$OUT" "${models[@]}"
  "$HRT" run "examples/experiments/$name.toml" --backend cpu "${EXTRA[@]}"
  local args=()
  for f in "${figs[@]}"; do args+=(--figure "$f"); done
  HRT="$HRT" .venv/bin/hbake plot "$OUT/$name.trace.csv" -o "$FIG" --scene "examples/experiments/$name.toml" \
    --hrt "$HRT" "${args[@]}" ${FRAME:+--frame "$FRAME"}
}

EXTRA=("$@")
case $what in
  translation|all) FRAME=${FRAME_TRANSLATION:-1800} run_one translation block gear -- fig7 scene ;;&
  rotation|all)    FRAME=${FRAME_ROTATION:-925} run_one rotation block -- fig8 scene ;;&
  scraping|all)    FRAME=${FRAME_SCRAPING:-250} run_one scraping file cad -- fig9 scene ;;&
  scraping_dense|all) FRAME=${FRAME_SCRAPING_DENSE:-250} run_one scraping_dense file cad -- fig9 scene ;;&
  hammer|all)      FRAME=${FRAME_HAMMER:-700} run_one hammer hammer torus -- fig9 scene ;;&
  translation|rotation|scraping|scraping_dense|hammer|all) ;;
  *) echo "run.sh: unknown experiment '$what' (translation, rotation, scraping, scraping_dense, hammer, all)" >&2; exit 2 ;;
esac
