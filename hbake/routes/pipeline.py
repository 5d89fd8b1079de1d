"""``hbake.bake``: run the stages and write the bundle.

Cage-bake route (``method = "cage"``), data flow per stage:

    load         file                         -> full mesh (m, repaired)
    simplify     full mesh                    -> coarse mesh (float32, outward)
    parameterize coarse mesh                  -> per-corner UVs, atlas size
    bake         coarse + UVs + full mesh     -> atlas (f of Sec. 5.1), displacement bounds
    decompose    coarse mesh                  -> convex pieces + piece <-> triangle map
                 (in a thread, alongside parameterize and bake: it needs only the coarse mesh)
    mass         full (or coarse, or hull)    -> volume, centre of mass, inertia
    quality      all of the above             -> reconstruction errors, hull measures
    write        everything                   -> OUT.hbundle (atomic, byte-deterministic)

The parameterization-preserving route of the paper (Sec. 6.1, ``method = "pp"``, alias
``preserve``) replaces simplify, parameterize and bake by hbake/routes/preserve.py's stages
(proxy, charts, transfer, simplify, bake; shown as "pp ..."); ``method = "auto"`` runs
both and keeps one (``preserve_or_auto``). The manifest's ``route`` (format 1.2) says
which and why; decompose, mass, quality and write are shared.
"""
from __future__ import annotations

import os
import platform
import resource
import time
from importlib import metadata
from pathlib import Path

import numpy as np

from hbake import __version__
from hbake.bundle import BundleData, remove_stale_temporaries, write_bundle
from hbake.errors import (EXIT_USAGE, HbakeError, OutputExistsError, OutputUnwritableError)
from hbake.stages.geometry import face_areas, signed_volumes
from hbake.stages.load import load_mesh
from hbake.stages.mass import mass_properties
from hbake.progress import Progress
from hbake.stages.quality import measure
from hbake.settings import BakeSettings
from hbake.routes.auto import preserve_or_auto
from hbake.routes.cage import cage_atlas, start_decompose
from hbake.stages.simplify import simplify

#: Distributions whose versions decide the bundle's bytes (recorded in the manifest).
LIBRARIES = ("numpy", "scipy", "trimesh", "pymeshlab", "fast-simplification", "xatlas",
             "embreex", "coacd", "manifold3d", "OpenEXR")


def library_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "unknown"
    return out


