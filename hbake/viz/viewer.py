"""A live 3-D view of bundles, sessions and traces in the browser: ``hbake view``.

Three modes, one page (docs/viewer.md):

* **bundle**: ``hbake view BUNDLE.hbundle``: the full surface the atlas reconstructs, with
  the coarse mesh, the convex pieces and the atlas charts as toggles;
* **live**: ``hbake view SCENE.toml``: the scene file's session run by the runtime
  (the Python module ``hrt``: hrt.Runner, the same device loop, coupling and force
  as ``hrt run``), in lockstep paced to the wall clock. The probe's handle is a
  *virtual device* moved with a 6-DoF gizmo (the file's scripted trajectory is played
  instead with ``--play``); contact patches with their windows and normals, the force and
  torque on the probe as arrows, the coupling target, and live plots;
* **replay**: ``hbake view SCENE.toml --trace TRACE.csv``: a recorded session
  (docs/trace-format.md) on a timeline to scrub or play at any speed, with the same
  overlays (the patches are recomputed by the runtime's query at the frame's poses: a
  trace records their count, not their windows).

The page is viser's (its client is built into its wheel: no network, no build step),
served on loopback by default. The contact force's vibration is also sound
(hbake/viz/sound.py): the page holds a player for the whole replay, or for the last seconds
of a live session.

Display units are millimetres (the scene's metres x 1000); arrows are scaled by the
legend's mm per newton and mm per newton-metre.
"""
from __future__ import annotations

import base64
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hbake.errors import HbakeError, InputInvalidError, InputMissingError

MM = 1000.0                       # display units per metre
MAX_SURFACE_TRIANGLES = 400_000   # per object: what a browser draws smoothly on a laptop
PLOT_SECONDS = 5.0                # width of the live plots
DEPTH_SERIES = 4                  # patches in the depth plot (the deepest ones)
DISPLAY_HZ = 30.0                 # scene and GUI updates per second
SOUND_SECONDS = 3.0               # a live session's sound: the last seconds
PALETTE = np.array([[230, 159, 0], [86, 180, 233], [0, 158, 115], [240, 228, 66], [0, 114, 178],
                    [213, 94, 0], [204, 121, 167], [120, 120, 120]], dtype=np.uint8)


def wxyz(q_xyzw) -> tuple:
    """viser's quaternion order (w, x, y, z) from the project's (x, y, z, w)."""
    x, y, z, w = (float(v) for v in q_xyzw)
    return (w, x, y, z)


def xyzw(q_wxyz) -> np.ndarray:
    w, x, y, z = (float(v) for v in q_wxyz)
    return np.array([x, y, z, w])


def rotate(q_xyzw, p) -> np.ndarray:
    x, y, z, w = q_xyzw
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    return np.asarray(p, float) @ R.T


# ----------------------------------------------------------------------------
# What a bundle shows: the reconstructed surface, coarse mesh, pieces, charts
# ----------------------------------------------------------------------------


