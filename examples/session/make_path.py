"""The device path of the worked session: the ball tip held 0.3 mm below the grating's
crest line, then drawn across the ridges along x at 20 mm/s, a small circle, and back
(docs/trajectory-format.md; written to OUT/path.csv)."""
import math
import sys
from pathlib import Path

out = Path(sys.argv[1])
z = 0.020 + 0.0005 + 0.004 - 0.0003        # grating crest + ball radius - press
rows = [(0.0, 0.015, 0.030, z), (0.3, 0.015, 0.030, z), (2.3, 0.055, 0.030, z)]
for k in range(1, 41):                       # a 5 mm circle in 1 s
    a = 2 * math.pi * k / 40
    rows.append((2.3 + k / 40, 0.050 + 0.005 * math.cos(a), 0.030 + 0.005 * math.sin(a), z))
rows.append((5.3, 0.015, 0.030, z))
with open(out / "path.csv", "w") as f:
    f.write("t,x,y,z,qx,qy,qz,qw\n")
    for t, x, y, zz in rows:
        f.write(f"{t:.4f},{x:.6f},{y:.6f},{zz:.6f},0,0,0,1\n")
print(f"wrote {out / 'path.csv'}")
