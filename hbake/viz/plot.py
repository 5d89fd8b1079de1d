"""Figures of a haptic session from its trace: ``hbake plot TRACE.csv``.

Works on any trace that follows docs/trace-format.md (the columns are found by name;
a figure that needs a column the file lacks is an error naming the file and the
column). Figures, each a PNG written to ``--out`` (default: beside the trace, named
``<trace stem>.<figure>.png``):

* ``fig7``: position of the probe (relative to its first frame) and the contact force
  on it along x, y, z per frame, as in Fig. 7 of the paper (roughness under translation);
* ``fig8``: rotation of the probe about ``--axis`` (the contact normal n) and its
  translation along it, and the contact torque about it, as in Fig. 8;
* ``fig9``: per-frame time of collision detection, of the texture force (clustering
  plus penetration depth and force), of the whole frame, and the number of contact
  patches, as in Fig. 9;
* ``scene``: a picture of the scene at ``--frame`` (needs ``--scene SCENE.toml``): the
  objects' coarse meshes at their poses, each contact patch's sampling window and its
  force on the probe as an arrow. The windows and forces come from ``hrt query --json``
  run at that frame's poses (the trace records neither), found on PATH or given with
  ``--hrt``.

``--audio`` also writes ``<trace stem>.wav``: the contact force's high-frequency part as
sound (hbake/viz/sound.py).

Matplotlib's Agg backend renders off screen; the same trace gives the same picture.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np

from hbake.errors import HbakeError, InputInvalidError, InputMissingError, OutputUnwritableError
from hbake.fileio import write_atomic

FIGURES = ("fig7", "fig8", "fig9", "scene")
#: Figures made when --figure is not given: those that need nothing but the trace.
DEFAULT_FIGURES = ("fig7", "fig8", "fig9")
DPI = 100


class Trace:
    """The columns of a trace as float64 arrays, by name."""

    def __init__(self, path: Path):
        self.path = Path(path)
        try:
            with open(self.path, encoding="ascii") as f:
                header = f.readline().rstrip("\n")
                self.columns = header.split(",") if header else []
                rows = [line.rstrip("\n").split(",") for line in f if line.strip()]
        except FileNotFoundError:
            raise InputMissingError(f"{self.path}: no such trace file") from None
        except IsADirectoryError:
            raise InputMissingError(f"{self.path}: is a directory, not a trace") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise InputInvalidError(f"{self.path}: cannot read the trace: {exc}") from None
        if not self.columns or "t" not in self.columns:
            raise InputInvalidError(f"{self.path}: not a trace of hrt run (no 't' column in the header; "
                                    f"see docs/trace-format.md)")
        n = len(self.columns)
        for i, r in enumerate(rows):
            if len(r) != n:
                raise InputInvalidError(f"{self.path}: line {i + 2}: {len(r)} fields, the header has {n}")
        try:
            self.data = np.array(rows, dtype=np.float64).reshape(len(rows), n)
        except ValueError as exc:
            raise InputInvalidError(f"{self.path}: a field is not a number ({exc})") from None
        if len(rows) == 0:
            raise InputInvalidError(f"{self.path}: the trace has no frames")
        self.index = {c: i for i, c in enumerate(self.columns)}

    def __len__(self):
        return self.data.shape[0]

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.index:
            raise InputInvalidError(f"{self.path}: no column '{name}' (docs/trace-format.md)")
        return self.data[:, self.index[name]]

    def vec(self, prefix: str, keys=("x", "y", "z")) -> np.ndarray:
        return np.column_stack([self[f"{prefix}{k}"] for k in keys])

    def frames(self) -> np.ndarray:
        return self["frame"] if "frame" in self.index else np.arange(1, len(self) + 1, dtype=float)

    def times(self) -> np.ndarray:
        """Session time of each row (s): the figures' x axis. A real-time session runs
        frames at ~10 kHz out of contact and ~1 kHz in it, so against the frame number the
        contact would be squeezed into a sliver of the plot."""
        return self["t"] if "t" in self.index else self.frames()


def _quat_mul(a, b):
    x1, y1, z1, w1 = np.moveaxis(np.asarray(a, float), -1, 0)
    x2, y2, z2, w2 = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2], -1)


def _quat_conj(q):
    q = np.asarray(q, float)
    return np.concatenate([-q[..., :3], q[..., 3:]], -1)


def _rotmat(q):
    x, y, z, w = (float(c) for c in np.asarray(q, float) / np.linalg.norm(q))
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def twist_angle(q: np.ndarray, q0: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation q q0^-1 about ``axis`` (its twist: the swing-twist
    decomposition, 2 atan2(q_vec . a, q_w)), wrapped to (-pi, pi]."""
    r = _quat_mul(q, _quat_conj(q0))
    ang = 2 * np.arctan2(r[:, :3] @ axis, r[:, 3])
    return (ang + np.pi) % (2 * np.pi) - np.pi


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path: Path):
    try:
        # Metadata without the software version and date: the same trace, the same bytes.
        # The temporary ends in .png: savefig picks the format from the name.
        return write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=DPI, metadata={"Software": None}),
                            suffix=".tmp.png")
    finally:
        _pyplot().close(fig)


