"""Continuity of delta along slow paths, and Fig. 7 on baked bundles.

The bundles are those of tests/integration/test_fullsurface_depth.py (fullsurface.py bakes them
once per process; FULLSURFACE_CACHE=DIR keeps them across runs). A path of A relative
to B is one `hrt query` holding a copy of B per pose (fullsurface.path_query: the
runtime's lattice and u are fixed to B, so a frame depends on the relative pose only;
test_path_query_is_a_motion_of_a checks that against queries that move A).

Continuity: along a slow path (steps of 1e-3 of A's atlas texel, in the contact plane),
|change of delta| <= s |step| + 1e-7 m at every step, except at counted events (a change
of the window's lattice, cell or resolution; of n beyond N_EVENT_RAD; of the triangle
lists or of covered; of the piece pairs clustered into the patch; the patch lost),
reported per path. Where n drifts (below N_EVENT_RAD) the texel centres turn with it,
and the bound adds what that drift allows (test_delta_continuous_along_slow_path).

Fig. 7 (paper Sec. 7): A face down on B, off the nested position, slid along the ridges
of the angled gratings: the force along the ridges must vanish. RMS of F . t at most 5 %
of RMS of F . n over the frames with delta > 0.1 of the relief amplitude, at N = 50.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

import fullsurface as FS


#: Step of a path, in A's atlas texels.
STEP_TEXELS = 1e-3
#: The slack of the continuity bound: float32 heights of ~5 cm carry ~4e-9 m
#: of rounding, and the runtime's n drifts with the pose (below).
CONT_ABS = 1e-7
#: (name, scene, direction in the contact plane, steps). The direction is given in the
#: world and projected on the plane of the followed patch's n at the start.
_A = math.radians(FS.GRATING_ANGLE)
ACROSS = (math.cos(_A), math.sin(_A), 0.0)
ALONG = (-math.sin(_A), math.cos(_A), 0.0)
#: `make test` follows one path (the curved coarse mesh of the sphere); the three others
#: (30-50 s each) are behind the slow marker.
_SLOW = pytest.mark.slow
PATHS = (
    pytest.param("gratings_offset0.25L across the ridges", "gratings", 2, ACROSS, 120, marks=_SLOW,
                 id="gratings_offset0.25L across the ridges"),
    pytest.param("gratings_offset0.10L at 60 deg to the ridges", "gratings", 1,
                 (math.cos(_A + math.radians(60)), math.sin(_A + math.radians(60)), 0.0), 120, marks=_SLOW,
                 id="gratings_offset0.10L at 60 deg to the ridges"),
    pytest.param("sphere_on_plate_0 along x", "sphere", 0, (1.0, 0.0, 0.0), 100, id="sphere_on_plate_0 along x"),
    pytest.param("sphere_on_plate_3 along x+y", "sphere", 3, (1.0, 1.0, 0.0), 100, marks=_SLOW,
                 id="sphere_on_plate_3 along x+y"),
)
#: A change of n by more than this between two steps is an event (a jump: the pieces'
#: closest features switch); below it, n drifts with the pose (it comes from the
#: pieces' closest points: about 3e-6 rad per step on the gratings). A turn of n by
#: theta changes the depth along n of two surfaces whose facing points are at most H
#: apart by at most s H theta (the column through B's point meets A H theta aside), and
#: H <= 1 mm here (depth <= 0.35 mm plus both reliefs' peak to peak <= 0.4 + 0.3 mm), so
#: 5e-5 rad gives at most 5e-8 m (half of CONT_ABS) with s <= 1; the lattice's turn is
#: accounted for separately (lattice_drift).
N_EVENT_RAD = 5e-5
H_MAX = 1e-3
#: At most this fraction of a path's steps may be events (else the path checks little).
MAX_EVENT_FRACTION = 0.25

#: Fig. 7: frames, their spacing along the ridges (not a multiple of the window cell or
#: of the mesh's cells), the share of F . n that F . t may reach, the depth threshold.
FIG7_SCENE = 2                 # gratings_offset0.25L: off the nested position
FIG7_FRAMES = 24
FIG7_SPACING = 0.29 * FS.MM
FIG7_RATIO = 0.05
FIG7_MIN_DELTA = 0.1 * FS.GRATING_A
FIG7_N = 50


def _scene(models, group, index):
    return FS.group_scenes(models, group)[index]


def _main_patch(contacts):
    """The patch a path follows: the covered one with the most triangles (the faces in
    contact, not the side pieces that touch within the tolerance)."""
    cov = [c for c in contacts if c["covered"]]
    return max(cov or contacts, key=lambda c: len(c["tris_a"]) + len(c["tris_b"]))


def _follow(prev, contacts):
    """The patch of ``contacts`` that continues ``prev``: the closest n, then p_b."""
    if not contacts:
        return None
    n0, p0, cell = np.asarray(prev["n"]), np.asarray(prev["p_b"]), prev["window"]["cell"]
    best = max(contacts, key=lambda c: float(np.dot(c["n"], n0))
               - float(np.linalg.norm(np.asarray(c["p_b"]) - p0)) / (100 * cell))
    return best if float(np.dot(best["n"], n0)) > math.cos(math.radians(10)) else None


def _lattice(c):
    w = c["window"]
    o, cell = np.asarray(w["origin"]), w["cell"]
    return o @ np.asarray(c["u"]) / cell, o @ np.asarray(c["v"]) / cell


def _corners(c):
    """The window's four corner texel centres (positions in B's frame: B stays put)."""
    w = c["window"]
    o, cell, N = np.asarray(w["origin"]), w["cell"], w["resolution"]
    u, v = np.asarray(c["u"]), np.asarray(c["v"])
    return [o + (i + 0.5) * cell * u + (j + 0.5) * cell * v for i in (0, N - 1) for j in (0, N - 1)]


def lattice_drift(prev, cur):
    """The largest motion, across the column direction n, of a texel centre of the
    window relative to B between two steps (the lattice is fixed to B, but u, v and n
    turn with n): the texel centres are affine in (i, j), so the largest is at a corner."""
    n = np.asarray(cur["n"])
    out = 0.0
    for x0, x1 in zip(_corners(prev), _corners(cur)):
        dx = x1 - x0
        out = max(out, float(np.linalg.norm(dx - (dx @ n) * n)))
    return out


def _angle(n0, n1):
    return math.acos(min(1.0, max(-1.0, float(np.dot(n0, n1)))))


def _events(prev, cur):
    """The events between two steps of a path (names), from the JSON alone."""
    if cur is None:
        return ["lost"]
    ev = []
    wp, wc = prev["window"], cur["window"]
    (iu0, iv0), (iu1, iv1) = _lattice(prev), _lattice(cur)
    if wp["cell"] != wc["cell"] or wp["resolution"] != wc["resolution"] or abs(iu1 - iu0) > 0.5 or abs(iv1 - iv0) > 0.5:
        ev.append("window")
    if _angle(prev["n"], cur["n"]) > N_EVENT_RAD:
        ev.append("n")
    if prev["tris_a"] != cur["tris_a"] or prev["tris_b"] != cur["tris_b"] or prev["covered"] != cur["covered"]:
        ev.append("coverage")
    if prev["piece_pairs"] != cur["piece_pairs"]:
        ev.append("pairs")
    return ev


def _path(hrt, models, group, index, direction, steps):
    sc = _scene(models, group, index)
    a, b = models[sc.a], models[sc.b]
    q0 = FS.hrt_query(hrt, a, b, sc.pose_a, sc.pose_b, 50)
    c0 = _main_patch(q0["contacts"])
    n0 = np.asarray(c0["n"])
    d = np.asarray(direction, float)
    d = d - (d @ n0) * n0
    d /= np.linalg.norm(d)
    step = STEP_TEXELS * a.texel
    offsets = [k * step * d for k in range(steps + 1)]
    frames = FS.path_query(hrt, a, b, sc.pose_a, sc.pose_b, offsets)
    return sc, a, b, c0, step, d, offsets, frames


def test_path_query_is_a_motion_of_a(hrt, models):
    """fullsurface.path_query (copies of B moved by -d) gives the contacts of A moved by
    +d: at three offsets of a grating path (one of 0.1 mm) the followed patch has the
    same window, n and delta as `hrt query` with A moved, to 1e-9 m and 1e-9 rad (the
    rounding of world coordinates of ~1 cm, far below CONT_ABS)."""
    sc = _scene(models, "gratings", 2)
    a, b = models[sc.a], models[sc.b]
    d = np.asarray(ACROSS)
    offsets = [0.0 * d, 7e-3 * a.texel * d, 1e-4 * d]
    frames = FS.path_query(hrt, a, b, sc.pose_a, sc.pose_b, offsets)
    for off, cs in zip(offsets, frames):
        q = FS.hrt_query(hrt, a, b, FS._translate(sc.pose_a, off), sc.pose_b, 50)
        ref = _main_patch(q["contacts"])
        got = _follow(ref, cs)
        assert got is not None
        assert got["window"]["cell"] == ref["window"]["cell"]
        assert got["window"]["resolution"] == ref["window"]["resolution"]
        assert np.allclose(got["window"]["origin"], ref["window"]["origin"], atol=1e-9, rtol=0)
        assert np.allclose(got["n"], ref["n"], atol=1e-9, rtol=0)
        assert abs(got["delta"] - ref["delta"]) <= 1e-9, (got["delta"], ref["delta"])
        assert got["tris_a"] == ref["tris_a"] and got["tris_b"] == ref["tris_b"]


@pytest.mark.parametrize("name,group,index,direction,steps", PATHS)
def test_delta_continuous_along_slow_path(name, group, index, direction, steps, hrt, models):
    """|delta_k - delta_{k-1}| <= s (|step| + l_k) + s H theta_k + CONT_ABS at every
    step that is no event; l_k = theta_k = 0 (the issue's s |step| + 1e-7 m) wherever n
    did not move.

    s = s_A + s_B: the two full surfaces' largest slopes along n over the followed
    patch's window at the start (fullsurface.evaluate_patch, from the full meshes).
    delta is a maximum of h_A - h_B over the texel centres; a step of A in the contact
    plane moves every height of A on a fixed column by at most s_A |step|; the texel
    centres are fixed to B while n stays, and where n turns by theta_k (within
    N_EVENT_RAD) they move across the columns by l_k (lattice_drift, from the two
    windows in the JSON), which moves h_A and h_B by at most s l_k, and the turn itself
    changes the depth by at most s H_MAX theta_k (N_EVENT_RAD)."""
    t0 = time.perf_counter()
    sc, a, b, c0, step, d, offsets, frames = _path(hrt, models, group, index, direction, steps)
    prev = _follow(c0, frames[0])
    assert prev is not None and prev["covered"], f"{name}: the followed patch is not in contact at the start"
    p0 = FS.evaluate_patch(sc.name, 50, prev, a, b, FS._translate(sc.pose_a, offsets[0]), sc.pose_b)
    assert not p0.wrong_way and p0.slope, f"{name}: {p0.line()}"
    s = sum(p0.slope)
    events: dict[str, int] = {}
    failures, checked, drifted = [], 0, 0
    worst, worst_plain, worst_drift, worst_theta = 0.0, 0.0, 0.0, 0.0
    for k in range(1, len(frames)):
        cur = _follow(prev, frames[k])
        ev = _events(prev, cur)
        for e in ev:
            events[e] = events.get(e, 0) + 1
        if cur is None:
            continue
        if not ev:
            change = abs(cur["delta"] - prev["delta"])
            theta = _angle(prev["n"], cur["n"])
            drift = lattice_drift(prev, cur) if theta > 0 else 0.0
            allowed = s * (step + drift) + s * H_MAX * theta + CONT_ABS
            checked += 1
            drifted += theta > 0
            worst = max(worst, change / allowed)
            worst_plain = max(worst_plain, change)
            worst_drift, worst_theta = max(worst_drift, drift), max(worst_theta, theta)
            if change > allowed:
                failures.append(f"step {k}: delta {prev['delta'] * 1e3:.6f} -> {cur['delta'] * 1e3:.6f} mm "
                                f"(|change| {change * 1e9:.1f} nm, allowed {allowed * 1e9:.1f} nm: n turned "
                                f"{theta:.2e} rad, lattice moved {drift * 1e9:.1f} nm)")
        prev = cur
    plain = s * step + CONT_ABS
    print(f"\npath {name}: {steps} steps of {step * 1e9:.1f} nm ({STEP_TEXELS} texel) along "
          f"{np.round(d, 3).tolist()}, delta {c0['delta'] * 1e3:.5f} mm at the start, s {s:.2f}; "
          f"{checked} steps checked ({drifted} with n drifting, up to {worst_theta:.1e} rad, lattice "
          f"{worst_drift * 1e9:.0f} nm), worst |change| {worst_plain * 1e9:.2f} nm (s |step| + 1e-7 m = "
          f"{plain * 1e9:.1f} nm; worst ratio to the allowed {worst:.3f}); events: {events or 'none'} "
          f"({time.perf_counter() - t0:.1f} s)")
    assert not failures, f"{name}: {len(failures)} jumps beyond the allowed change:\n" + "\n".join(failures[:10])
    ev_steps = steps - checked
    assert ev_steps <= MAX_EVENT_FRACTION * steps, f"{name}: {ev_steps} of {steps} steps are events ({events})"


def _truth_depth(c, a, b, pose_a, pose_b):
    """max over the window's columns of h_A - h_B on the full meshes (wrong-way test)."""
    X, n, u, v, _ = FS.window_columns(c)
    ha = FS.surface_columns(a, pose_a, X, n, u, v, True).h
    hb = FS.surface_columns(b, pose_b, X, n, u, v, False).h
    both = np.isfinite(ha) & np.isfinite(hb)
    return float(np.max(ha[both] - hb[both])) if both.any() else -math.inf


def fig7_frames(hrt, models):
    """Fig. 7's frames: per frame, the face patch (the one between the ridged faces:
    the covered patch with the most triangles), its delta, n and force, the force of
    every patch whose n is the right way (the full meshes along it are not through the
    bodies) and the net force; t = the ridge direction projected on the plane of n."""
    sc = _scene(models, "gratings", FIG7_SCENE)
    a, b = models[sc.a], models[sc.b]
    d = np.asarray(ALONG)
    offsets = [(k - FIG7_FRAMES // 2) * FIG7_SPACING * d for k in range(FIG7_FRAMES)]
    frames = FS.path_query(hrt, a, b, sc.pose_a, sc.pose_b, offsets, N=FIG7_N)
    out = []
    for off, cs in zip(offsets, frames):
        pose_a = FS._translate(sc.pose_a, off)
        main = _main_patch(cs)
        n = np.asarray(main["n"])
        t = d - (d @ n) * n
        t /= np.linalg.norm(t)
        right, wrong, rims = np.zeros(3), 0, 0
        for c in cs:
            f = np.asarray(c["force"])
            if not np.any(f):
                continue
            if _truth_depth(c, a, b, pose_a, sc.pose_b) > FS.WRONG_WAY_DEPTH:
                wrong += 1
                continue
            right += f
            rims += c is not main
        net = np.sum([c["force"] for c in cs], axis=0)
        out.append({"delta": main["delta"], "n": n, "t": t, "face": np.asarray(main["force"]), "right": right,
                    "net": net, "wrong": wrong, "rims": rims})
    return out


def fig7_ratio(frames, key):
    sel = [f for f in frames if f["delta"] > FIG7_MIN_DELTA]
    ft = np.array([f[key] @ f["t"] for f in sel])
    fn = np.array([f[key] @ f["n"] for f in sel])
    return len(sel), float(np.sqrt(np.mean(ft ** 2))), float(np.sqrt(np.mean(fn ** 2)))


def test_fig7_no_force_along_the_ridges(hrt, models):
    """Fig. 7 on the baked gratings: RMS of F . t <= 5 % of RMS of F . n, both
    for F the texture force between the ridged faces (the face patch) and for F the net
    force on A (every patch: what the hand feels, rim and wrong-way patches included).
    Also printed: F summed over the patches whose n is the right way (the full meshes
    along it do not run through the bodies), and how many rim and wrong-way patches gave
    force (before runtime 32ab9b5, rim patches between A's side pieces and B's ridges
    gave several N each where the faces give 0.1 N)."""
    t0 = time.perf_counter()
    frames = fig7_frames(hrt, models)
    k, ft, fn = fig7_ratio(frames, "face")
    _, rt, rn = fig7_ratio(frames, "right")
    _, nt, nn = fig7_ratio(frames, "net")
    print(f"\nFig. 7 (gratings_offset0.25L slid along the ridges, N = {FIG7_N}, {FIG7_FRAMES} frames "
          f"{FIG7_SPACING * 1e3:.2f} mm apart, {k} with delta > {FIG7_MIN_DELTA * 1e3:.3f} mm): face patch RMS F.t "
          f"{ft:.4g} N, RMS F.n {fn:.4g} N, ratio {ft / fn:.4f} (at most {FIG7_RATIO}); every right-way patch: "
          f"ratio {rt / rn:.4f} ({sum(f['rims'] for f in frames)} rim patches with force); net force: ratio "
          f"{nt / nn if nn else math.inf:.4f} ({sum(f['wrong'] for f in frames)} wrong-way patches with force) "
          f"({time.perf_counter() - t0:.1f} s)")
    for f in frames:
        print(f"  delta {f['delta'] * 1e3:+.4f} mm  face F.n {f['face'] @ f['n']:+.5f} N F.t {f['face'] @ f['t']:+.6f} N"
              f"  right-way F.t {f['right'] @ f['t']:+.5f} N  net F.t {f['net'] @ f['t']:+.5f} N")
    assert k >= FIG7_FRAMES // 2, f"only {k} of {FIG7_FRAMES} frames deeper than {FIG7_MIN_DELTA} m"
    assert ft <= FIG7_RATIO * fn, f"face patch: RMS F.t {ft} > {FIG7_RATIO} x RMS F.n {fn}"
    assert nt <= FIG7_RATIO * nn, f"net force: RMS F.t {nt} > {FIG7_RATIO} x RMS F.n {nn}"
