"""A probe driven deep into an object keeps a force that pushes it out (src/contact/frame.cpp,
"Deep fallback"), through the real chain: bundles baked by `hbake bake` (tests/sessions.py:
the "block", 12 x 8 x 4 mm, the "tip", a sphere of radius 4 mm, the "slab", 160 x 60 x 6 mm,
each centred on its origin, so the slab's top is z = 3 mm), scenes run by `hrt run --lockstep`,
and their traces read back (docs/trace-format.md).

1. A scripted jump: the device holds the probe at the slab (0.05 mm clear of it, or resting
   on it), then at t = 0.1 s jumps 10 mm into it in one step (two samples 1 ms apart), and the
   coupling drags the probe after it. 10 mm is more than the slab is thick: the block's
   resting depth under that pull (6.67 mm, below) is past the middle of the slab, where its
   pieces' shortest way apart, and so the texture force, turns downwards (before the fallback
   the block fell through the slab, or was held pushed downwards against the coupling, and
   the tip was pushed out through the bottom). In every frame that starts with the probe in
   the slab the contact force is upwards, never zero; the probe never gets deeper than the
   jump frame's own plunge, and it settles at the depth the two springs share.
2. A start 10 mm deep, inside a 30 mm thick box of the slab's footprint whose top is also
   z = 3 mm (10 mm inside the 6 mm slab would be past its middle: its nearest way out is
   through the bottom, and with no motion to tell where the probe came from, that is where
   it goes): pushed out, its z increases over the first 0.2 s and it ends where the springs
   (or the surface) put it.

Every bound is fixed from the scene's numbers before the run; the figures printed are for
the reader.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

import fullsurface as FS
import sessions as S
import trace as T
from hbake.lab import procedural as P
from sessioncli import RES, SLAB_TOP, hrt_run, objects, write_scene

MM = 1e-3
H = 1e-3                    # s: the scripted device's period and the simulation's frame (lockstep, 1 kHz)
K_CONTACT = 1000.0          # N/m: [force] stiffness, the default
K_COUPLING = 2000.0         # N/m: the coupling's k_lin = the device's max_stiffness, the default
DENSITY = 1000.0            # kg/m^3: the session's default
JUMP = 10 * MM
T_JUMP = 0.1
HALF = {"block": S.BLOCK[2] / 2, "tip": S.TIP_R}   # half height of each probe
SLAB_BOTTOM = -SLAB_TOP
DEEP_BOX = (160 * MM, 60 * MM, 30 * MM)
DEEP_BOX_Z = SLAB_TOP - DEEP_BOX[2] / 2            # its centre, so that its top is z = 3 mm too


def make_deep_box() -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=DEEP_BOX)
    return P._finish(trimesh.Trimesh(b.vertices, b.faces, process=False))


@pytest.fixture(scope="module")
def deep_box(tmp_path_factory):
    return FS.bake_model("deepbox", Path(tmp_path_factory.getbasetemp() / "sessions"), make_deep_box)


def tolerance(probe, b) -> float:
    """The pair's contact tolerance (docs/bundle-format.md): both bundles' displacement_outward
    and hull_deviation plus the automatic margin, 1e-3 of the smaller bbox diagonal."""
    qa, qb = probe.manifest["quality"], b.manifest["quality"]
    return (qa["displacement_outward"] + qa["hull_deviation"] + qb["displacement_outward"] + qb["hull_deviation"]
            + 1e-3 * min(qa["bbox_diagonal"], qb["bbox_diagonal"]))


def plunge(probe, jump: float, stretch: float = 0.0) -> float:
    """How far the jump frame moves the probe: that frame's contact is evaluated before the
    step (nothing deep yet), so at most the implicit step of the coupling alone, from rest,
    its spring already stretched by `stretch`, towards a target `jump` further that moves
    at jump / h:
      (m/h^2 + b/h + k_c) dx = k_c (jump + stretch) + (b/h) jump,
    m the probe's mass (its bundle's volume at the session's density), b the coupling's
    damper (hrt::default_coupling: 2 sqrt(k_c m), capped at m / 1 ms). A contact in that
    frame (the probe resting on the slab) only adds its stiffness to the left side."""
    m = DENSITY * probe.manifest["mass"]["volume"]
    b = min(2 * math.sqrt(K_COUPLING * m), m / 1e-3)
    return (K_COUPLING * (jump + stretch) + b / H * jump) / (m / H ** 2 + b / H + K_COUPLING)


def overlap_z(z, half, top=SLAB_TOP, bottom=SLAB_BOTTOM):
    """Overlap along z of the probe's bounding interval [z - half, z + half] with [bottom, top]."""
    return np.minimum(z + half, top) - np.maximum(z - half, bottom)


