"""The GL backend against the CPU backend through the real chain.

Meshes are baked by ``hbake bake`` (tests/fullsurface.py: the angled grating at 23
degrees whose coarse mesh follows its ridges only in part, the bumpy sphere on the
textured plate, and shared models at random rotations on the plate and the box), then
``hrt query --json`` runs each scene with ``--backend cpu``, ``--backend gl`` (compute
reduction) and ``--backend gl --gl-search occlusion``. Collision and clustering run on the
CPU in all three, so the contacts are the same patches; their depths must agree.

Bounds, fixed before comparing (docs/gl-backend.md; runtime/tests/test_gl_depth.cpp
states the same ones):

* compute reduction: the shaders repeat the CPU's arithmetic, so a height differs by
  float32 rounding of the atlas lookup at most: 4 float ulps of the largest atlas
  position |p|max per height, 8 x 2^-24 x (|p|max_A + |p|max_B) for delta.
* occlusion search: delta is the midpoint of an interval one depth quantum wide
  (``gl.depth_quantum`` per contact, 2 R / 2^steps): within the quantum plus the
  bound above.
* the gradient by central differences over +-step (Eq. 7): each component within
  2 x (delta bound) / (2 step) = bound / step (step = the grid cell for u, v; the
  default angle step cell / R_corner for the rotations, computed from the window and
  c_A of the JSON); the force -k delta grad within k (|delta| |d grad| + |grad| |d delta|),
  element by element, absolute (a relative tolerance on a force near zero means
  nothing).

Coverage: the two backends decide coverage by one rule (the CPU's, in the fragment
shader), so ``covered`` must agree too.
"""
from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest

import fullsurface as FS
import thinfeatures as TF

HEIGHT_ULPS = 8.0
EPS32 = 2.0 ** -24


def atlas_radius(model) -> float:
    """|p|max: the largest atlas position (covered texels), object frame."""
    from hbake.bundle import read_bundle

    a = read_bundle(model.bundle, verify=False).atlas
    cov = a[..., 3] > 0
    return float(np.linalg.norm(a[..., :3][cov], axis=1).max())


def query(hrt, a, b, sc, N, *backend):
    cmd = [hrt, "query", str(a.bundle), str(b.bundle), "--pose-a", *map(repr, map(float, sc.pose_a)),
           "--pose-b", *map(repr, map(float, sc.pose_b)), "--resolution", str(N), "--json", *backend]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, f"{' '.join(cmd)}: exit {res.returncode}: {res.stderr}"
    return json.loads(res.stdout)


def ang_step(c: dict, c_a) -> float:
    """default_ang_step (depth.h): cell / the largest distance from c_A to the window's corners."""
    w = c["window"]
    o, u, v = np.array(w["origin"]), np.array(c["u"]), np.array(c["v"])
    L = w["cell"] * w["resolution"]
    R = max(np.linalg.norm(o + i * L * u + j * L * v - c_a) for i in (0, 1) for j in (0, 1))
    return w["cell"] / R


def compare(cpu: dict, gl: dict, delta_bound, stiffness, label) -> tuple[int, float, list]:
    """Contacts of two query outputs: coverage equal, delta within delta_bound(k), the
    gradient and the wrench within the bounds derived from it."""
    fails = []
    cc, cg = cpu["contacts"], gl["contacts"]
    if len(cc) != len(cg):
        return 0, 0.0, [f"{label}: {len(cc)} contacts on cpu, {len(cg)} on gl"]
    c_a = np.array(cpu["objects"][0]["center_of_mass"])
    compared, worst = 0, 0.0
    for k, (a, b) in enumerate(zip(cc, cg)):
        where = f"{label} contact {k}"
        if a["n"] != b["n"] or a["tris_a"] != b["tris_a"] or a["tris_b"] != b["tris_b"]:
            fails.append(f"{where}: not the same patch")
            continue
        if a["covered"] != b["covered"]:
            fails.append(f"{where}: covered cpu {a['covered']} gl {b['covered']}")
            continue
        if not a["covered"]:
            continue
        compared += 1
        bd = delta_bound(k)
        e = abs(a["delta"] - b["delta"])
        worst = max(worst, e / bd)
        if e > bd:
            fails.append(f"{where}: delta cpu {a['delta']!r} gl {b['delta']!r} (|d| {e:.3g} > {bd:.3g})")
        cell = a["window"]["cell"]
        steps = [cell, cell, math.inf, *[ang_step(a, c_a)] * 3]
        dgrad = [bd / s for s in steps]
        for i in range(6):
            if abs(a["grad"][i] - b["grad"][i]) > dgrad[i]:
                fails.append(f"{where}: grad[{i}] cpu {a['grad'][i]!r} gl {b['grad'][i]!r} (> {dgrad[i]:.3g})")
        if a["refused"] != b["refused"] or a["clamped"] != b["clamped"]:
            fails.append(f"{where}: safety decisions differ (refused {a['refused']}/{b['refused']}, "
                         f"clamped {a['clamped']}/{b['clamped']})")
            continue
        if a["refused"]:
            continue
        d = max(a["delta_force"], 0.0)
        g = np.array(a["grad"])
        # force = -k d (g_u u + g_v v + g_n n): per world component at most
        # k (d |d g| + |g| |d delta|) summed over the three axes (|u_i|, |v_i|, |n_i| <= 1).
        f_tol = stiffness * (d * sum(dgrad[:2]) + np.abs(g[:3]).sum() * bd)
        t_tol = stiffness * (d * sum(dgrad[3:]) + np.abs(g[3:]).sum() * bd)
        for name, tol in (("force", f_tol), ("torque", t_tol)):
            diff = np.abs(np.array(a[name]) - np.array(b[name])).max()
            if diff > tol:
                fails.append(f"{where}: {name} cpu {a[name]} gl {b[name]} (max |d| {diff:.3g} > {tol:.3g})")
    return compared, worst, fails


