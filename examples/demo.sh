#!/usr/bin/env bash
# `make demo`: the paper's roughness-under-translation experiment (Sec. 6.3, Fig. 6b and
# 7) end to end, on the CPU backend with a scripted device: bake the ridged block and
# the ridged gear (hbake generate + hbake bake, once), run the session
# examples/experiments/translation.toml with `hrt run` (lockstep, frictionless), write
# the trace, the Fig. 7-style figure and a picture of the scene (`hbake plot`), and
# print where they are with a short summary. Everything goes to out/experiments.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=.venv/bin
OUT=out/experiments
start=$(date +%s)

echo "== 1. make and bake the ridged block (65,536 triangles) and the ridged gear (25,600)"
$BIN/python examples/experiments/models.py "$OUT" block gear

echo "== 2. run the translation experiment (3 s of session, 1 kHz lockstep, CPU backend)"
$BIN/hrt run examples/experiments/translation.toml --backend cpu

echo "== 3. figures from the trace"
mkdir -p "$OUT/figures"
$BIN/hbake plot "$OUT/translation.trace.csv" -o "$OUT/figures" --figure fig7 --figure scene \
  --scene examples/experiments/translation.toml --frame 1800 --hrt "$BIN/hrt"

echo "== summary"
$BIN/python examples/experiments/summary.py "$OUT/translation.trace.csv"
echo "  trace:        $OUT/translation.trace.csv (docs/trace-format.md)"
echo "  Fig. 7:       $OUT/figures/translation.trace.fig7.png"
echo "  scene:        $OUT/figures/translation.trace.scene.png (frame 1800: block, gear, patch window, force)"
echo "  other experiments: bash examples/experiments/run.sh rotation|scraping|hammer|all"
echo "  demo took $(( $(date +%s) - start )) s"