def run(hrt, folder: Path, name: str, tables: dict):
    scene = write_scene(folder, name, tables)
    res = hrt_run(hrt, scene, "--json")
    assert res.returncode == 0, res.stderr
    import json
    return json.loads(res.stdout), T.read_trace(tables["trace"]["path"])


# ----------------------------------------------------------------------------
# 1. A 10 mm jump into the slab in one step
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("start", ["clear", "resting"])
@pytest.mark.parametrize("probe", ["block", "tip"])
def test_a_jump_into_the_slab_keeps_an_upward_force_and_a_bounded_depth(session_bakes, hrt, tmp_path, probe, start):
    half = HALF[probe]
    z_touch = SLAB_TOP + half            # the probe's z when it just touches the slab's top
    # Held 0.05 mm clear of the slab (several times the contact tolerance, 15-55 um: no
    # contact, nothing remembered), or resting on it (target 0.1 mm inside: the probe
    # sits 1/3 of that deep, the springs in series).
    hold = 0.05 * MM if start == "clear" else -0.1 * MM
    z_hold = z_touch + hold
    traj = S.write_trajectory(tmp_path / "jump.csv", [0.0, T_JUMP, T_JUMP + H, 1.0],
                              [(0, 0, z_hold), (0, 0, z_hold), (0, 0, z_hold - JUMP), (0, 0, z_hold - JUMP)],
                              [(0, 0, 0, 1.0)] * 4)
    summary, tr = run(hrt, tmp_path, "jump", {
        "run": {"duration": 0.4, "lockstep": True},
        "object": objects(session_bakes, probe, (0.0, 0.0, z_touch + max(hold, 0.0))),
        "force": {"resolution": RES},
        "device": {"trajectory": traj},
        "trace": {"path": tmp_path / "trace.csv"},
    })
    tol = tolerance(session_bakes[probe], session_bakes["slab"])
    z = tr["probe_z"]
    depth = z_touch - z
    fz = tr["contact_fz"]
    # The frame of row i evaluates the contact at the pose the probe had when it started,
    # row i - 1's (moved ahead along its velocity by at most SessionOptions::max_prediction,
    # 1 mm): the rows whose starting pose overlaps the slab by more than the tolerance.
    inside = np.flatnonzero(overlap_z(z[:-1], half) > tol) + 1
    zero_or_down = inside[fz[inside] <= 0.0]
    # Bounds fixed before the run:
    # - deepest: the jump frame's plunge (see plunge()) from where the probe was held: 0.05 mm
    #   clear, or resting at d0 = k_c / (k + k_c) x 0.1 mm, its spring stretched by the rest
    #   of the 0.1 mm. From the next frame on the contact acts inside the implicit step
    #   (stiffness k) and pushes back; 0.05 mm of room for the contact's texel-scale details.
    target_depth = JUMP - hold
    d0 = -hold if start == "clear" else K_COUPLING / (K_CONTACT + K_COUPLING) * -hold
    deepest = d0 + plunge(session_bakes[probe], JUMP, -hold - d0) + 0.05 * MM
    # - settled: the contact (k per metre of depth, along +z) and the coupling (k_c, towards
    #   the target) share the target's depth: d_eq = k_c D / (k + k_c) = 6.67 mm; within
    #   0.2 mm (the tip's coarse sphere is a few um inside its radius, the texture model's
    #   delta a texel-scale step of the depth).
    d_eq = K_COUPLING * target_depth / (K_CONTACT + K_COUPLING)
    settled = tr["t"] >= T_JUMP + 0.2
    w = summary["warnings"]
    print(f"\n{probe} {start}: {len(inside)} frames in the slab (tolerance {tol * 1e6:.1f} um), contact fz "
          f"{fz[inside].min():.3f}..{fz[inside].max():.3f} N; deepest {depth.max() / MM:.3f} mm at "
          f"t = {tr['t'][depth.argmax()]:.3f} s (bound {deepest / MM:.3f} mm); settled "
          f"{depth[settled].min() / MM:.3f}..{depth[settled].max() / MM:.3f} mm (d_eq {d_eq / MM:.3f} mm); "
          f"warnings {w}")
    assert len(inside) >= 0.25 / H, "the probe did not stay in the slab after the jump (the run is vacuous)"
    assert depth.max() > 5 * MM, "no deep penetration: the scene does not test what it says"
    assert len(zero_or_down) == 0, \
        f"contact fz <= 0 with the probe in the slab at t = {tr['t'][zero_or_down[:5]]}: {fz[zero_or_down[:5]]}"
    assert depth.max() <= deepest, f"deepest {depth.max() / MM:.3f} mm > {deepest / MM:.3f} mm"
    # Never through: the probe's top stays above the slab's bottom.
    assert np.all(z + half > SLAB_BOTTOM + tol)
    assert np.all(np.abs(depth[settled] - d_eq) < 0.2 * MM)
    assert w["deep_fallbacks"] >= 1 and w["deep_fallback_patches"] >= 1
    if probe == "block":
        # The block's d_eq is past the slab's middle ((4 + 6) / 2 = 5 mm): the fallback, not
        # the texture force, holds it there, every frame once settled.
        assert w["deep_fallbacks"] >= np.count_nonzero(settled)


