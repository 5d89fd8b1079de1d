#!/usr/bin/env bash
# Benchmark of the haptic session: `hrt run --realtime` on the worked scene
# (examples/session: a 4 mm ball tip drawn over the baked grating, one contact patch at
# N = 50, the corrected heights, friction on), REPEATS runs of DURATION s each, with and
# without SCHED_FIFO for the device thread. Prints the machine, its load, and per mode the
# medians over the runs of: the device loop's period error p50 / p99 / max (us) and the
# simulation's compute rate (frames per second of frame compute) and achieved rate.
# Never asserted in tests. Usage: bash examples/bench_session.sh [REPEATS] [DURATION]
# Environment: RUN_ARGS, more `hrt run` options (e.g. "--threads 1": the texture force and
# the narrow phase on the simulation thread only; the default is every hardware thread).
set -euo pipefail
cd "$(dirname "$0")/.."
REPEATS=${1:-3}
DURATION=${2:-5}
HRT=${HRT:-.venv/bin/hrt}
bash examples/session/run.sh --quiet >/dev/null   # bakes the bundles once, writes the path
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(nproc) cores; load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
for mode in normal fifo; do
  flags=""; [ "$mode" = fifo ] && flags="--sched-fifo"
  for r in $(seq "$REPEATS"); do
    # shellcheck disable=SC2086
    "$HRT" run examples/session/scene.toml --realtime --duration "$DURATION" $flags ${RUN_ARGS:-} --json --trace out/session/bench-trace.csv 2>/dev/null || true
  done | .venv/bin/python examples/session/summarize.py "$mode"
done
# The platform's own wake-up latency, for comparison (rt-tests' cyclictest, when installed:
# `apt-get install rt-tests`): a thread sleeping to absolute 1 ms deadlines and nothing else.
if command -v cyclictest >/dev/null; then
  for p in 0 80; do
    echo "cyclictest (priority $p, 5000 loops at 1 ms): $(cyclictest -m -p $p -i 1000 -l 5000 -q 2>/dev/null | tail -1 | sed 's/.*Min:/Min:/') us"
  done
fi
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
