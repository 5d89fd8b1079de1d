#!/usr/bin/env python3
"""Write the scripted device trajectories of the four experiments
beside this file (docs/trajectory-format.md); the scenes examples/experiments/*.toml
play them. The same code writes the same bytes (run it after changing a path; the CSVs
are committed so that a scene can be read with its path).

Poses are those of the device handle; every scene's [workspace] grasp_position is
the probe's centre, so a handle rotation turns the probe about its centre.

* translation.csv (Fig. 7): the ridged block, upside down on the ridged gear (axis
  along x, so the gear's ridges run along x under the block's), a quarter wavelength
  off the nested position and 0.3 mm below the nested contact level: held, slid 8 mm along the ridges
  (x), 12.5 mm (2.5 ridges) across them (y), lifted 1.5 mm off (z) and put back. 3 s.
* rotation.csv (Fig. 8): the ridged block upside down on a second one, nested, 0.2 mm
  below contact; turned about n = z by +/-3.7 degrees (two periods of 2.5 s). 5.3 s.
* scraping.csv (Fig. 9): the file (rasp) teeth down across the ridge of the machined CAD
  part, 0.3 mm below it, scraped 20 mm along x in 0.5 s (500 frames at 1 kHz) with a
  small sideways wobble.
* scraping_dense.csv (Fig. 9, busier): the file drawn 20 mm along x across three copies
  of the CAD part over their lower step, with a sideways wobble: 5 to 7 patches per frame (measured).
* hammer.csv: the knurled hammer, head down, pressed 0.3 mm into the wrinkled torus's
  top and slid 12 mm along the tube in 1 s.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
MM = 1e-3

# Ridged block (hbake/lab/procedural.py): 50 x 60 x 20 mm, ridges along x, wavelength 5 mm,
# amplitude 0.5 mm, mean top at 20 mm; its centre in its own frame:
BLOCK_C = (25 * MM, 30 * MM, 10 * MM)
L, A = 5 * MM, 0.5 * MM
# Ridged gear: mean rim radius R = 50 * 5 mm / (2 pi) = 39.789 mm.
GEAR_R = 50 * L / (2 * math.pi)


def quat(axis, angle):
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    return np.array([*(a * math.sin(angle / 2)), math.cos(angle / 2)])


def qmul(q1, q2):
    x1, y1, z1, w1 = q1
    x2, y2, z2, w2 = q2
    return np.array([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])


def write(name, rows):
    with open(HERE / name, "w") as f:
        f.write("t,x,y,z,qx,qy,qz,qw\n")
        for t, p, q in rows:
            f.write(",".join(f"{v:.9g}" for v in (t, *p, *q)) + "\n")
    print(f"wrote {HERE / name} ({len(rows)} rows)")


FLIP = quat([1, 0, 0], math.pi)     # upside down: ridges along x stay along x


def translation():
    # Block frame origin at (x0, y0, z0) upside down: its centre is at
    # (x0 + 25, y0 - 30, z0 - 10) mm. The gear's top line is at z = R; nested when the
    # block's y0 is an odd multiple of L / 2 (32.5 mm), a quarter wavelength off at
    # 33.75 mm, where the block clears the gear by 2 A sin(pi / 4) = 0.707 mm more.
    x0, y0 = -15 * MM, 32.5 * MM + L / 4
    # Pressed 0.3 mm below the nested contact level, so the block stays in contact in
    # the nested position too.
    z = 20 * MM + GEAR_R - 0.3 * MM
    def c(x, y, zz):
        return (x + BLOCK_C[0], y - BLOCK_C[1], zz - BLOCK_C[2])
    keys = [(0.0, c(x0, y0, z)), (0.2, c(x0, y0, z)), (1.2, c(x0 + 8 * MM, y0, z)),
            (2.4, c(x0 + 8 * MM, y0 + 2.5 * L, z)), (2.7, c(x0 + 8 * MM, y0 + 2.5 * L, z + 1.5 * MM)),
            (3.0, c(x0 + 8 * MM, y0 + 2.5 * L, z))]
    write("translation.csv", [(t, p, FLIP) for t, p in keys])


def rotation():
    # B at the origin; A upside down with its frame at (0, 60 mm, 40 mm): nested (its
    # y0 a multiple of L), its centre at (25, 30, 30) mm. 0.2 mm below contact.
    centre = (25 * MM, 30 * MM, 30 * MM - 0.2 * MM)
    rows = []
    theta_max = math.radians(3.7)
    for k in range(531):
        t = k * 0.01
        th = 0.0 if t < 0.3 else theta_max * math.sin(2 * math.pi * (t - 0.3) / 2.5)
        rows.append((t, centre, qmul(quat([0, 0, 1], th), FLIP)))
    write("rotation.csv", rows)


def scraping():
    # The CAD part (fandisk, cm) upside down at (0, 0.152, 0): its stepped fan side up,
    # the highest ridge at z = 26.5 mm near y = 4 mm. The rasp (160 x 20 x 6.8 mm,
    # centred, teeth tips 3.4 mm below its centre) lies along x.
    z = 26.5 * MM + 3.4 * MM - 0.3 * MM
    rows = []
    for k in range(51):
        t = k * 0.01
        x = 0.024 + 0.02 * min(t / 0.5, 1.0) - 0.01
        y = 0.004 + 0.0015 * math.sin(2 * math.pi * t / 0.25)
        rows.append((t, (x, y, z), (0, 0, 0, 1)))
    write("scraping.csv", rows)


def scraping_dense():
    # Fig. 9's busier contact: the same file drawn across three machined parts clamped
    # side by side (scraping_dense.toml: 52 mm apart along x, the outer two shifted by
    # -/+0.6 mm along y), over their lower step (z = 15.2 mm, about 0.3 mm deep), with
    # a sideways wobble that brings each part's second facet in and out of contact: 5 to
    # 7 patches per frame.
    rows = []
    for k in range(51):
        t = k * 0.01
        x = 0.014 + 0.02 * min(t / 0.5, 1.0)
        y = -0.0115 + 0.0009 * math.sin(2 * math.pi * t / 0.25)
        rows.append((t, (x, y, 15.2 * MM), (0, 0, 0, 1)))
    write("scraping_dense.csv", rows)


def hammer():
    # The torus (R 50 mm, tube 20 mm, axis z, at the origin): its top at z = 20 mm over
    # (50, 0). The hammer (inches; centred, head at the top of the file, its head's top
    # face at z = +104.7 mm) turned upside down about x: that face is down. Its centre is
    # its frame's origin.
    z = 20 * MM + 104.7 * MM - 0.3 * MM
    keys = [(0.0, (50 * MM, -6 * MM, z + 2 * MM)), (0.2, (50 * MM, -6 * MM, z)),
            (1.2, (50 * MM, 6 * MM, z))]
    write("hammer.csv", [(t, p, FLIP) for t, p in keys])


if __name__ == "__main__":
    translation()
    rotation()
    scraping()
    scraping_dense()
    hammer()