def surface_mesh(faces: np.ndarray, uvs: np.ndarray, atlas: np.ndarray, max_triangles: int = MAX_SURFACE_TRIANGLES):
    """The full surface the atlas reconstructs, as a closed triangle mesh (vertices in
    metres, object frame; faces): what a GPU does with displacement mapping. Each coarse
    triangle is cut into k x k small ones on a barycentric grid, and each grid point is moved
    to the atlas's bilinear lookup at its UV (the point of the full surface the runtime reads
    there, docs/bundle-format.md). Grid points on a coarse edge are shared by the two faces
    of the edge (taken from the first), so the mesh has no crack at a chart's seam. k is the
    largest that keeps the count within ``max_triangles`` (k^2 per face), and at most the
    coarse triangles' longest UV edge in texels (finer would only interpolate)."""
    from hbake.bundle import atlas_lookup

    f = np.asarray(faces, np.int64)
    uv = np.asarray(uvs, np.float64)
    F = len(f)
    if F == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    H, W = atlas.shape[:2]
    tex = uv * np.array([W, H])
    edge = np.max(np.linalg.norm(tex - np.roll(tex, 1, axis=1), axis=2), axis=1)
    k = int(max(1, min(math.floor(math.sqrt(max_triangles / F)), math.ceil(float(np.max(edge))))))
    gi, gj = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    inside = gi + gj <= k
    gi, gj = gi[inside], gj[inside]                       # grid points: weight gi / k on corner 1, gj / k on 2
    P = len(gi)
    w = np.stack([k - gi - gj, gi, gj], axis=1) / k       # (P, 3) barycentric weights
    pts_uv = np.einsum("pc,fcd->fpd", w, uv)          # (F, P, 2)
    pos = atlas_lookup(atlas, pts_uv.reshape(-1, 2))[:, :3]
    # Keys that are equal for the same point of the coarse mesh seen from two faces:
    # a corner is its vertex; a point of an edge is (lower vertex, higher vertex, steps from
    # the lower); an interior point is its face's own.
    va, vb, vc = f[:, 0:1], f[:, 1:2], f[:, 2:3]
    a, b, c = (k - gi - gj)[None, :], gi[None, :], gj[None, :]
    key = np.zeros((F, P, 3), dtype=np.int64)
    key[..., 0] = -1 - np.arange(F)[:, None]          # interior: (-1 - face, point, 0)
    key[..., 1] = np.arange(P)[None, :]

    def on_edge(mask, x, y, tx):  # points with weight only on corners x, y; tx = steps from x
        lo, hi = np.minimum(x, y), np.maximum(x, y)
        t = np.where(x <= y, tx, k - tx)
        sel = np.broadcast_to(mask, (F, P))
        for d, val in enumerate((lo, hi, t)):
            key[..., d] = np.where(sel, np.broadcast_to(val, (F, P)), key[..., d])

    on_edge(a == 0, vb, vc, c)        # edge 1-2: steps from corner 1 = gj
    on_edge(b == 0, va, vc, c)        # edge 0-2: steps from corner 0 = gj
    on_edge(c == 0, va, vb, b)        # edge 0-1: steps from corner 0 = gi
    for corner, vx in ((a == k, va), (b == k, vb), (c == k, vc)):
        sel = np.broadcast_to(corner, (F, P))
        for d, val in enumerate((vx, vx, 0 * vx)):
            key[..., d] = np.where(sel, np.broadcast_to(val, (F, P)), key[..., d])
    _, first, inv = np.unique(key.reshape(-1, 3), axis=0, return_index=True, return_inverse=True)
    verts = pos[first]
    index = inv.reshape(F, P)
    # Small triangles of the grid, wound like their face: (i, j), (i + 1, j), (i, j + 1)
    # and (i + 1, j), (i + 1, j + 1), (i, j + 1).
    at = -np.ones((k + 1, k + 1), dtype=np.int64)
    at[gi, gj] = np.arange(P)
    ti, tj = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    up = ti + tj <= k - 1
    down = ti + tj <= k - 2
    tri = np.concatenate([
        np.stack([at[ti[up], tj[up]], at[ti[up] + 1, tj[up]], at[ti[up], tj[up] + 1]], axis=1),
        np.stack([at[ti[down] + 1, tj[down]], at[ti[down] + 1, tj[down] + 1], at[ti[down], tj[down] + 1]], axis=1)])
    out_faces = index[:, tri].reshape(-1, 3)
    return verts, out_faces