# ----------------------------------------------------------------------------
# 2. A session that starts 10 mm deep
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("target", ["same", "surface"])
@pytest.mark.parametrize("probe", ["block", "tip"])
def test_a_probe_that_starts_deep_is_pushed_out(session_bakes, deep_box, hrt, tmp_path, probe, target):
    half = HALF[probe]
    z_touch = SLAB_TOP + half
    z0 = z_touch - JUMP
    z_target = z0 if target == "same" else z_touch
    objs = objects(session_bakes, probe, (0.0, 0.0, z0))
    objs[1] = {"name": "box", "bundle": deep_box.bundle, "position": [0.0, 0.0, DEEP_BOX_Z]}
    summary, tr = run(hrt, tmp_path, "start", {
        "run": {"duration": 0.3, "lockstep": True},
        "object": objs,
        "force": {"resolution": RES},
        "device": {"trajectory": S.write_trajectory(tmp_path / "still.csv", [0.0, 1.0], [(0, 0, z_target)] * 2,
                                                    [(0, 0, 0, 1.0)] * 2)},
        "trace": {"path": tmp_path / "trace.csv"},
    })
    tol = tolerance(session_bakes[probe], deep_box)
    z, t, fz = tr["probe_z"], tr["t"], tr["contact_fz"]
    depth = z_touch - z
    # Bounds fixed before the run: with the target where the probe starts, the springs share
    # its 10 mm (d_eq = k_c D / (k + k_c) = 6.67 mm); with the target at the surface the probe
    # ends resting on it (no force left but the contact's: depth within the tolerance,
    # 0.1 mm of room for the texture model's texel-scale delta). Within 0.2 mm of d_eq, as above.
    end_bound = (K_COUPLING * JUMP / (K_CONTACT + K_COUPLING) + 0.2 * MM) if target == "same" else 0.1 * MM
    rise_by = JUMP - end_bound - 0.2 * MM  # the rise that ending within end_bound takes, less 0.2 mm
    first = t <= 0.2
    # Row i's frame starts from row i - 1's pose (row 0's from the initial one).
    starts = np.concatenate([[z0], z[:-1]])
    inside = np.flatnonzero(overlap_z(starts, half, SLAB_TOP, SLAB_TOP - DEEP_BOX[2]) > tol)
    print(f"\n{probe}, target {target}: z {z[0] / MM:.3f} -> {z[first][-1] / MM:.3f} mm at 0.2 s -> {z[-1] / MM:.3f} mm; "
          f"final depth {depth[-1] / MM:.3f} mm (bound {end_bound / MM:.3f}); contact fz in the box "
          f"{fz[inside].min():.3f}..{fz[inside].max():.3f} N; warnings {summary['warnings']}")
    assert z[first][-1] - z0 >= rise_by, "not pushed out within 0.2 s"
    # Out, not through: never deeper than where it started.
    assert depth.max() <= JUMP + tol
    assert np.all(fz[inside] > 0.0)
    assert -tol - 0.1 * MM <= depth[-1] <= end_bound