def scenes(models):
    out = [(sc, N) for sc in FS.grating_scenes() for N in (50, 128)]
    out += [(sc, 50) for sc in FS.sphere_scenes(models, count=4)]
    if FS.shared_present():
        names = [n.split(".")[0] for n in FS.SHARED]
        out += [(sc, 50) for sc in FS.model_scenes(models, names, random_poses=1, thin_poses=0)]
    return out


def test_gl_backends_equal_cpu_on_baked_models(hrt, models):
    radius = {name: atlas_radius(m) for name, m in models.items()}
    totals = {"compute": [0, 0.0], "occlusion": [0, 0.0]}
    fails = []
    in_contact = 0
    for sc, N in scenes(models):
        a, b = models[sc.a], models[sc.b]
        hb = HEIGHT_ULPS * EPS32 * (radius[sc.a] + radius[sc.b])
        cpu = query(hrt, a, b, sc, N, "--backend", "cpu")
        k = cpu["options"]["stiffness"]
        in_contact += sum(1 for c in cpu["contacts"] if c["covered"] and c["delta"] > 0)
        gl = query(hrt, a, b, sc, N, "--backend", "gl")
        assert gl["options"]["backend"] == "gl" and gl["gl"]["round_trips"] <= 1
        n, w, f = compare(cpu, gl, lambda _k: hb, k, f"{sc.name} N={N} compute")
        totals["compute"][0] += n
        totals["compute"][1] = max(totals["compute"][1], w)
        fails += f
        occ = query(hrt, a, b, sc, N, "--backend", "gl", "--gl-search", "occlusion")
        q = occ["gl"]["depth_quantum"]
        assert len(q) == len(occ["contacts"]) and all(x > 0 for x in q)
        n, w, f = compare(cpu, occ, lambda kk: q[kk] + hb, k, f"{sc.name} N={N} occlusion")
        totals["occlusion"][0] += n
        totals["occlusion"][1] = max(totals["occlusion"][1], w)
        fails += f
    for mode, (n, w) in totals.items():
        print(f"{mode}: {n} covered patches compared, worst |gl - cpu| / bound = {w:.3g}")
    print(f"{in_contact} of the CPU's patches in contact (delta > 0)")
    assert in_contact >= 20, "the scenes must be in contact"
    assert totals["compute"][0] >= 20 and totals["occlusion"][0] >= 20
    assert not fails, f"{len(fails)} disagreements:\n" + "\n".join(fails[:20])


@pytest.fixture(scope="module")
def thin(tmp_path_factory):
    """The thin-feature models of tests/integration/test_thin_features.py, from the same bake cache."""
    return TF.bake_models(tmp_path_factory)


def test_gl_mesh_heights_equal_cpu_on_thin_features(hrt, thin):
    """--heights mesh on both backends (the GL one draws a point per atlas quad): the pins
    block and the armadillo pressed tip first into the box and the textured plate, the pins
    at N = 50 and 128, the armadillo at 50; same bounds as above."""
    radius = {name: atlas_radius(m) for name, m in thin.items()}
    compared, worst, fails, in_contact = 0, 0.0, [], 0
    for shape, seed in (("pins", 3), ("armadillo", 4)):
        for cs in TF.tip_first_cases(thin, shape, 2, seed):
            a, b = thin[cs.a], thin[cs.b]
            hb = HEIGHT_ULPS * EPS32 * (radius[cs.a] + radius[cs.b])
            for N in (50, 128) if shape == "pins" else (50,):
                cpu = query(hrt, a, b, cs, N, "--backend", "cpu", "--heights", "mesh")
                gl = query(hrt, a, b, cs, N, "--backend", "gl", "--heights", "mesh")
                assert gl["options"]["backend"] == "gl" and gl["options"]["heights"] == "mesh"
                if gl["contacts"]:  # drawn by the mesh program, not the face raster
                    assert gl["gl"]["mesh_quads"] > 0, gl["gl"]
                in_contact += sum(1 for c in cpu["contacts"] if c["covered"] and c["delta"] > 0)
                n, w, f = compare(cpu, gl, lambda _k: hb, cpu["options"]["stiffness"], f"{cs.name} N={N} mesh")
                compared += n
                worst = max(worst, w)
                fails += f
    print(f"mesh heights: {compared} covered patches compared, worst |gl - cpu| / bound = {worst:.3g}, "
          f"{in_contact} in contact")
    assert in_contact >= 5, "the scenes must be in contact"
    assert not fails, f"{len(fails)} disagreements:\n" + "\n".join(fails[:20])