def fig7(tr: Trace, path: Path, title: str | None = None) -> Path:
    """Position (relative to the first frame, mm) and contact force (N) along x, y, z."""
    plt = _pyplot()
    f = tr.times()
    p = tr.vec("probe_") * 1e3
    p = p - p[0]
    F = tr.vec("contact_f")
    fig, ax = plt.subplots(3, 2, figsize=(10, 6.5), sharex=True)
    for k, name in enumerate("xyz"):
        ax[k, 0].plot(f, p[:, k], lw=1, color="C0")
        ax[k, 0].set_ylabel(f"{name} (mm)")
        ax[k, 1].plot(f, F[:, k], lw=1, color="C3")
        ax[k, 1].set_ylabel(f"F{name} (N)")
        for a in ax[k]:
            a.grid(alpha=0.3)
    ax[0, 0].set_title("probe position (from the first row)")
    ax[0, 1].set_title("contact force on the probe")
    ax[2, 0].set_xlabel("session time (s)")
    ax[2, 1].set_xlabel("session time (s)")
    fig.suptitle(title or f"Roughness under translation (Fig. 7): {tr.path.name}")
    fig.tight_layout()
    return _save(fig, path)


def fig8(tr: Trace, path: Path, axis=(0.0, 0.0, 1.0), title: str | None = None) -> Path:
    """Rotation about n (deg), translation along n (mm) and contact torque about n (N m)."""
    plt = _pyplot()
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    f = tr.times()
    q = tr.vec("probe_", ("qx", "qy", "qz", "qw"))
    p = tr.vec("probe_")
    rot = np.degrees(twist_angle(q, q[0], a))
    lift = (p - p[0]) @ a * 1e3
    torque = tr.vec("contact_t") @ a
    fig, ax = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True)
    ax[0].plot(f, rot, lw=1)
    ax[0].set_ylabel("rotation about n (deg)")
    ax[1].plot(f, lift, lw=1, color="C2")
    ax[1].set_ylabel("translation along n (mm)")
    ax[2].plot(f, torque * 1e3, lw=1, color="C3")
    ax[2].set_ylabel("contact torque about n (N mm)")
    ax[2].set_xlabel("session time (s)")
    for x in ax:
        x.grid(alpha=0.3)
    fig.suptitle(title or f"Roughness under rotation (Fig. 8): {tr.path.name}, n = "
                          f"[{', '.join(f'{c:.3g}' for c in a)}]")
    fig.tight_layout()
    return _save(fig, path)


def fig9(tr: Trace, path: Path, title: str | None = None) -> Path:
    """Collision, texture and total time per frame (ms) and the number of patches."""
    plt = _pyplot()
    f = tr.times()
    coll = tr["collision_us"] / 1e3
    tex = (tr["clustering_us"] + tr["force_us"]) / 1e3
    total = tr["total_us"] / 1e3
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax[0].plot(f, total, lw=1, color="k", label=f"total (median {np.median(total):.2f} ms)")
    ax[0].plot(f, tex, lw=1, color="C3", label=f"texture: clustering + depth + force "
                                              f"(median {np.median(tex):.2f} ms)")
    ax[0].plot(f, coll, lw=1, color="C0", label=f"collision detection (median {np.median(coll):.2f} ms)")
    ax[0].set_ylabel("time per frame (ms)")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[0].grid(alpha=0.3)
    ax[1].step(f, tr["patches"], where="mid", lw=1, color="C2")
    ax[1].set_ylabel("patches")
    ax[1].set_xlabel("session time (s)")
    ax[1].grid(alpha=0.3)
    # The frames in contact are the ones whose cost matters (out of contact a frame is a
    # few microseconds: a median over all of them would say hundreds of kHz).
    contact = tr["patches"] > 0
    med = float(np.median(total[contact])) if contact.any() else float(np.median(total))
    rate = 1e3 / med if med > 0 else float("inf")
    fig.suptitle(title or f"Timings (Fig. 9): {tr.path.name}: median {med:.2f} ms a frame "
                          f"{'in contact' if contact.any() else '(no contact)'} ({rate:.0f} Hz of compute)")
    fig.tight_layout()
    return _save(fig, path)


