#!/usr/bin/env python3
"""A short summary of the translation experiment's trace (`make demo`): frames, the
force along the ridges against the normal force while the block slides along them,
and the height steps while it crosses them.

    .venv/bin/python examples/experiments/summary.py out/experiments/translation.trace.csv
"""
import sys

import numpy as np

from hbake.viz.plot import Trace

tr = Trace(sys.argv[1])
t = tr["t"]
F = tr.vec("contact_f")
z = tr["probe_z"]
along = (t > 0.3) & (t <= 1.2)          # paths.py: 0.2-1.2 s along x (the ridges)
across = (t > 1.3) & (t <= 2.4)         # 1.2-2.4 s across them (y)
rx = np.sqrt(np.mean(F[along, 0] ** 2))
rn = np.sqrt(np.mean(F[along, 2] ** 2))
print(f"{tr.path}: {len(tr)} frames ({t[-1]:.2f} s), up to {int(tr['patches'].max())} patch(es); "
      f"frame compute median {np.median(tr['frame_us']) / 1e3:.2f} ms")
print(f"  along the ridges (x): RMS Fx {rx * 1e3:.2f} mN = {rx / rn:.2%} of RMS Fz {rn * 1e3:.0f} mN "
      f"(the paper: 'almost 0')")
print(f"  across the ridges (y): the block rises and falls by {np.ptp(z[across]) * 1e3:.2f} mm "
      f"(2 x amplitude = 1 mm) while Fy swings over {np.ptp(F[across, 1]):.2f} N")
