"""Sampling: the runtime's depth against the truth sampled every 0.1 atlas
texel over the window (not only at the texel centres), on the runs of
tests/integration/test_fullsurface_depth.py (fullsurface.group_runs: the angled gratings at six
offsets, the bumpy sphere on the textured plate, and one shared model on the textured
plate and the plain box; N = 50 and 128). The patches compared are those the brute-force
test keeps (its keep rule and bound, from the full meshes). With CI set, a missing
../shared or hrt fails.
"""
from __future__ import annotations

import math
import time

import pytest

import fullsurface as FS



def _runs(hrt, models, group):
    return FS.group_runs(hrt, models, group)


#: The sampling test's model: one shared model with creases and thin fins (its scenes on
#: the textured plate and the plain box); the gratings and the sphere are all compared.
SAMPLING_MODEL = "fandisk"


# The shared models' group (about 50 s) is behind the slow marker; the gratings and the
# sphere run in `make test`.
@pytest.mark.parametrize("group", ["gratings", "sphere", pytest.param("models", marks=pytest.mark.slow)])
def test_depth_against_continuous_truth(group, hrt, models):
    """Sampling: against the truth sampled every 0.1 atlas texel over the window
    (fullsurface.continuous_truth: the maximum of h_A - h_B over the window, not only at
    the texel centres), |delta_hrt - delta_continuous| <= the patch's bound + s cell /
    sqrt(2). Why that bound: the runtime samples the texel centres, each within its
    bound of the full meshes there; every point of the window lies within cell / sqrt(2)
    of a texel centre, and h_A - h_B changes by at most s = s_A + s_B (the two full
    surfaces' largest slopes along n over the window, the harness's s) per unit of
    lateral distance. Both are fixed from the full meshes before comparing."""
    if group == "models":
        FS.require_shared()
    runs = _runs(hrt, models, group)
    if group == "models":
        runs = [r for r in runs if r.scene.a == SAMPLING_MODEL]
    t0 = time.perf_counter()
    rows, failures, cast = [], [], 0
    for r in runs:
        a, b = models[r.scene.a], models[r.scene.b]
        for c, p in zip(r.query["contacts"], r.patches):
            if not p.kept or p.problem or FS.refused(p) or not c["covered"]:
                continue
            cont, k = FS.continuous_truth(c, a, b, r.scene.pose_a, r.scene.pose_b, p)
            cast += k
            err = p.delta_rt - cont
            allowed = p.bound + sum(p.slope) * p.cell / math.sqrt(2)
            rows.append((abs(err) / p.texel, err, allowed, p, cont))
            line = (f"{p.scene} N={p.N} patch {p.patch}: hrt {p.delta_rt * 1e3:+.4f} mm, continuous "
                    f"{cont * 1e3:+.4f} mm (texel centres {p.delta_truth * 1e3:+.4f}), error "
                    f"{err / p.texel:+.3f} texel, allowed {allowed / p.texel:.3f} texel")
            print("  " + line)
            if abs(err) > allowed:
                failures.append(line)
    assert rows, f"{group}: no patch compared"
    worst = max(rows, key=lambda x: x[0])
    print(f"{group} sampling: {len(rows)} patches, {cast} columns cast in {time.perf_counter() - t0:.1f} s; worst "
          f"|delta_hrt - delta_continuous| {worst[0]:.3f} texel ({abs(worst[1]) * 1e3:.4f} mm, allowed "
          f"{worst[2] / worst[3].texel:.3f} texel) at {worst[3].scene} N={worst[3].N}")
    assert not failures, f"{group}: {len(failures)} of {len(rows)} patches beyond bound + s cell / sqrt 2:\n" + "\n".join(failures[:8])