# ----------------------------------------------------------------------------
# The scene picture
# ----------------------------------------------------------------------------


def scene_objects(scene: Path):
    """The objects of a scene file (name, bundle, initial position and orientation,
    trajectory) and its [force] table, paths resolved against the file's folder
    (docs/scene-format.md). Only what the pictures need is read: `hrt run` checks the rest."""
    try:
        with open(scene, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise InputMissingError(f"{scene}: no such scene file") from None
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputInvalidError(f"{scene}: not a readable scene file: {exc}") from None
    objs = doc.get("object")
    if not isinstance(objs, list) or len(objs) < 2:
        raise InputInvalidError(f"{scene}: object: a scene needs at least two [[object]] tables")
    out = []
    for i, o in enumerate(objs):
        if "bundle" not in o:
            raise InputInvalidError(f"{scene}: object[{i}].bundle: missing")
        out.append({"name": o.get("name", f"object{i}"), "bundle": (scene.parent / o["bundle"]).resolve(),
                    "position": np.asarray(o.get("position", [0, 0, 0]), float),
                    "orientation": np.asarray(o.get("orientation", [0, 0, 0, 1]), float),
                    "trajectory": (scene.parent / o["trajectory"]) if o.get("trajectory") else None})
    force = doc.get("force", {})
    return out, force


def trajectory_pose(path: Path, t: float):
    """Linear interpolation of a trajectory's position, nlerp of its quaternion at t
    (the picture needs no slerp's exactness)."""
    rows = [r for r in open(path).read().splitlines() if r.strip() and not r.lstrip().startswith("#")]
    head = [c.strip() for c in rows[0].split(",")]
    data = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    col = {c: i for i, c in enumerate(head)}
    tt = data[:, col.get("t", col.get("time", 0))]
    pos = np.array([np.interp(t, tt, data[:, col[k]]) for k in "xyz"])
    q = np.array([np.interp(t, tt, data[:, col[k]]) for k in ("qx", "qy", "qz", "qw")])
    return pos, q / np.linalg.norm(q)


def _hrt(hrt: str | None) -> str:
    exe = hrt or os.environ.get("HRT") or shutil.which("hrt")
    if not exe:
        here = Path(sys.executable).parent / "hrt"
        exe = str(here) if here.exists() else None
    if not exe:
        raise HbakeError("scene picture: no hrt binary (put it on PATH, set HRT or pass --hrt)", 3)
    return exe


def scene_picture(tr: Trace, scene: Path, frame: int, path: Path, hrt: str | None = None,
                  title: str | None = None) -> Path:
    """The objects' coarse meshes at ``frame``, each patch's window and force arrow."""
    from hbake.bundle import read_bundle

    plt = _pyplot()
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    objs, force = scene_objects(Path(scene))
    frames = tr.frames()
    k = int(np.argmin(np.abs(frames - frame)))
    t = float(tr["t"][k])
    poses = [(tr.vec("probe_")[k], tr.vec("probe_", ("qx", "qy", "qz", "qw"))[k])]
    for o in objs[1:]:
        poses.append(trajectory_pose(o["trajectory"], t) if o["trajectory"] else (o["position"], o["orientation"]))
    cmd = [_hrt(hrt), "query", *[str(o["bundle"]) for o in objs], "--json", "--no-verify-hashes",
           "--pose-a", *[repr(float(x)) for x in (*poses[0][0], *poses[0][1])]]
    for p, q in poses[1:]:
        cmd += ["--pose-b", *[repr(float(x)) for x in (*p, *q)]]
    if "stiffness" in force:
        cmd += ["--stiffness", repr(float(force["stiffness"]))]
    if "resolution" in force:
        cmd += ["--resolution", str(int(force["resolution"]))]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise HbakeError(f"{scene}: hrt query at frame {int(frames[k])} failed (exit {res.returncode}): "
                         f"{res.stderr.strip().splitlines()[-1] if res.stderr.strip() else ''}", 7)
    q = json.loads(res.stdout)

    fig = plt.figure(figsize=(6.4, 5.6))
    ax = fig.add_subplot(projection="3d")
    colours = ["#4c72b0", "#aaaaaa", "#c9a66b", "#8fbf8f"]
    allpts = []
    for i, (o, (p, qq)) in enumerate(zip(objs, poses)):
        try:
            b = read_bundle(o["bundle"], verify=False)
        except HbakeError as exc:
            raise InputInvalidError(f"{scene}: object[{i}] {o['bundle']}: {exc}") from None
        V = np.asarray(b.coarse_vertices, float) @ _rotmat(qq).T + p
        F = np.asarray(b.coarse_faces, np.int64)
        allpts.append(V)
        poly = Poly3DCollection(V[F], facecolor=colours[i % len(colours)], edgecolor="k",
                                linewidths=0.1, alpha=0.35 if i == 0 else 0.25)
        ax.add_collection3d(poly)
    pts = np.concatenate(allpts)
    scale = float(np.linalg.norm(pts.max(0) - pts.min(0)))
    fmax = max([np.linalg.norm(c["force"]) for c in q["contacts"]] + [1e-12])
    segs = []
    for c in q["contacts"]:
        w = c["window"]
        o, cell, N = np.asarray(w["origin"]), w["cell"], w["resolution"]
        u, v = np.asarray(c["u"]), np.asarray(c["v"])
        L = cell * N
        corners = [o, o + L * u, o + L * u + L * v, o + L * v, o]
        segs += [[corners[j], corners[j + 1]] for j in range(4)]
        f = np.asarray(c["force"])
        if np.linalg.norm(f) > 0:
            a = np.asarray(c["p_a"])
            d = f / fmax * 0.25 * scale
            ax.quiver(*a, *d, color="C3", linewidth=2, arrow_length_ratio=0.2)
    if segs:
        ax.add_collection3d(Line3DCollection(segs, colors="C1", linewidths=1.5))
    c = 0.5 * (pts.max(0) + pts.min(0))
    r = 0.5 * float((pts.max(0) - pts.min(0)).max())
    # Zoom on the contact when there is one: the patches are small beside the parts.
    if q["contacts"]:
        pa = np.array([cc["p_a"] for cc in q["contacts"]])
        c = pa.mean(0)
        r = max(0.25 * r, float(np.ptp(pa, axis=0).max()) * 0.75,
                max(cc["window"]["cell"] * cc["window"]["resolution"] for cc in q["contacts"]))
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    F = np.asarray(q["force"])
    ax.set_title(title or f"{Path(scene).name}, frame {int(frames[k])} (t = {t:.3f} s): "
                          f"{len(q['contacts'])} patch(es), |F| = {np.linalg.norm(F):.3g} N\n"
                          f"orange: patch windows; red: each patch's force on the probe "
                          f"(longest = {fmax:.3g} N)", fontsize=9)
    ax.view_init(elev=22, azim=-60)
    fig.tight_layout()
    return _save(fig, path)


def plot_trace(trace: Path, figures=DEFAULT_FIGURES, out: Path | None = None, scene: Path | None = None,
               frame: int | None = None, axis=(0.0, 0.0, 1.0), hrt: str | None = None,
               audio: bool = False, audio_source: str = "contact", audio_cutoff: float | None = None) -> list[Path]:
    """Write the figures of ``trace`` (and with ``audio`` its sound, hbake/viz/sound.py);
    returns their paths."""
    trace = Path(trace)
    tr = Trace(trace)
    out = Path(out) if out is not None else trace.parent
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputUnwritableError(f"{out}: cannot create the folder: {exc.strerror}") from None
    if "scene" in figures and scene is None:
        raise HbakeError(f"{trace}: --figure scene needs --scene SCENE.toml (the objects and their bundles)", 2)
    stem = trace.stem
    # Nothing is written over an input: a trace named like one of the outputs
    # (x.wav, x.fig7.png) in the output folder would be replaced by it.
    inputs = [trace.resolve()] + ([Path(scene).resolve()] if scene is not None else [])
    for p in [out / f"{stem}.{name}.png" for name in figures] + ([out / f"{stem}.wav"] if audio else []):
        if p.resolve() in inputs:
            raise OutputUnwritableError(f"{p}: an output of hbake plot would overwrite this input (choose another -o)")
    paths = []
    for name in figures:
        path = out / f"{stem}.{name}.png"
        if name == "fig7":
            paths.append(fig7(tr, path))
        elif name == "fig8":
            paths.append(fig8(tr, path, axis))
        elif name == "fig9":
            paths.append(fig9(tr, path))
        elif name == "scene":
            fr = frame if frame is not None else int(tr.frames()[len(tr) // 2])
            paths.append(scene_picture(tr, Path(scene), fr, path, hrt))
    if audio:
        from hbake.viz import sound
        cutoff = sound.DEFAULT_CUTOFF if audio_cutoff is None else audio_cutoff
        sig = sound.trace_vibration(tr, sound.DEFAULT_RATE, cutoff, audio_source)
        paths.append(sound.write_wav(out / f"{stem}.wav", sig, sound.DEFAULT_RATE))
    return paths
