"""Thin features through the real chain: ``hbake bake``, then ``hrt query --heights mesh``.

The shapes (tests/thinfeatures.py): a block with pins and fins at angles that are not
multiples of 45 degrees, and the armadillo of ../shared/models (ears, fingers, toes),
each pressed tip first on the plain box and on the textured plate at seeded random
orientations, N = 50 and 128. The truth is Eq. 2 on the full meshes over each grid
texel's footprint (rays finer than the grid); the bound of each patch is computed from
the geometry before comparing (thinfeatures.footprint_truth).

Fixed in advance (the thin-feature targets; "texel" is the pair's coarser atlas texel,
max(t_A, t_B), since delta's error is the sum of both reconstructions' errors, each of
its own texel's order):
* no missed contact: a patch whose truth exceeds 2 atlas texels is covered and its
  delta is within 2 texels of the truth;
* at most 2 % of the patches off by more than one texel, the worst within 3 texels;
* every patch within its own bound.
Left out, each counted and listed: patches the runtime refused (its safety rules) where
the truth overlaps beyond the bound (a refused patch between bodies apart along its n
gives no force, rightly, and is not counted), and wrong-way ones (truth along n beyond 5 mm: n goes through the bodies), at most 5 %.

A pass-through test lowers a pin into the box in 20 um steps to 2 mm deep: delta >=
truth - bound at every step, and delta > 0 wherever the truth exceeds the bound.
The fast subset runs always; the 20-orientation sweep is behind the slow marker.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

import fullsurface as FS
import thinfeatures as TF

HRT = str(FS.REPO / "build" / "runtime" / "hrt")
MAX_LEFT_OUT = 0.05


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    t0 = time.perf_counter()
    out = TF.bake_models(tmp_path_factory)
    print(f"\nthin-feature bakes: {time.perf_counter() - t0:.1f} s; atlas texels "
          + ", ".join(f"{n} {m.texel * 1e6:.1f} um" for n, m in out.items()))
    return out


def evaluate(models, cases, Ns=(50, 128), heights="mesh"):
    """(kept, left_out): per patch (case, N, delta, truth, err, bound, texel) in metres."""
    kept, left = [], []
    for cs in cases:
        a, b = models[cs.a], models[cs.b]
        for N in Ns:
            q = FS.hrt_query(HRT, a, b, cs.pose_a, cs.pose_b, N, heights=heights)
            for c in q["contacts"]:
                fp = TF.footprint_truth(c, a, b, cs.pose_a, cs.pose_b)
                if c.get("refused"):
                    # Refused (no force): right when the truth has no overlap along this
                    # n beyond the bound (a patch between bodies apart along it).
                    if not (fp.delta > fp.bound):
                        continue
                    left.append((cs.name, N, f"refused by the runtime's safety rules, truth "
                                 f"{fp.delta * 1e3:+.3f} mm"))
                    continue
                if fp.delta_raw_far:
                    left.append((cs.name, N, "wrong-way: the truth along n exceeds 5 mm"))
                    continue
                if not math.isfinite(fp.delta):
                    if c["covered"] and c["delta"] > fp.bound:
                        kept.append((cs.name, N, c["delta"], -math.inf, math.inf, fp.bound, fp.texel))
                    continue  # nothing covered by both in the truth: no contact to compare
                d = c["delta"] if c["covered"] else -math.inf
                kept.append((cs.name, N, d, fp.delta, d - fp.delta, fp.bound, fp.texel))
    return kept, left


def check_tail(kept, left, label):
    n = len(kept) + len(left)
    assert n > 0, "no patches"
    errs = np.array([abs(k[4]) / k[6] for k in kept])
    missed = [k for k in kept if k[3] > 2 * k[6] and not (k[2] >= k[3] - 2 * k[6])]
    beyond_bound = [k for k in kept if not (abs(k[4]) <= k[5])]
    over1 = float(np.mean(errs > 1.0)) if len(errs) else 0.0
    signed = np.array([k[4] / k[6] for k in kept if math.isfinite(k[4])])
    print(f"\n{label}: {len(kept)} patches compared, {len(left)} left out of {n}; error in atlas texels: "
          f"median {np.median(signed):+.3f}, p95 |err| {np.percentile(np.abs(signed), 95):.3f}, "
          f"worst {np.max(np.abs(signed)):.3f}; > 1 texel {over1:.1%}; missed contacts {len(missed)}")
    for item in left:
        print("  left out:", *item)
    assert len(left) <= MAX_LEFT_OUT * n, f"{len(left)} of {n} patches left out"
    assert not missed, f"missed contacts (truth > 2 texels): {missed[:5]}"
    assert over1 <= 0.02, f"{over1:.1%} of the patches off by more than one texel"
    assert np.max(errs) <= 3.0, f"worst {np.max(errs):.2f} texels"
    assert not beyond_bound, f"{len(beyond_bound)} patches beyond their bound: {beyond_bound[:5]}"


@pytest.mark.parametrize("shape,count,seed", [("pins", 4, 3), ("armadillo", 4, 4)])
def test_thin_features_within_the_bound(models, shape, count, seed):
    cases = TF.tip_first_cases(models, shape, count, seed)
    kept, left = evaluate(models, cases)
    check_tail(kept, left, f"{shape}, {count} orientations, N = 50 and 128, heights = mesh")


@pytest.mark.slow
@pytest.mark.parametrize("shape,seed", [("pins", 13), ("armadillo", 14)])
def test_thin_features_sweep_20_orientations(models, shape, seed):
    cases = TF.tip_first_cases(models, shape, 20, seed)
    kept, left = evaluate(models, cases)
    check_tail(kept, left, f"{shape}, 20 orientations, N = 50 and 128, heights = mesh")


def test_a_pin_lowered_into_the_box_never_passes_through(models):
    """A pin (tilted 23 degrees from the block's normal) tip first into the plain box,
    from 0.1 mm above to 2 mm deep in 20 um steps."""
    worst = lowered(models, 1, "box")
    # The pin's flat cap meets the box's flat top face to face (its axis along -z): the
    # shortfall is float rounding (the float32 atlas, ~1e-8 m here) and the cap's flat
    # triangles: 1 um covers both with margin.
    assert worst <= 1e-6, f"largest shortfall {worst * 1e6:.2f} um"


@pytest.mark.slow
@pytest.mark.parametrize("tip", (
    3,
    pytest.param(5, marks=pytest.mark.xfail(strict=True, reason=(
        "open: 1.88-1.98 mm deep a second patch appears with n 66 degrees off vertical "
        "(0.917, 0.007, -0.398) and reads 2.27 mm against 3.78 mm of footprint truth along "
        "that n (bound 1.42 mm); the patches along the vertical read within 0.01 mm. Cause: "
        "the patch's height fields hold only its own pieces' faces, the truth crosses the "
        "plate's neighbouring pieces (with every piece in reach it reads 3.89 mm and is "
        "refused: beyond its pieces' bound, 3.78 mm)"))),
    6,
))
def test_pins_and_fins_lowered_into_the_textured_plate_never_pass_through(models, tip):
    """The 61-degree pin and two fins, tip first into the textured plate, 0.1 mm above to
    2 mm deep in 20 um steps: delta >= truth - bound at every step, a contact wherever
    the truth exceeds the bound."""
    lowered(models, tip, "plate")


def lowered(models, tip_index: int, plate: str) -> float:
    """Lowers tip ``tip_index`` of the pins block into ``plate``; asserts the pass-through
    rules and returns the largest shortfall (truth - delta, m)."""
    pins, box = models["pins"], models[plate]
    tip = TF.pins_tips()[tip_index]
    from scipy.spatial.transform import Rotation
    r0, _ = Rotation.align_vectors([[0, 0, -1.0]], [tip])
    R = (Rotation.from_euler("z", 0.37) * r0).as_matrix()
    if plate == "box":
        centre = (FS.BOX_SIZE[0] / 2, FS.BOX_SIZE[1] / 2)
    else:
        centre = (FS.PLATE_SIDE / 2 + 0.7e-3, FS.PLATE_SIDE / 2 + 0.3e-3)
    t = FS._rest_on(pins.mesh, R, box, FS.IDENTITY, centre, -0.1e-3)   # 0.1 mm above
    pose = [*t.tolist(), *FS._quat_from_matrix(R)]
    steps = np.arange(0, 2.1e-3 + 1e-9, 20e-6)
    offsets = [np.array([0.0, 0.0, -s]) for s in steps]
    per = FS.path_query(HRT, pins, box, pose, FS.IDENTITY, offsets, N=50, heights="mesh")
    worst, fails = -math.inf, []
    for s, d, contacts in zip(steps, offsets, per):
        pose_k = FS._translate(pose, d)
        truth, reported, bound = -math.inf, -math.inf, 0.0
        for c in contacts:
            if c.get("refused"):
                continue
            fp = TF.footprint_truth(c, pins, box, pose_k, FS.IDENTITY, sub=3)
            if fp.delta_raw_far:
                continue
            truth = max(truth, fp.delta)
            bound = max(bound, fp.bound)
            if c["covered"]:
                reported = max(reported, c["delta"])
        if truth > -math.inf:
            worst = max(worst, truth - reported)
        if truth > -math.inf and not (reported >= truth - bound):
            fails.append((round(s * 1e3, 3), reported, truth, bound))
        if truth > bound and not (reported > 0):
            fails.append((round(s * 1e3, 3), reported, truth, bound, "no contact"))
    print(f"\ntip {tip_index} into the {plate}, {len(steps)} steps to 2 mm: largest shortfall {worst * 1e6:.1f} um")
    assert not fails, fails[:5]
    return worst


def test_a_pin_tip_slid_over_the_box_keeps_its_depth(models):
    """A pin (37 degrees from the block's normal) pressed 0.1 mm into the plain box's flat
    top, then slid sideways in steps of 1/200 grid texel (0.06 of the pin's atlas texel)
    over 0.3 texel: over a flat top the overlap cannot change (closed form: the press,
    0.1 mm, at every step), so a change between steps is a sample dropping in or out.
    Bounds: 0.1 um per step (float rounding of the heights, ~1e-8 m here, with margin)
    and 1 um against the press (the same, plus the cap's flat triangles in float32)."""
    pins, box = models["pins"], models["box"]
    from scipy.spatial.transform import Rotation
    r0, _ = Rotation.align_vectors([[0, 0, -1.0]], [TF.pins_tips()[2]])
    R = (Rotation.from_euler("z", 0.37) * r0).as_matrix()
    press = 0.1e-3
    t = FS._rest_on(pins.mesh, R, box, FS.IDENTITY, (FS.BOX_SIZE[0] / 2, FS.BOX_SIZE[1] / 2), press)
    pose = [*t.tolist(), *FS._quat_from_matrix(R)]
    cell = FS.hrt_query(HRT, pins, box, pose, FS.IDENTITY, 50, heights="mesh")["contacts"][0]["window"]["cell"]
    d = np.array([math.cos(0.3), math.sin(0.3), 0.0])
    offsets = [d * (k * cell / 200) for k in range(60)]
    out = {}
    # (The default surface mode, same path: 0.0911-0.1000 mm, up to 4.0 um per 2.44 um
    # step, as the cap's rim crosses texel centres; not run here.)
    for mode in ("mesh",):
        per = FS.path_query(HRT, pins, box, pose, FS.IDENTITY, offsets, N=50, heights=mode)
        out[mode] = np.array([max([c["delta"] for c in p if c["covered"] and not c.get("refused")] or [np.nan])
                              for p in per])
        ds = out[mode]
        print(f"\n{mode}: delta {np.nanmin(ds) * 1e3:.4f}..{np.nanmax(ds) * 1e3:.4f} mm over {len(ds)} steps of "
              f"{cell / 200 * 1e6:.2f} um; largest change per step {np.nanmax(np.abs(np.diff(ds))) * 1e6:.3f} um")
    ds = out["mesh"]
    assert np.all(np.isfinite(ds)), "the contact was lost on the way"
    assert np.max(np.abs(np.diff(ds))) <= 1e-7
    assert np.max(np.abs(ds - press)) <= 1e-6


# Paths over the textured plate (its sine: slope 2 pi a / lambda at most; the baked full
# mesh is its chords, no steeper) for the continuity test: (tip index of
# thinfeatures.pins_tips(), direction of travel in radians, start offset in grid texels).
CONTINUITY_PATHS = ((1, 0.9, 0.0), (3, 2.1, 0.37), (5, 0.4, 0.61), (6, 1.3, 0.83))


def continuity_path(models, tip: int, heading: float, start: float, N: int, steps: int):
    """A pin's or fin's tip pressed 0.1 mm into the textured plate, then moved in steps of
    1e-3 of the pins' atlas texel. Returns (deltas, step, cell)."""
    pins, plate = models["pins"], models["plate"]
    from scipy.spatial.transform import Rotation
    r0, _ = Rotation.align_vectors([[0, 0, -1.0]], [TF.pins_tips()[tip]])
    R = (Rotation.from_euler("z", 0.37) * r0).as_matrix()
    centre = (FS.PLATE_SIDE / 2 + 0.7e-3, FS.PLATE_SIDE / 2 + 0.3e-3)
    t = FS._rest_on(pins.mesh, R, plate, FS.IDENTITY, centre, 0.1e-3)
    pose = [*t.tolist(), *FS._quat_from_matrix(R)]
    first = FS.hrt_query(HRT, pins, plate, pose, FS.IDENTITY, N, heights="mesh")["contacts"]
    cell = max(c["window"]["cell"] for c in first)
    d = np.array([math.cos(heading), math.sin(heading), 0.0])
    step = 1e-3 * pins.texel
    offsets = [d * (start * cell + k * step) for k in range(steps)]
    per = FS.path_query(HRT, pins, plate, pose, FS.IDENTITY, offsets, N=N, heights="mesh")
    ds = np.array([max([c["delta"] for c in p if c["covered"] and not c.get("refused")] or [np.nan]) for p in per])
    cells = {c["window"]["cell"] for p in per for c in p}
    return ds, step, max(cells)


def check_continuity(ds, step, cell, label):
    """Bound per step, fixed from the geometry: the tips' contact faces (pin caps, fin
    tops) lie parallel to the plate here, so a texel's highest point of A moves with A
    and the plate's slope s_B changes B's lowest over a texel's square by at most s_B
    per unit of motion: step * s_B. A sliver of A entering a new square pairs A's height
    with that square's lowest point of B, which differs from a neighbouring square's by
    at most s_B times two squares' diagonal: 2 sqrt(2) cell s_B. Float rounding of the
    heights: 1e-9 m."""
    s_b = 2 * math.pi * FS.PLATE_A / FS.PLATE_L
    bound = step * s_b + 2 * math.sqrt(2) * cell * s_b + 1e-9
    assert np.all(np.isfinite(ds)), f"{label}: the contact was lost on the way"
    jumps = np.abs(np.diff(ds))
    print(f"\n{label}: delta {ds.min() * 1e6:.2f}..{ds.max() * 1e6:.2f} um over {len(ds)} steps of "
          f"{step * 1e9:.1f} nm; largest change per step {jumps.max() * 1e9:.2f} nm (bound {bound * 1e9:.0f} nm, "
          f"grid texel {cell * 1e6:.0f} um)")
    assert jumps.max() <= bound, f"{label}: a step changed delta by {jumps.max() * 1e9:.1f} nm > {bound * 1e9:.1f} nm"


def test_a_pin_tip_moved_over_the_textured_plate_is_continuous(models):
    """One path of the continuity test in `make test`; the four paths at N = 50 and 128
    are in the slow sweep below."""
    tip, heading, start = CONTINUITY_PATHS[0]
    ds, step, cell = continuity_path(models, tip, heading, start, 50, 100)
    check_continuity(ds, step, cell, f"tip {tip}, N = 50")


@pytest.mark.slow
@pytest.mark.parametrize("N", (50, 128))
@pytest.mark.parametrize("path", CONTINUITY_PATHS, ids=lambda p: f"tip{p[0]}")
def test_tips_and_fins_moved_over_the_textured_plate_are_continuous(models, path, N):
    tip, heading, start = path
    ds, step, cell = continuity_path(models, tip, heading, start, N, 300)
    check_continuity(ds, step, cell, f"tip {tip}, N = {N}")


def test_mesh_heights_give_every_configuration_and_a_tangential_gradient(models):
    """Eq. 7 with the mesh heights through the real chain: every configuration of every
    patch is covered (the four whole-texel translations are shifts of configuration 0;
    they were once left unevaluated, 4 uncovered per patch and g_u = g_v = 0), and the
    pins pressed into the textured plate get a tangential gradient. (The gradient's value
    against A moved and evaluated from scratch: runtime/tests/test_depth_analytic.cpp.)"""
    contacts = 0
    tangential = 0
    for cs in TF.tip_first_cases(models, "pins", 4, 3):
        q = FS.hrt_query(HRT, models[cs.a], models[cs.b], cs.pose_a, cs.pose_b, 50, heights="mesh")
        assert q["warnings"]["uncovered_configurations"] == 0, (cs.name, q["warnings"])
        for c in q["contacts"]:
            if c["covered"] and c["delta"] > 0:
                contacts += 1
                tangential += cs.b == "plate" and abs(c["grad"][0]) + abs(c["grad"][1]) > 1e-3
    assert contacts >= 3
    assert tangential >= 1


def test_validate_and_check_count_the_same_cut_quads(models):
    """Where the mesh heights' guarantee stops (docs/bundle-format.md): `hbake validate`
    (numpy, from the spec) and `hrt check` (the runtime's surface map) count the same atlas
    quads inside the UV triangles, the same cut ones and the same widest cut, on the
    thin-featured bakes (both have cuts) and a plain one; the text output notes them."""
    import json
    import subprocess
    import sys
    seen_cut = 0
    for name in ("pins", "armadillo", "box"):
        bundle = str(models[name].bundle)
        v = subprocess.run([sys.executable, "-m", "hbake.cli", "validate", bundle, "--json"],
                           capture_output=True, text=True, timeout=600)
        assert v.returncode == 0, v.stderr
        c = subprocess.run([HRT, "check", bundle, "--json"], capture_output=True, text=True, timeout=600)
        assert c.returncode == 0, c.stderr
        mine, theirs = json.loads(v.stdout)["surface"], json.loads(c.stdout)["surface"]
        print(f"{name}: {mine}")
        assert mine == theirs
        # The batching that bounds its memory changes nothing: tiny batches, same counts.
        import hbake.bundle.surface_coverage as SC
        from hbake.bundle import read_bundle
        saved = SC._CANDIDATES, SC._ROWS
        try:
            SC._CANDIDATES, SC._ROWS = 997, 7
            assert SC.surface_coverage(read_bundle(bundle, verify=False)) == theirs
        finally:
            SC._CANDIDATES, SC._ROWS = saved
        assert mine["quads"] > 0
        seen_cut += mine["cut_quads"] > 0
        text = subprocess.run([sys.executable, "-m", "hbake.cli", "validate", bundle],
                              capture_output=True, text=True, timeout=600).stdout.splitlines()
        assert text[0] == f"{bundle}: OK"
        assert (len(text) == 2 and text[1].startswith(f"{bundle}: note: surface: ")) == (mine["cut_quads"] > 0)
    assert seen_cut >= 2, "the thin-featured bakes were expected to have cut quads"


def test_thin_feature_queries_are_the_same_on_one_and_two_threads(models):
    """The pool (`--threads`) through the real chain on thin features: pins and armadillo
    tips pressed into the box and the textured plate, in the mesh and surface modes, give
    the same `hrt query --json` digit for digit on one thread and on two (all but the
    wall-clock timings and the thread count itself)."""
    compared = multi = 0
    for name in ("pins", "armadillo"):
        for cs in TF.tip_first_cases(models, name, 2, 21):
            a, b = models[cs.a], models[cs.b]
            for heights in ("mesh", "surface"):
                q = [FS.hrt_query(HRT, a, b, cs.pose_a, cs.pose_b, 50, heights=heights, threads=t) for t in (1, 2)]
                for r in q:
                    r.pop("timings_us")
                    assert r["options"].pop("threads") in (1, 2)
                assert q[0] == q[1], (name, heights)
                compared += 1
                multi += len(q[0]["contacts"]) > 1
    print(f"{compared} queries compared, {multi} with several patches")
    assert multi >= 1, "no query had patches to share between the threads"
