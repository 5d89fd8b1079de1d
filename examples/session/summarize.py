"""Medians over `hrt run --json` summaries read from stdin (examples/bench_session.sh)."""
import json
import statistics
import sys

text = sys.stdin.read()
docs, dec, i = [], json.JSONDecoder(), 0
while i < len(text):
    if text[i].isspace():
        i += 1
        continue
    d, i = dec.raw_decode(text, i)
    docs.append(d)
mode = sys.argv[1]
if not docs:
    sys.exit(f"{mode}: no run completed")


def med(*keys):
    vals = []
    for d in docs:
        for k in keys:
            d = d[k]
        vals.append(d)
    return statistics.median(vals)


fifo = sum(bool(d["device_loop"].get("sched_fifo")) for d in docs)
print(f"{mode:6s} ({len(docs)} runs, SCHED_FIFO granted in {fifo}): period error "
      f"p50 {med('device_loop', 'jitter_us', 'p50'):.1f} us, p99 {med('device_loop', 'jitter_us', 'p99'):.1f} us, "
      f"max {med('device_loop', 'jitter_us', 'max'):.1f} us; simulation {med('simulation', 'rate_hz'):.0f} Hz "
      f"achieved, frame compute median {med('simulation', 'frame_us_median'):.0f} us "
      f"({med('simulation', 'compute_rate_hz'):.0f} frames/s of compute)")
