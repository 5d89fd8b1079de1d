"""``hbake report``: an HTML page with pictures of a bundle, rendered headless.

    bundle (+ its source mesh)  -> pieces.png        coarse mesh, convex pieces in distinct colours
                                   atlas_positions.png  RGB = position, scaled to the bbox
                                   atlas_height.png     (f(q) - q) . n per covered texel
                                   error_histogram.png  coarse->full distances of seeded samples
                                   error_map.png        the same, mean per coarse triangle
                                -> index.html         the images and the manifest's figures

matplotlib's Agg backend draws everything (no display, no GPU). The error pictures need
the full-resolution mesh, which a bundle does not hold: ``source`` names it, and it
must be the bundle's source (same SHA-256 as ``manifest.source.sha256``). Each figure of
the page carries its manifest key and the manifest's value as JSON
(``data-key``/``data-value``), so a reader (or the test) can check the page against the
manifest exactly. The directory is written to a temporary sibling and renamed.
"""
from __future__ import annotations

import html
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from hbake.errors import (EXIT_OUTPUT_EXISTS, EXIT_OUTPUT_UNWRITABLE, EXIT_USAGE, BundleError,
                          HbakeError)

#: Manifest sections whose scalar fields the page lists (every leaf, flattened).
FIGURE_SECTIONS = ("source", "units", "coarse", "pieces", "atlas", "mass", "quality")

#: Default number of coarse-surface samples of the error pictures (seeded by the bundle's seed).
DEFAULT_SAMPLES = 20000

#: PNG metadata without matplotlib's version, so the files depend on the data alone.
_PNG_META = {"Software": None}


def flatten_figures(manifest: dict) -> list[tuple[str, object]]:
    """(dotted key, value) of every scalar or short list of FIGURE_SECTIONS."""
    out: list[tuple[str, object]] = []

    def walk(prefix: str, value) -> None:
        if isinstance(value, dict):
            for k in sorted(value):
                walk(f"{prefix}.{k}", value[k])
        else:
            out.append((prefix, value))

    for section in FIGURE_SECTIONS:
        if section in manifest:
            walk(section, manifest[section])
    return out


def _fmt(value) -> str:
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


def _figure_setup():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _set_equal_3d(ax, pts: np.ndarray) -> None:
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c, r = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-12)
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1), zoom=1.35)     # mplot3d's default leaves a wide margin
    ax.set_axis_off()


