"""The patch normal n checked by the wrench in the demo's scene.

examples/demo.sh: two baked ridged blocks (hbake's procedural ridged_block at the
default 600 coarse faces, so the coarse mesh follows the ridges and CoACD cuts it
into slabs whose hulls are bevelled at the cuts), A upside down, 1 mm off the nested
position across the ridges and 0.2 mm low. Along z the closed form is
delta = 2 a sin(pi s / lambda) + g = 0.788 mm, and the force on A is along the
ridge flank's normal m = (0, -d delta/ds, 1) / |.| with d delta/ds =
2 a (pi / lambda) cos(pi s / lambda) = 0.508, |F| = k delta |(0, 0.508, 1)|.

The runtime's n is the weighted mean of the piece pairs' normals (cluster.cpp).
The two pairs across the slabs' cuts overlap along the bevels, whose normals are
tilted 23.6 degrees; weighted by depth alone (the previous rule) they tilted n by
6.8 degrees, and delta along n dropped to 0.736 mm, |F| 11 % low. Weighted by
their overlap area (the rule now) they count for their 3.3 mm strips against the
flat pairs' 18 mm: the tilt is at most atan(2 r q sin(23.6) / (3 + 2 r q
cos(23.6))) = 1.6 degrees (r = 3.3 / 18 the area ratio, q = 0.62 their depth
ratio), below 2.5 degrees with the margin of the box estimate of the areas.

Bounds, fixed in advance:
* tilt of n from -z <= 2.5 degrees (the estimate above plus margin);
* direction of F within 2.5 degrees of m: for a line contact the gradient of the
  directional depth is m / (m . n) whatever n (so F is along m), up to the
  finite differences over one grid texel (0.24 mm at N = 256, 1/20 of the
  wavelength) and the mesh being the piecewise-linear interpolant of the sine
  (12 rows per wavelength, hbake.lab.procedural);
* |F| within 8.5 % of the closed form: a tilt phi toward m scales delta by
  cos(theta) / cos(theta - phi) and |grad delta| by the same (theta = 26.9 deg,
  the flank's angle): 4.2 % at 2.5 degrees, plus 2 x 17 um of the
  piecewise-linear mesh against the sine on 0.788 mm (4.3 %).
"""
from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest
from hrt_locate import hrt_binary

from hbake.lab import procedural as P
from hbake.routes.pipeline import bake
from hbake.settings import BakeSettings

K_STIFF = 1000.0
S_OFF, GAP = 1e-3, 0.2e-3
POSE_A = ["0", "0.061", "0.0398", "1", "0", "0", "0"]  # demo.sh: 180 deg about x
POSE_B = ["0", "0", "0", "0", "0", "0", "1"]


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("patch_normal")
    src = root / "ridged_block.ply"
    P.MODELS["ridged_block"].make().export(src)
    out = root / "ridged_block.hbundle"
    bake(src, out, BakeSettings().with_overrides({"load.units": "m", "quality.samples": 20000}))
    return out


def test_demo_scene_wrench_against_closed_form(block, record_property):
    res = subprocess.run([hrt_binary(), "query", str(block), str(block), "--pose-a", *POSE_A,
                          "--pose-b", *POSE_B, "--stiffness", str(K_STIFF), "--resolution", "256", "--json"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    contacts = [c for c in out["contacts"] if c["covered"] and c["delta"] > 0]
    assert len(contacts) == 1, out["contacts"]
    c = contacts[0]
    assert not c["refused"] and not c["clamped"]
    a, lam = P.BLOCK_AMPLITUDE, P.BLOCK_WAVELENGTH
    delta = 2 * a * math.sin(math.pi * S_OFF / lam) + GAP
    slope = 2 * a * math.pi / lam * math.cos(math.pi * S_OFF / lam)
    m = np.array([0.0, -slope, 1.0])
    f_closed = K_STIFF * delta * m
    n = np.asarray(c["n"])
    F = np.asarray(out["force"])
    tilt = math.degrees(math.acos(min(1.0, -n[2])))
    angle = math.degrees(math.acos(min(1.0, F @ f_closed / np.linalg.norm(F) / np.linalg.norm(f_closed))))
    rel = np.linalg.norm(F) / np.linalg.norm(f_closed) - 1
    record_property("tilt_deg", tilt)
    record_property("force_angle_deg", angle)
    record_property("force_rel_error", rel)
    assert tilt <= 2.5, (tilt, c["n"])
    assert angle <= 2.5, (angle, F, f_closed)
    assert abs(rel) <= 0.085, (rel, F, f_closed)
