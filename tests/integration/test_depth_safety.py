"""Patch safety on the scenes of the full-surface depth tests.

The runs are those of tests/integration/test_fullsurface_depth.py (fullsurface.group_runs: the
gratings pressed together at six offsets, a bumpy sphere on a textured plate, three
shared models on a textured plate and a plain box, at N = 50 and 128), checked by
fullsurface.safety_failures: a refused patch gives no force and delta_force 0; a patch
not refused has delta_force = min(delta, delta_bound) and is clamped exactly when
delta > delta_bound; every wrong-way patch (the full meshes along its n go through the
bodies, deeper than 5 mm) is refused; delta_bound never cuts the truth of a kept patch;
warnings.refused_patches and clamped_patches count them. The gratings' nested pose is
the constructed case: its side pieces give patches whose n runs through both blocks.
"""
from __future__ import annotations

import numpy as np

import fullsurface as FS



def test_safety_patches(hrt, models):
    groups = ["gratings", "sphere"] + (["models"] if FS.shared_present() else [])
    runs = [r for g in groups for r in FS.group_runs(hrt, models, g)]
    missing = FS.safety_members_missing(runs)
    assert not missing, f"hrt query --json has no {missing} per contact"
    wrong = [(r, c, p) for r in runs for c, p in zip(r.query["contacts"], r.patches) if p.wrong_way]
    print(f"\n{len(wrong)} wrong-way patches, {sum(bool(c['refused']) for _, c, _ in wrong)} refused, "
          f"{sum(bool(np.any(c['force'])) for _, c, _ in wrong)} with force")
    assert any(r.scene.name == "gratings_offset0.00L" for r, _, _ in wrong), \
        "the constructed case (the gratings' nested pose) no longer gives a wrong-way patch"
    failures = FS.safety_failures(runs)
    assert not failures, f"{len(failures)} safety failures:\n" + "\n".join(failures[:20])
