#!/usr/bin/env bash
# The worked haptic session, end to end: make the models, bake them (once), write the
# device path, run `hrt run` on examples/session/scene.toml (lockstep; pass --realtime
# for the 1 kHz device thread) and print the summary. Usage: bash examples/session/run.sh [hrt run options]
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=out/session
PY=.venv/bin/python
mkdir -p "$OUT"
if [ ! -f "$OUT/ball.hbundle/manifest.json" ] || [ ! -f "$OUT/grating.hbundle/manifest.json" ]; then
  $PY examples/session/make_models.py "$OUT"
  .venv/bin/hbake bake "$OUT/ball.ply" -o "$OUT/ball.hbundle" -f -q --set 'load.units="m"'
  .venv/bin/hbake bake "$OUT/grating.ply" -o "$OUT/grating.hbundle" -f -q --set 'load.units="m"'
fi
$PY examples/session/make_path.py "$OUT"
.venv/bin/hrt run examples/session/scene.toml "$@"
