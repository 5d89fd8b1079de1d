#!/usr/bin/env bash
# Regenerate the results of docs/guides/experiments.md (the figures in docs/figures and the Table 1 rows):
# bake the six benchmark models, run the five experiments, draw their figures, copy
# those docs/guides/experiments.md shows into docs/figures. Run on a quiet machine: Fig. 9 and the
# bake times are wall clock. Usage: bash examples/experiments/docs_figures.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=out/experiments
.venv/bin/python examples/experiments/table.py "$OUT" --markdown "$OUT/table1.md"
bash examples/experiments/run.sh all
mkdir -p docs/figures
for f in translation.trace.fig7 translation.trace.scene rotation.trace.fig8 scraping.trace.fig9 scraping_dense.trace.fig9 \
         hammer.trace.fig9 hammer.trace.scene; do
  cp "$OUT/figures/$f.png" "docs/figures/$f.png"
done
cp "$OUT/table1.md" docs/figures/table1.md
echo "docs/figures updated ($(nproc) cores: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2))"