def chart_ids(faces: np.ndarray, uvs: np.ndarray) -> np.ndarray:
    """The atlas chart of each coarse face: faces joined across an edge whose two corners
    have the same UVs on both sides (scipy's connected components)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(faces)
    key = {}
    src, dst = [], []
    q = np.round(np.asarray(uvs, np.float64) * (1 << 20)).astype(np.int64)
    for f in range(m):
        for k in range(3):
            i, j = int(faces[f, k]), int(faces[f, (k + 1) % 3])
            ui, uj = tuple(q[f, k]), tuple(q[f, (k + 1) % 3])
            e = (min(i, j), max(i, j), *((ui, uj) if i < j else (uj, ui)))
            g = key.setdefault(e, f)
            if g != f:
                src.append(f), dst.append(g)
    graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(m, m))
    return connected_components(graph, directed=False)[1]


@dataclass
class ObjectView:
    """One bundle, ready to draw (metres, object frame)."""

    name: str
    bundle: Path
    surface: tuple
    coarse: tuple
    charts: np.ndarray
    pieces: list
    center_of_mass: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius: float = 0.0


def load_object(name: str, bundle: Path, max_triangles: int = MAX_SURFACE_TRIANGLES) -> ObjectView:
    from hbake.bundle import BundleError, read_bundle

    if not Path(bundle).exists():
        raise InputMissingError(f"{bundle}: no such bundle")
    try:
        # Fully checked (hashes, convexity, the atlas's lookups): the page shows only a
        # bundle the runtime would load, and a NaN texel would make a NaN vertex.
        b = read_bundle(bundle, verify=True)
    except BundleError as exc:
        raise InputInvalidError(f"{bundle}: {exc}") from None
    except FileNotFoundError:
        raise InputMissingError(f"{bundle}: no such bundle") from None
    v, f = np.asarray(b.coarse_vertices, float), np.asarray(b.coarse_faces, np.int64)
    pieces = [(np.asarray(pv, float), np.asarray(pf, np.int64)) for pv, pf in zip(b.piece_vertices, b.piece_faces)]
    com = np.asarray(b.manifest.get("mass", {}).get("center_of_mass", v.mean(axis=0)), float)
    return ObjectView(name=name, bundle=Path(bundle), surface=surface_mesh(f, b.coarse_uvs, b.atlas, max_triangles),
                      coarse=(v, f), charts=chart_ids(f, b.coarse_uvs), pieces=pieces, center_of_mass=com,
                      radius=float(np.max(np.linalg.norm(v - v.mean(axis=0), axis=1))))


# ----------------------------------------------------------------------------
# Scene files
# ----------------------------------------------------------------------------


def object_pose_at(obj: dict, t: float):
    """Position and quaternion of a scene object (hbake.viz.plot.scene_objects) at time t."""
    from hbake.viz.plot import trajectory_pose

    if obj["trajectory"]:
        return trajectory_pose(obj["trajectory"], t)
    return obj["position"], obj["orientation"]


# ----------------------------------------------------------------------------
# The page
# ----------------------------------------------------------------------------


class Viewer:
    """The viser page and what drives it. ``mode`` is "bundle", "live" or "replay".

    For scripts and tests: :meth:`drag_to` moves the virtual device's handle as the gizmo
    does; :meth:`step` runs frames of a live session when it was made with
    ``realtime=False``; :meth:`show_frame` jumps a replay to a frame; :attr:`last` holds
    what the page shows (frame, force, torque, patches)."""

    def __init__(self, target: Path, trace: Path | None = None, *, host: str = "127.0.0.1", port: int = 8080,
                 play: bool = False, realtime: bool = True, max_triangles: int = MAX_SURFACE_TRIANGLES,
                 force_scale: float | None = None, torque_scale: float | None = None, duration: float = 3600.0):
        import viser

        target = Path(target)
        self.lock = threading.RLock()
        self.stop_event = threading.Event()
        self.last: dict = {}
        self.history: deque = deque()
        self.runner = None
        self.scene_query = None
        self.trace = None
        self.sim_rate = 0.0
        self._last_display = 0.0
        self._thread = None
        self.overlays: dict = {}
        if target.is_dir() or target.suffix == ".hbundle":
            self.mode = "bundle"
            self.objects = [{"name": target.stem, "bundle": target, "position": np.zeros(3),
                             "orientation": np.array([0, 0, 0, 1.0]), "trajectory": None}]
            self.force_table = {}
        else:
            if not target.exists():
                raise InputMissingError(f"{target}: no such scene file or bundle")
            from hbake.viz.plot import scene_objects

            self.objects, self.force_table = scene_objects(target)
            self.mode = "replay" if trace is not None else "live"
        self.views = [load_object(o["name"], o["bundle"], max_triangles) for o in self.objects]
        size = max(v.radius for v in self.views) * 2
        self.force_scale = force_scale if force_scale is not None else 0.25 * size * MM   # mm per N
        self.torque_scale = torque_scale if torque_scale is not None else 5.0 * size * MM  # mm per N m

        if self.mode in ("live", "replay"):
            try:
                import hrt
            except ImportError:
                raise HbakeError("a session needs the runtime's Python module hrt, which is not installed "
                                 "(make setup builds it; pip install . installs it)", 1) from None
        if self.mode == "live":
            try:
                # No trace (the file's would be overwritten by an hour of dragging) and no
                # frames kept (the page keeps the last seconds).
                self.runner = hrt.Runner(str(target), duration=duration, device="file" if play else "virtual",
                                         write_trace=False, keep_frames=False)
            except (hrt.SceneFileError, hrt.BundleError, hrt.DeviceError, ValueError) as exc:
                raise InputInvalidError(str(exc)) from None
            self.virtual = not play
        if self.mode == "replay":
            from hbake.viz.plot import Trace
            self.trace = Trace(trace)
            models = [hrt.load_bundle(str(o["bundle"]), verify_hashes=False) for o in self.objects]
            opts = {k: self.force_table[k] for k in ("resolution", "stiffness", "heights") if k in self.force_table}
            self.scene_query = hrt.Scene(models, **opts)

        self.server = viser.ViserServer(host=host, port=port, label="hbake view", verbose=False)
        self.server.scene.set_up_direction("+z")
        self._build_scene()
        self._build_gui()
        if self.mode == "live":
            self._frame_dict(self.runner.step())
            self._display()
            if realtime:
                self._thread = threading.Thread(target=self._run_live, name="hbake-view-session", daemon=True)
                self._thread.start()
        elif self.mode == "replay":
            self.show_frame(0)
            self._thread = threading.Thread(target=self._run_replay, name="hbake-view-replay", daemon=True)
            self._thread.start()

    # -- the URL -------------------------------------------------------------------
    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}/"

    def close(self):
        self.stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.server.stop()

    # -- the 3-D scene -------------------------------------------------------------
    def _build_scene(self):
        sc = self.server.scene
        self.frames = []
        self.groups = {"surface": [], "coarse": [], "pieces": [], "charts": []}
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for i, (o, v) in enumerate(zip(self.objects, self.views)):
            node = sc.add_frame(f"/obj{i}", show_axes=False, position=tuple(o["position"] * MM),
                                wxyz=wxyz(o["orientation"]))
            self.frames.append(node)
            sv, sf = v.surface
            color = (200, 170, 140) if i == 0 else (175, 185, 200)
            g = self.groups
            if len(sf):
                # The probe a little transparent in a session: the patches' normals and
                # the force arrow start inside it.
                see_through = 0.6 if i == 0 and self.mode != "bundle" else None
                g["surface"].append(sc.add_mesh_simple(f"/obj{i}/surface", sv * MM, sf, color=color, side="double",
                                                       opacity=see_through))
            cv, cf = v.coarse
            g["coarse"].append(sc.add_mesh_simple(f"/obj{i}/coarse", cv * MM, cf, color=(40, 40, 40),
                                                  wireframe=True, visible=False))
            # Charts: the coarse faces of each chart as one mesh in one colour.
            for c in np.unique(v.charts):
                sel = v.charts == c
                tv = cv[cf[sel]].reshape(-1, 3)
                g["charts"].append(sc.add_mesh_simple(
                    f"/obj{i}/charts/c{c}", tv * MM, np.arange(len(tv)).reshape(-1, 3),
                    color=tuple(int(x) for x in PALETTE[c % len(PALETTE)]), flat_shading=True, visible=False))
            for k, (pv, pf) in enumerate(v.pieces):
                g["pieces"].append(sc.add_mesh_simple(
                    f"/obj{i}/pieces/p{k}", pv * MM, pf, color=tuple(int(x) for x in PALETTE[k % len(PALETTE)]),
                    opacity=0.55, visible=False))
            R = rotate(o["orientation"], cv) + o["position"]
            lo, hi = np.minimum(lo, R.min(axis=0)), np.maximum(hi, R.max(axis=0))
        centre, extent = (lo + hi) / 2 * MM, float(np.max(hi - lo)) * MM
        cam = self.server.initial_camera
        cam.look_at = tuple(centre)
        cam.position = tuple(centre + np.array([0.55, -0.85, 0.5]) * max(extent, 1.0))
        cam.near = max(extent, 1.0) * 1e-3
        cam.far = max(extent, 1.0) * 100
        self.extent = extent
        if self.mode in ("live", "replay"):
            cv, cf = self.views[0].coarse
            self.ghost = sc.add_mesh_simple("/target/ghost", cv * MM, cf, color=(0, 160, 90), wireframe=True,
                                            opacity=0.35)
            self.gizmo = None
            if self.mode == "live" and self.virtual:
                o = self.objects[0]
                self.gizmo = sc.add_transform_controls("/gizmo", scale=0.3 * max(extent, 1.0),
                                                       position=tuple(o["position"] * MM),
                                                       wxyz=wxyz(o["orientation"]))
                self.gizmo.on_update(lambda _: self.drag_to(np.asarray(self.gizmo.position) / MM,
                                                            xyzw(self.gizmo.wxyz), from_gizmo=True))

    # -- the panel -----------------------------------------------------------------
    def _build_gui(self):
        gui = self.server.gui
        gui.add_markdown(f"**{self.mode}**: " + ", ".join(f"`{o['name']}`" for o in self.objects))
        with gui.add_folder("Show"):
            self.cb = {}
            for key, label, on in (("surface", "full surface (atlas)", True), ("coarse", "coarse mesh", False),
                                   ("pieces", "convex pieces", False), ("charts", "atlas charts", False)):
                cb = gui.add_checkbox(label, initial_value=on)
                cb.on_update(lambda _, key=key, cb=cb: self._toggle(key, cb.value))
                self.cb[key] = cb
        self.txt = {}
        if self.mode == "bundle":
            v = self.views[0]
            gui.add_markdown(f"{len(v.coarse[1])} coarse triangles, {len(v.pieces)} pieces, "
                             f"{len(np.unique(v.charts))} charts, {len(v.surface[1])} surface triangles drawn")
            return
        with gui.add_folder("Frame"):
            for key in ("t", "frame", "patches", "force", "torque", "depth", "rate"):
                self.txt[key] = gui.add_text(key, initial_value="", disabled=True)
        gui.add_markdown(f"Arrows: force {self.force_scale:.3g} mm/N (red), torque "
                         f"{self.torque_scale:.3g} mm/(N m) (blue); patch windows yellow, normals n "
                         "from the probe into the other object; the coupling target green.")
        x0 = np.zeros(2)
        self.plots = {
            "force": gui.add_uplot((x0, x0, x0, x0), ({"label": "t (s)"}, {"label": "Fx (N)", "stroke": "red"},
                                   {"label": "Fy", "stroke": "green"}, {"label": "Fz", "stroke": "blue"}),
                                   title="contact force", aspect=2.0, scales={"x": {"time": False}}),
            "torque": gui.add_uplot((x0, x0, x0, x0), ({"label": "t (s)"}, {"label": "Tx (N m)", "stroke": "red"},
                                    {"label": "Ty", "stroke": "green"}, {"label": "Tz", "stroke": "blue"}),
                                    title="contact torque", aspect=2.0, scales={"x": {"time": False}}),
            "depth": gui.add_uplot(
                (x0,) * (DEPTH_SERIES + 2),
                ({"label": "t (s)"},
                 *({"label": f"delta {k + 1} (mm)" + (" (0: none)" if k else ""), "stroke": s, "scale": "mm"}
                   for k, s in enumerate(("black", "gray", "teal", "olive")[:DEPTH_SERIES])),
                 {"label": "patches", "stroke": "orange", "scale": "n"}),
                scales={"x": {"time": False}, "mm": {"auto": True}, "n": {"auto": True}},
                axes=({}, {"scale": "mm"}, {"scale": "n", "side": 1}),
                title="depth per patch (deepest first), patches", aspect=2.0),
            "rate": gui.add_uplot((x0, x0), ({"label": "t (s)"}, {"label": "frames/s", "stroke": "purple"}),
                                  title=("achieved simulation rate" if self.mode == "live"
                                         else "recorded frame rate if alone (1 / total_us)"), aspect=2.5,
                                  scales={"x": {"time": False}}),
        }
        self.rates: deque = deque()
        if self.mode == "replay":
            n = len(self.trace)
            with gui.add_folder("Replay"):
                self.slider = gui.add_slider("frame", min=0, max=max(n - 1, 1), step=1, initial_value=0)
                self.slider.on_update(lambda _: self.show_frame(int(self.slider.value)) if not self._playing else None)
                self.play_cb = gui.add_checkbox("play", initial_value=False)
                self.speed = gui.add_slider("speed", min=0.05, max=4.0, step=0.05, initial_value=1.0)
            self._playing = False
            from hbake.viz import sound
            sig = sound.trace_vibration(self.trace)
            self._audio_html(sound.wav_bytes(sig), f"the texture's vibration over the whole trace "
                                                   f"({self.trace['t'][-1] - self.trace['t'][0]:.2f} s)")
        else:
            with gui.add_folder("Session"):
                self.pause_cb = gui.add_checkbox("pause", initial_value=False)
                b = gui.add_button("sound of the last seconds")
                b.on_click(lambda _: self._live_sound())
                # A new clip of the last seconds every SOUND_SECONDS of wall time, played as
                # it arrives (the page may play sound once it has been clicked).
                self.live_sound_cb = gui.add_checkbox("sound, live", initial_value=False)
            self.audio = None

    def _audio_html(self, wav: bytes, caption: str, autoplay: bool = False):
        src = "data:audio/wav;base64," + base64.b64encode(wav).decode("ascii")
        play = " autoplay" if autoplay else ""
        html = f'<div><small>{caption}</small><br><audio id="hbake-audio" controls{play} src="{src}"></audio></div>'
        if getattr(self, "audio", None) is not None:
            self.audio.content = html
        else:
            self.audio = self.server.gui.add_html(html)

    def _live_sound(self, autoplay: bool = False):
        from hbake.viz import sound
        with self.lock:
            h = list(self.history)
        t = np.array([x[0] for x in h])
        if len(t) < 2:
            return
        m = t >= t[-1] - SOUND_SECONDS
        f = np.array([x[1][:3] for x in h])[m]
        sig = sound.vibration(t[m], f)
        self._audio_html(sound.wav_bytes(sig), f"the last {t[m][-1] - t[m][0]:.2f} s of the session "
                                               f"(to t = {t[-1]:.2f} s)", autoplay)

    def _toggle(self, key: str, on: bool):
        with self.server.atomic():
            for handle in self.groups[key]:
                handle.visible = on

    # -- frames --------------------------------------------------------------------
    def drag_to(self, position, q_xyzw, from_gizmo: bool = False):
        """Moves the virtual device's handle so that the coupling target is this pose of
        the probe's object frame (scene frame, metres): what dragging the gizmo does."""
        if self.runner is None or not self.virtual:
            raise HbakeError("drag_to: only a live session with the virtual device has a handle to move", 2)
        pose = np.concatenate([np.asarray(position, float), np.asarray(q_xyzw, float)])
        with self.lock:
            self.runner.set_device_pose(self.runner.target_to_device(pose))
        if not from_gizmo and self.gizmo is not None:
            self.gizmo.position = tuple(pose[:3] * MM)
            self.gizmo.wxyz = wxyz(pose[3:])

    def step(self, frames: int = 1):
        """Runs ``frames`` simulation frames of a live session now (for scripts and tests;
        the page is updated after the last)."""
        fr = None
        for _ in range(frames):
            with self.lock:
                fr = self.runner.step()
            if fr is None:
                break
            self._frame_dict(fr)
        self._display()
        return self.last

    def _frame_dict(self, fr):
        if fr is None:
            return
        c = fr["contacts"]
        self.last = {"t": float(fr["t"]), "frame": int(fr["frame"]), "probe": np.asarray(fr["probe"]),
                     "target": np.asarray(fr["target"]), "poses": np.asarray(fr["poses"]),
                     "force": np.asarray(fr["contact"][:3]), "torque": np.asarray(fr["contact"][3:]),
                     "device_output": np.asarray(fr["device_output"]), "patches": int(fr["patches"]),
                     "contacts": c}
        # 0 where there are fewer patches: uPlot's ranges do not skip NaN.
        d = np.zeros(DEPTH_SERIES)
        deepest = np.sort(np.asarray(c["delta"], float))[::-1][:DEPTH_SERIES]
        d[:len(deepest)] = deepest
        with self.lock:
            self.history.append((self.last["t"], np.asarray(fr["contact"]), d, self.last["patches"]))
            while self.history and self.history[0][0] < self.last["t"] - max(PLOT_SECONDS, SOUND_SECONDS):
                self.history.popleft()

    def _run_live(self):
        t_wall0 = time.perf_counter()
        t_sim0 = self.last.get("t", 0.0)
        n, t_rate = 0, time.perf_counter()
        t_sound = time.perf_counter()
        while not self.stop_event.is_set():
            if self.live_sound_cb.value and time.perf_counter() - t_sound >= SOUND_SECONDS:
                t_sound = time.perf_counter()
                self._live_sound(autoplay=True)
            if self.pause_cb.value:
                time.sleep(0.05)
                t_wall0, t_sim0 = time.perf_counter(), self.last.get("t", 0.0)
                continue
            # Lockstep paced to the wall clock: never ahead of it.
            ahead = (self.last.get("t", 0.0) - t_sim0) - (time.perf_counter() - t_wall0)
            if ahead > 0:
                time.sleep(min(ahead, 0.01))
                continue
            with self.lock:
                fr = self.runner.step()
            if fr is None:
                break
            self._frame_dict(fr)
            n += 1
            now = time.perf_counter()
            if now - t_rate >= 0.5:
                self.sim_rate, n, t_rate = n / (now - t_rate), 0, now
                with self.lock:
                    self.rates.append((self.last["t"], self.sim_rate))
                    while self.rates and self.rates[0][0] < self.last["t"] - PLOT_SECONDS:
                        self.rates.popleft()
            if now - self._last_display >= 1.0 / DISPLAY_HZ:
                self._display()

    def show_frame(self, k: int):
        """A replay at row ``k`` of the trace (0-based): poses, patches and readouts."""
        tr = self.trace
        k = int(np.clip(k, 0, len(tr) - 1))
        t = float(tr["t"][k])
        poses = [np.concatenate([tr.vec("probe_")[k], tr.vec("probe_", ("qx", "qy", "qz", "qw"))[k]])]
        for o in self.objects[1:]:
            p, q = object_pose_at(o, t)
            poses.append(np.concatenate([p, q]))
        P = np.ascontiguousarray(np.array(poses))
        P[:, 3:] /= np.linalg.norm(P[:, 3:], axis=1, keepdims=True)
        with self.lock:
            self.scene_query.reset()
            r = self.scene_query.query(P)
        force = tr.vec("contact_f")[k]
        torque = tr.vec("contact_t")[k]
        self.last = {"t": t, "frame": int(tr["frame"][k]) if "frame" in tr.index else k + 1, "probe": P[0],
                     "target": np.concatenate([tr.vec("target_")[k], tr.vec("target_", ("qx", "qy", "qz", "qw"))[k]]),
                     "poses": P, "force": force, "torque": torque, "patches": int(tr["patches"][k]),
                     "contacts": r["patches"], "row": k}
        t0 = t - PLOT_SECONDS
        m = (tr["t"] >= t0) & (np.arange(len(tr)) <= k)
        ts = tr["t"][m]
        # A trace records no depths: the plot shows the patch count.
        self._plot(ts, tr.vec("contact_f")[m], tr.vec("contact_t")[m], np.zeros((len(ts), DEPTH_SERIES)),
                   tr["patches"][m])
        if "total_us" in tr.index and len(ts) >= 2:
            us = tr["total_us"][m]
            self.plots["rate"].data = (ts, np.where(us > 0, 1e6 / np.maximum(us, 1e-9), 0.0))
        self._display(plots=False)

    def _run_replay(self):
        """Play: the replay's session time advances by the wall time times the speed; the
        frame shown is the last one at or before it; at the end it starts over."""
        t = self.trace["t"]
        t_prev = time.perf_counter()
        t_play = None
        while not self.stop_event.is_set():
            time.sleep(1.0 / DISPLAY_HZ)
            now = time.perf_counter()
            dt, t_prev = now - t_prev, now
            if not self.play_cb.value:
                self._playing, t_play = False, None
                continue
            self._playing = True
            if t_play is None:  # from the frame shown (the slider's)
                t_play = float(t[self.last.get("row", 0)])
            t_play += dt * float(self.speed.value)
            if t_play > t[-1]:
                t_play = float(t[0])
            k = max(0, int(np.searchsorted(t, t_play, side="right")) - 1)
            if k != self.last.get("row"):
                self.show_frame(k)
                self.slider.value = k

    # -- drawing -------------------------------------------------------------------
    def _plot(self, t, f, tq, depth, patches):
        if len(t) < 2:
            return
        self.plots["force"].data = (t, f[:, 0], f[:, 1], f[:, 2])
        self.plots["torque"].data = (t, tq[:, 0], tq[:, 1], tq[:, 2])
        depth = np.asarray(depth, float).reshape(len(t), -1)
        self.plots["depth"].data = (t, *(depth[:, k] for k in range(DEPTH_SERIES)), np.asarray(patches, float))

    def _display(self, plots: bool = True):
        if not self.last:
            return
        self._last_display = time.perf_counter()
        L = self.last
        sc = self.server.scene
        with self.server.atomic():
            for i, node in enumerate(self.frames):
                p = L["poses"][i]
                node.position = tuple(p[:3] * MM)
                node.wxyz = wxyz(p[3:])
            self.ghost.position = tuple(L["target"][:3] * MM)
            self.ghost.wxyz = wxyz(L["target"][3:])
            c = L["contacts"]
            m = len(c["delta"])
            segs, normals = [], []
            for k in range(m):
                o, u, v, s = (np.asarray(c["window_origin"][k]), np.asarray(c["u"][k]), np.asarray(c["v"][k]),
                              float(c["window_side"][k]))
                q = [o, o + s * u, o + s * u + s * v, o + s * v]
                segs += [[q[j], q[(j + 1) % 4]] for j in range(4)]
                # n from A into B, drawn as an arrow ending at the window's centre.
                mid = o + 0.5 * s * (u + v)
                normals.append([mid - 0.25 * s * np.asarray(c["n"][k]), mid])
            # Overlays are made again each update (adding a node under a name replaces
            # it) and removed when there is nothing to show.
            ov = self.overlays

            def drop(*names):
                for name in names:
                    if ov.get(name) is not None:
                        ov.pop(name).remove()

            if not segs:
                drop("windows", "normals")
            else:
                ov["windows"] = sc.add_line_segments("/patches/windows", np.array(segs) * MM, (230, 200, 0),
                                                     thickness=2.0, thickness_units="screen")
                ov["normals"] = sc.add_arrows("/patches/normals", np.array(normals) * MM, (230, 200, 0),
                                              shaft_radius=0.004 * self.extent, head_radius=0.01 * self.extent,
                                              head_length=0.02 * self.extent)
            com = rotate(L["poses"][0][3:], self.views[0].center_of_mass) + L["poses"][0][:3]
            arrows, colors = [], []
            if np.linalg.norm(L["force"]) > 0:
                arrows.append([com * MM, com * MM + L["force"] * self.force_scale])
                colors.append((220, 30, 30))
            if np.linalg.norm(L["torque"]) > 0:
                arrows.append([com * MM, com * MM + L["torque"] * self.torque_scale])
                colors.append((30, 60, 220))
            if not arrows:
                drop("wrench")
            else:
                ov["wrench"] = sc.add_arrows("/wrench", np.array(arrows), np.array(colors, dtype=np.uint8),
                                             shaft_radius=0.006 * self.extent, head_radius=0.015 * self.extent,
                                             head_length=0.03 * self.extent)
            fmt = lambda v: "[" + ", ".join(f"{x:+.4f}" for x in v) + "]"  # noqa: E731
            self.txt["t"].value = f"{L['t']:.4f} s"
            self.txt["frame"].value = str(L["frame"])
            self.txt["patches"].value = str(L["patches"])
            self.txt["force"].value = fmt(L["force"]) + " N"
            self.txt["torque"].value = fmt(L["torque"]) + " N m"
            d = np.asarray(c["delta"])
            self.txt["depth"].value = ", ".join(f"{x * 1e3:.4f}" for x in d) + " mm" if len(d) else "no patch"
            self.txt["rate"].value = (f"{self.sim_rate:.0f} frames/s" if self.mode == "live" and self._thread
                                      else "stepped" if self.mode == "live" else "replay")
            if plots and self.mode == "live":
                with self.lock:
                    h = list(self.history)
                t = np.array([x[0] for x in h])
                sel = t >= t[-1] - PLOT_SECONDS if len(t) else np.zeros(0, bool)
                w = np.array([x[1] for x in h])[sel] if len(t) else np.zeros((0, 6))
                self._plot(t[sel], w[:, :3], w[:, 3:], np.array([x[2] for x in h])[sel] * 1e3,
                           np.array([x[3] for x in h])[sel])
                with self.lock:
                    r = list(self.rates)
                if len(r) >= 2:
                    self.plots["rate"].data = (np.array([x[0] for x in r]), np.array([x[1] for x in r]))

    def wait(self):
        """Serves until Ctrl-C (or the live session's end)."""
        try:
            while not self.stop_event.is_set():
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