def piece_colours(n: int) -> np.ndarray:
    """(n, 4) RGBA, one per piece: hues stepped by the golden ratio, so consecutive pieces
    (which CoACD tends to place side by side) differ strongly for any n, unlike a
    qualitative colour map that repeats after 10 or 20."""
    from matplotlib.colors import hsv_to_rgb

    k = np.arange(n)
    hsv = np.stack([(k * 0.6180339887498949) % 1.0, 0.55 + 0.3 * (k % 2),
                    0.95 - 0.2 * ((k // 2) % 2)], axis=1)
    return np.hstack([hsv_to_rgb(hsv), np.ones((n, 1))])


def _draw_pieces(plt, b, path: Path) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    colours = piece_colours(len(b.piece_vertices))
    fig = plt.figure(figsize=(10, 5), dpi=100)
    v, f = b.coarse_vertices, b.coarse_faces.astype(np.int64)
    # Left: the coarse mesh, each triangle in the colour of the first piece that lists it
    # (grey if none); right: the convex pieces themselves.
    owner = np.full(len(f), -1)
    for p, cf in enumerate(b.piece_coarse_faces):
        free = cf[owner[cf] < 0]
        owner[free] = p
    face_col = [colours[o] if o >= 0 else (0.7, 0.7, 0.7, 1.0) for o in owner]
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.add_collection3d(Poly3DCollection(v[f], facecolors=face_col, edgecolors=(0, 0, 0, 0.3),
                                         linewidths=0.3))
    _set_equal_3d(ax, v)
    ax.view_init(elev=25, azim=-60)
    ax.set_title(f"coarse mesh: {len(f)} triangles, coloured by piece")
    ax = fig.add_subplot(1, 2, 2, projection="3d")
    for p, (pv, pf) in enumerate(zip(b.piece_vertices, b.piece_faces)):
        ax.add_collection3d(Poly3DCollection(pv[pf.astype(np.int64)], facecolors=colours[p],
                                             edgecolors=(0, 0, 0, 0.25), linewidths=0.3, alpha=0.9))
    _set_equal_3d(ax, np.vstack(b.piece_vertices))
    ax.view_init(elev=25, azim=-60)
    ax.set_title(f"{len(b.piece_vertices)} convex pieces")
    fig.tight_layout()
    fig.savefig(path, metadata=_PNG_META)
    plt.close(fig)


def texel_heights(b) -> np.ndarray:
    """(H, W) displacement (f(q) - q) . n of each covered texel from the coarse surface
    (m), NaN elsewhere: q is the texel centre's point on its coarse triangle, n that
    triangle's unit normal (the height the depth computation uses, bundle-format.md)."""
    from hbake.stages.atlas import assign_texels

    h, w = b.atlas.shape[:2]
    tri, bary, dist = assign_texels(np.asarray(b.coarse_uvs, dtype=np.float64), w, h)
    covered = (b.atlas[..., 3] == 1.0) & (tri >= 0) & (dist == 0)
    out = np.full((h, w), np.nan)
    t = tri[covered]
    f = b.coarse_faces.astype(np.int64)[t]
    corners = b.coarse_vertices[f]                                   # (n, 3, 3)
    q = np.einsum("nk,nkd->nd", bary[covered], corners)
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    out[covered] = np.einsum("nd,nd->n", b.atlas[covered][:, :3].astype(np.float64) - q, n)
    return out


def _draw_atlas(plt, b, pos_path: Path, height_path: Path) -> dict:
    a = b.atlas.astype(np.float64)
    rgb, alpha = a[..., :3], a[..., 3]
    # Covered texels and the filled gutter (finite, not the 0 of texels far from any chart).
    filled = (np.isfinite(rgb).all(axis=2) & (np.abs(rgb).sum(axis=2) > 0)) | (alpha == 1)
    lo = rgb[filled].min(axis=0) if filled.any() else np.zeros(3)
    hi = rgb[filled].max(axis=0) if filled.any() else np.ones(3)
    img = np.where(filled[..., None], (rgb - lo) / np.maximum(hi - lo, 1e-300), 0.0)
    fig, ax = plt.subplots(figsize=(6, 6 * a.shape[0] / a.shape[1] + 0.6), dpi=100)
    ax.imshow(np.clip(img, 0, 1), origin="upper", interpolation="nearest")   # row 0 = top
    ax.set_title(f"atlas {a.shape[1]} x {a.shape[0]}: position (x, y, z) as (R, G, B)")
    ax.set_xlabel("texel column i")
    ax.set_ylabel("texel row j (row 0 = first scanline)")
    fig.tight_layout()
    fig.savefig(pos_path, metadata=_PNG_META)
    plt.close(fig)

    heights = texel_heights(b)
    # Colours span the 99th percentile of |height|: a few texels far off their triangle's
    # plane (thin parts, folds) would otherwise wash the relief out; they saturate.
    lim = float(np.nanpercentile(np.abs(heights), 99)) if np.isfinite(heights).any() else 1.0
    lim = max(lim, 1e-12)
    fig, ax = plt.subplots(figsize=(6.6, 6 * a.shape[0] / a.shape[1] + 0.6), dpi=100)
    cmap = plt.get_cmap("RdBu_r").copy()
    cmap.set_bad((0.85, 0.85, 0.85))
    im = ax.imshow(heights * 1e6, origin="upper", interpolation="nearest", cmap=cmap,
                   vmin=-lim * 1e6, vmax=lim * 1e6)
    fig.colorbar(im, ax=ax, extend="both",
                 label="displacement along the coarse normal (um; 99th percentile range)")
    ax.set_title("haptic texture: height above the coarse surface")
    ax.set_xlabel("texel column i")
    ax.set_ylabel("texel row j")
    fig.tight_layout()
    fig.savefig(height_path, metadata=_PNG_META)
    plt.close(fig)
    return {"height_min": float(np.nanmin(heights)) if np.isfinite(heights).any() else None,
            "height_max": float(np.nanmax(heights)) if np.isfinite(heights).any() else None}


def reconstruction_errors(b, full_vertices, full_faces, samples: int, seed: int):
    """(face ids, distances m) of ``samples`` seeded area-uniform coarse-surface samples,
    mapped through the atlas (bilinear, as the runtime reads it) to the full surface."""
    from hbake.bundle import atlas_lookup
    from hbake.stages.geometry import closest_points, sample_surface

    rng = np.random.default_rng(seed)
    _, face, bary = sample_surface(b.coarse_vertices, b.coarse_faces.astype(np.int64), samples, rng)
    uv = np.einsum("nk,nkd->nd", bary, np.asarray(b.coarse_uvs, dtype=np.float64)[face])
    mapped = atlas_lookup(b.atlas, uv)[:, :3]
    return face, closest_points(full_vertices, full_faces, mapped)[1]


def _draw_errors(plt, b, face, d, hist_path: Path, map_path: Path) -> dict:
    from matplotlib.colors import Normalize
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    texel = b.manifest["atlas"]["texel_size"]
    rec = b.manifest["quality"]["reconstruction"]["coarse_to_full"]
    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    ax.hist(d * 1e6, bins=60, color="#4477aa")
    ax.set_yscale("log")
    for x, label, c in ((rec["mean"], "mean", "#228833"), (rec["p95"], "p95", "#ee7733"),
                        (rec["max"], "max", "#cc3311")):
        ax.axvline(x * 1e6, color=c, linestyle="--", label=f"manifest {label} {x * 1e6:.3g} um")
    ax.set_xlabel(f"distance of the reconstructed surface to the full mesh (um; texel "
                  f"{texel * 1e6:.3g} um)")
    ax.set_ylabel("samples")
    ax.set_title(f"reconstruction error coarse->full, {len(d):,} samples")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(hist_path, metadata=_PNG_META)
    plt.close(fig)

    v, f = b.coarse_vertices, b.coarse_faces.astype(np.int64)
    sums = np.bincount(face, weights=d, minlength=len(f))
    counts = np.bincount(face, minlength=len(f))
    per_face = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    norm = Normalize(vmin=0.0, vmax=max(float(per_face.max()), 1e-12) * 1e6)
    cmap = plt.get_cmap("viridis")
    fig = plt.figure(figsize=(10, 5), dpi=100)
    for k, azim in enumerate((-60, 120)):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(v[f], facecolors=cmap(norm(per_face * 1e6)),
                                             edgecolors=(0, 0, 0, 0.15), linewidths=0.2))
        _set_equal_3d(ax, v)
        ax.view_init(elev=25, azim=azim)
        ax.set_title(f"view from azimuth {azim} deg")
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=fig.axes, shrink=0.7, label="mean error per coarse triangle (um)")
    fig.suptitle("reconstruction error on the coarse surface")
    fig.savefig(map_path, metadata=_PNG_META)
    plt.close(fig)
    return {"samples": int(len(d)), "mean": float(d.mean()), "p95": float(np.percentile(d, 95)),
            "max": float(d.max())}


_CSS = """body{font-family:sans-serif;margin:2em;max-width:1400px}
#pictures{display:grid;grid-template-columns:1fr 1fr;gap:1em}
figure{margin:0}figure.wide{grid-column:1 / span 2}
img{max-width:100%;border:1px solid #ccc}
table{border-collapse:collapse;font-size:90%}td,th{border:1px solid #ddd;padding:2px 8px;text-align:left}
td.v{font-family:monospace}.warn{color:#a60}"""


def _page(bundle_name: str, manifest: dict, images: list[tuple[str, str]], recomputed: dict | None,
          source_note: str) -> str:
    rows = "\n".join(
        f'<tr><th>{html.escape(k)}</th><td class="v" data-key="{html.escape(k)}" '
        f"data-value='{html.escape(json.dumps(v), quote=True)}'>{html.escape(_fmt(v))}</td></tr>"
        for k, v in flatten_figures(manifest))
    # The 3D views are twice as wide as the atlas pictures: they take a whole row.
    figs = "\n".join(f'<figure{" class=wide" if src in ("pieces.png", "error_map.png") else ""}>'
                     f'<img src="{html.escape(src)}" alt="{html.escape(cap)}">'
                     f"<figcaption>{html.escape(cap)}</figcaption></figure>"
                     for src, cap in images)
    warnings = "".join(f'<li class="warn">{html.escape(w)}</li>' for w in manifest.get("warnings", []))
    rec = ""
    if recomputed:
        rec = ("<p>Recomputed here from the source mesh: "
               + ", ".join(f"{k} {_fmt(v)}" for k, v in recomputed.items())
               + " (m; other samples than the manifest's, so close to but not equal to "
                 "<code>quality.reconstruction.coarse_to_full</code>).</p>")
    gen = manifest.get("generator", {})
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>hbake report: {html.escape(bundle_name)}</title>
<style>{_CSS}</style></head><body>
<h1>{html.escape(bundle_name)}</h1>
<p>Haptic bundle format {html.escape(str(manifest.get('format_version')))}, written by
{html.escape(str(gen.get('name')))} {html.escape(str(gen.get('version')))} from
<code>{html.escape(str(manifest['source']['name']))}</code>. {html.escape(source_note)}</p>
<div id="pictures">
{figs}
</div>
{rec}
<h2>Warnings</h2><ul id="warnings">{warnings or '<li>none</li>'}</ul>
<h2>Figures of manifest.json</h2>
<table id="figures">{rows}</table>
</body></html>
"""


def write_report(bundle: str | os.PathLike, out_dir: str | os.PathLike, *,
                 source: str | os.PathLike | None = None, force: bool = False,
                 samples: int = DEFAULT_SAMPLES) -> dict:
    """Write ``out_dir``/index.html and its PNGs for ``bundle``; return {output, page,
    images, figures, errors}. Raises HbakeError (one line, its exit code)."""
    from hbake.bundle import read_bundle

    bundle, out_dir = Path(bundle), Path(out_dir)
    if (out_dir.exists() or out_dir.is_symlink()) and not force:
        raise HbakeError(f"{out_dir} already exists (use --force to replace it)", EXIT_OUTPUT_EXISTS)
    parent = out_dir.absolute().parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise HbakeError(f"{parent}: output directory missing or not writable", EXIT_OUTPUT_UNWRITABLE)
    try:
        b = read_bundle(bundle)
    except BundleError as exc:
        raise HbakeError(f"{bundle}: {exc.cls}: {exc}", exc.exit_code) from None
    full = None
    if source is not None:
        from hbake.stages.load import load_mesh
        from hbake.settings import BakeSettings

        settings = BakeSettings.from_dict(b.manifest["settings"], source=f"{bundle}/manifest.json")
        full = load_mesh(source, settings.load, warn=lambda msg: None)
        if full.sha256 != b.manifest["source"]["sha256"]:
            raise HbakeError(f"{source}: not the source of {bundle} (its SHA-256 differs from "
                             f"manifest source.sha256)", EXIT_USAGE)

    plt = _figure_setup()
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".tmp", dir=parent))
    try:
        images = [("pieces.png", "Coarse mesh coloured by convex piece (left) and the convex pieces (right)")]
        _draw_pieces(plt, b, tmp / "pieces.png")
        heights = _draw_atlas(plt, b, tmp / "atlas_positions.png", tmp / "atlas_height.png")
        images += [("atlas_positions.png", "Atlas: full-surface position of each texel as a colour"),
                   ("atlas_height.png", "Atlas: displacement from the coarse surface (height map)")]
        errors = None
        if full is not None:
            face, d = reconstruction_errors(b, full.vertices, full.faces, samples,
                                            int(b.manifest["seeds"]["quality"]))
            errors = _draw_errors(plt, b, face, d, tmp / "error_histogram.png", tmp / "error_map.png")
            images += [("error_histogram.png", "Reconstruction error coarse->full: histogram"),
                       ("error_map.png", "Reconstruction error on the coarse surface")]
            note = f"Error pictures from {samples:,} samples against {Path(source).name}."
        else:
            note = ("No source mesh given (--source): the error pictures need the full-resolution "
                    "mesh; the manifest's error figures are below.")
        (tmp / "index.html").write_text(_page(bundle.name, b.manifest, images, errors, note),
                                        encoding="utf-8")
        (tmp / "manifest.json").write_bytes((bundle / "manifest.json").read_bytes())
        os.chmod(tmp, 0o755)
        if out_dir.exists() or out_dir.is_symlink():
            old = out_dir.with_name(f".{out_dir.name}.{os.getpid()}.old")
            os.rename(out_dir, old)
            os.rename(tmp, out_dir)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, out_dir)
    except OSError as exc:
        raise HbakeError(f"{out_dir}: cannot write the report: {exc.strerror or exc}",
                         EXIT_OUTPUT_UNWRITABLE) from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return {"output": str(out_dir), "page": str(out_dir / "index.html"),
            "images": [str(out_dir / src) for src, _ in images],
            "figures": dict(flatten_figures(b.manifest)), "errors": errors, "heights": heights}