def check_output(output: Path, force: bool) -> None:
    """Fail early (before minutes of work) on an output that cannot be written."""
    if not output.name.endswith(".hbundle"):
        raise HbakeError(f"{output}: the output name must end in .hbundle", EXIT_USAGE)
    parent = output.absolute().parent
    if not parent.is_dir():
        raise OutputUnwritableError(f"output directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputUnwritableError(f"output directory {parent} is not writable")
    if (output.exists() or output.is_symlink()) and not force:
        raise OutputExistsError(f"{output} already exists (use --force to replace it)")


def bake(input, output, settings: BakeSettings | None = None, progress: Progress | None = None,
         *, force: bool = False) -> dict:
    """Bake ``input`` (a mesh file) into the bundle directory ``output``.

    Returns a report: the final manifest, stage wall and CPU timings (s), peak RSS
    (bytes) and the warnings. Raises an ``HbakeError`` subclass for every user-facing failure; on any
    exception (KeyboardInterrupt included) nothing is left at ``output``.
    """
    settings = settings or BakeSettings()
    output = Path(output)
    check_output(output, force)
    progress = progress or Progress(quiet=True)
    t_start = time.perf_counter()
    warnings: list[str] = []

    def warn(msg: str) -> None:
        warnings.append(msg)
        progress.warn(msg)

    # Said on stderr only: the manifest describes the bake, not the output directory.
    for msg in remove_stale_temporaries(output):
        progress.warn(msg)

    with progress.stage("load"):
        full = load_mesh(input, settings.load, warn=warn)
    route = None
    if settings.method == "cage":
        with progress.stage("simplify"):
            coarse = simplify(full.vertices, full.faces, settings.simplify,
                              input_closed=full.closed, warn=warn)
        solid, decomposer = start_decompose(coarse, settings, warn)
        param, baked = cage_atlas(full, coarse, settings, progress, warn)
    else:
        coarse, param, baked, route = preserve_or_auto(input, full, settings, progress, warn)
        solid, decomposer = start_decompose(coarse, settings, warn)
    with progress.stage("decompose"):
        pieces = decomposer.result()
        for w in pieces.warnings:
            warn(w)
    # The stage's own run time (it overlapped parameterize and bake), not the wait for it.
    progress.timings["decompose"] = decomposer.seconds
    with progress.stage("mass"):
        solid_closed = solid is not None
        sv, sf = solid if solid is not None else (coarse.vertices, coarse.faces)
        mass = mass_properties(full.vertices, full.faces, full.closed, sv, sf, solid_closed)
        if mass.basis != "full":
            what = {"coarse": "the coarse mesh" + ("" if coarse.closed else " with its holes capped"),
                    "hull": "the convex hull of the full mesh"}[mass.basis]
            warn(f"mass properties are computed from {what} because the input is not closed")
    coarse_volume = float(signed_volumes(sv, sf).sum()) if solid_closed else None
    with progress.stage("quality", total=3) as update:
        quality, qwarn = measure(
            full_vertices=full.vertices, full_faces=full.faces,
            coarse_vertices=coarse.vertices, coarse_faces=coarse.faces,
            coarse_closed=coarse.closed, uvs=param.uvs, baked=baked, pieces=pieces,
            mass_volume=mass.volume, coarse_volume=coarse_volume,
            samples=settings.quality.samples, seed=settings.seed, progress=update,
            solid=solid if not coarse.closed else None)
        for w in qwarn:
            warn(w)

    manifest = assemble_manifest(settings, full, coarse, param, baked, pieces, mass, quality,
                                 warnings, route)
    data = BundleData(
        coarse_vertices=coarse.vertices,
        coarse_faces=coarse.faces.astype(np.uint32),
        coarse_uvs=param.uvs,
        atlas=baked.image,
        piece_vertices=pieces.vertices,
        piece_faces=[f.astype(np.uint32) for f in pieces.faces],
        piece_coarse_faces=[c.astype(np.uint32) for c in pieces.coarse_faces],
        manifest=manifest)
    with progress.stage("write"):
        final = write_bundle(output, data, force=force, compression=settings.atlas.compression)
    total = time.perf_counter() - t_start
    return {
        "input": str(input),
        "output": str(output),
        "manifest": final,
        "timings": {k: round(v, 4) for k, v in progress.timings.items()},
        "cpu_timings": {k: round(v, 4) for k, v in progress.cpu_timings.items()},
        "total_seconds": round(total, 4),
        "peak_rss_bytes": peak_rss_bytes(),
        "warnings": list(warnings),
        "bake": {"rays": baked.rays, "fallbacks": baked.fallbacks,
                 "border_fallbacks": baked.border_fallbacks,
                 "simplify_scores": coarse.scores},
    }


def peak_rss_bytes() -> int:
    """Peak resident set size of this process (Linux reports KiB)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


def _vec(x) -> list[float]:
    return [float(v) for v in x]


def assemble_manifest(settings, full, coarse, param, baked, pieces, mass, quality,
                      warnings, route=None) -> dict:
    """All manifest fields except format, format_version and files (write_bundle's).
    ``route`` (format 1.2): which route made the bundle and why (``method`` pp or auto)."""
    out = {
        "generator": {"name": "hbake", "version": __version__},
        "units": {"length": "m", "source_unit": full.source_unit,
                  "scale_to_meters": float(full.scale_to_meters)},
        "source": {"name": full.name, "sha256": full.sha256,
                   "vertices": int(len(full.vertices)), "triangles": int(len(full.faces)),
                   "bodies": int(full.bodies), "closed": bool(full.closed),
                   "boundary_edges": int(full.boundary_edges),
                   "repair": {k: int(v) for k, v in full.repair.items()}},
        "method": settings.method,
        "settings": settings.to_dict(),
        "seeds": {"coacd": int(settings.seed), "quality": int(settings.seed)},
        "libraries": library_versions(),
        "coarse": {"vertices": int(len(coarse.vertices)), "triangles": int(len(coarse.faces)),
                   "bbox_min": _vec(coarse.vertices.min(axis=0)),
                   "bbox_max": _vec(coarse.vertices.max(axis=0)),
                   "area": float(face_areas(coarse.vertices, coarse.faces).sum()),
                   "closed": bool(coarse.closed), "placement": coarse.placement,
                   "pre_decimated_faces": int(coarse.pre_decimated_faces)},
        "pieces": {"count": len(pieces.vertices), "map_tolerance": float(pieces.map_tolerance)},
        "atlas": {"width": int(param.width), "height": int(param.height),
                  "gutter": int(baked.gutter), "gutter_setting": int(settings.atlas.gutter),
                  "texel_size": float(baked.texel_size),
                  "coverage": float(baked.coverage), "charts": int(param.charts),
                  "discontinuities": dict(baked.jumps),
                  "packed_width": int(param.packed_width),
                  "packed_height": int(param.packed_height)},
        "mass": mass.to_manifest(),
        "quality": quality,
        "warnings": list(warnings),
    }
    if route is not None:
        out["route"] = route
        # the preserve route's simplifier decides its bytes too (cage manifests unchanged)
        try:
            out["libraries"]["meshoptimizer"] = metadata.version("meshoptimizer")
        except metadata.PackageNotFoundError:
            out["libraries"]["meshoptimizer"] = "unknown"
    # the route that made the bundle ("pp" or "cage"; "auto" is a setting, not a route)
    if route is not None:
        out["method"] = route["chosen"]
    return out
