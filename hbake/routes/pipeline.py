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
both and keeps one (``_preserve_or_auto``). The manifest's ``route`` (format 1.2) says
which and why; decompose, mass, quality and write are shared.
"""
from __future__ import annotations

import os
import platform
import resource
import threading
import time
from importlib import metadata
from pathlib import Path

import numpy as np

from hbake import __version__
from hbake.stages.atlas import bake_atlas
from hbake.bundle import BundleData, remove_stale_temporaries, write_bundle
from hbake.stages.decompose import decompose
from hbake import constants as C
from hbake.errors import (EXIT_USAGE, HbakeError, OutputExistsError, OutputUnwritableError,
                          TargetUnreachableError)
from hbake.stages.geometry import face_areas, signed_volumes
from hbake.stages.load import load_mesh
from hbake.stages.mass import mass_properties
from hbake.stages.parameterize import parameterize
from hbake.progress import Progress
from hbake.stages.quality import measure
from hbake.settings import BakeSettings
from hbake.stages.simplify import cap_holes, simplify

#: Distributions whose versions decide the bundle's bytes (recorded in the manifest).
LIBRARIES = ("numpy", "scipy", "trimesh", "pymeshlab", "fast-simplification", "xatlas",
             "embreex", "coacd", "manifold3d", "OpenEXR")

#: Share of texels whose rays found no surface above which the bake warns.
FALLBACK_WARN_FRACTION = 0.01


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
        solid, decomposer = _start_decompose(coarse, settings, warn)
        param, baked = _cage_atlas(full, coarse, settings, progress, warn)
    else:
        coarse, param, baked, route = _preserve_or_auto(input, full, settings, progress, warn)
        solid, decomposer = _start_decompose(coarse, settings, warn)
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


def _start_decompose(coarse, settings, warn):
    """The coarse mesh's solid (holes capped where open) and the CoACD thread."""
    # An open coarse mesh is decomposed (and weighed) with its holes capped.
    solid = (coarse.vertices, coarse.faces) if coarse.closed else cap_holes(coarse.vertices, coarse.faces)
    if not coarse.closed and solid is not None:
        warn(f"the coarse mesh is open: its holes were capped ({len(solid[1]) - len(coarse.faces)} "
             f"triangles, not stored) for the convex pieces and the mass properties")
    elif not coarse.closed:
        warn("the coarse mesh is open and its holes could not be capped: CoACD remeshes it "
             "(slower, pieces approximate a shell) and mass properties fall back further")
    # CoACD needs only the coarse mesh and releases the GIL, so it runs in a thread while
    # xatlas and embree work: on the 650k CAD part that hides most of its 6.5 s. Its
    # warnings are collected and emitted after it, so their order stays deterministic.
    decomposer = _Background(lambda: decompose(coarse.vertices, coarse.faces, settings.decompose,
                                               seed=settings.seed, solid=solid))
    decomposer.start()
    return solid, decomposer


def _cage_atlas(full, coarse, settings, progress, warn):
    """The cage route's parameterize and bake stages."""
    with progress.stage("parameterize"):
        param = parameterize(coarse.vertices, coarse.faces, settings.parameterize)
    with progress.stage("bake", total=1.0) as update:
        baked = bake_atlas(coarse.vertices, coarse.faces, param.uvs, param.width, param.height,
                           full.vertices, full.faces, settings.cage, settings.atlas,
                           progress=update)
        covered = int(baked.covered.sum())
        if baked.fallbacks > FALLBACK_WARN_FRACTION * covered:
            warn(f"{baked.fallbacks} of {covered} covered texels ({100 * baked.fallbacks / covered:.1f}%) "
                 f"found no surface along the normal within {settings.cage.max_ray_distance:g} of the "
                 f"bbox diagonal and use the closest point instead")
    return param, baked


def route_errors(full, coarse, param, baked, samples: int, seed: int) -> dict:
    """The two-way reconstruction error (p95, in the route's texel sizes) on which
    ``method = "auto"`` chooses (hbake/stages/quality.py's measures, on fewer samples)."""
    from hbake.stages.parameterize import chart_labels
    from hbake.stages.quality import coarse_to_full, full_to_coarse, reconstructed_mesh

    rng_c, rng_f = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    d_cf = coarse_to_full(coarse.vertices, coarse.faces, param.uvs, baked.image, full.vertices,
                          full.faces, samples, rng_c)
    rv, rf = reconstructed_mesh(baked.image, baked.triangle, baked.baked,
                                chart_labels(coarse.faces, np.asarray(param.uvs)))
    d_fc = full_to_coarse(full.vertices, full.faces, rv, rf, samples, rng_f)
    t = baked.texel_size
    return {"triangles": int(len(coarse.faces)), "texel_size": float(t),
            "coarse_to_full_p95_texels": float(np.percentile(d_cf, 95) / t),
            "full_to_coarse_p95_texels": float(np.percentile(d_fc, 95) / t),
            # In metres too: the routes' texels differ, and the choice compares them.
            "p95_m": float(max(np.percentile(d_cf, 95), np.percentile(d_fc, 95))),
            "max_m": float(max(d_cf.max(), d_fc.max()))}


def choose_route(cage_err: dict, pp_err: dict, bound: float, target: int) -> tuple[bool, str]:
    """``method = "auto"``'s choice from the two routes' :func:`route_errors`: (keep the
    preserve bundle?, the one-line reason). The preserve bundle is kept when both its
    reconstruction errors (p95) are within ``bound`` texels and neither its p95 nor its
    worst error (both ways, metres) is more than one cage texel above the cage bundle's: a
    p95 alone kept a preserve bundle whose worst error was 4.4 texels (6.8 mm) against the
    cage's 1.3 mm."""
    worst = max(pp_err["coarse_to_full_p95_texels"], pp_err["full_to_coarse_p95_texels"])
    t_cage = cage_err["texel_size"]
    p95_ok = pp_err["p95_m"] <= cage_err["p95_m"] + t_cage
    max_ok = pp_err["max_m"] <= cage_err["max_m"] + t_cage
    if worst <= bound and p95_ok and max_ok:
        return True, (f"the preserve route reached {pp_err['triangles']} triangles (target "
                      f"{target}) with a reconstruction error of {worst:.3g} texel (p95, "
                      f"the worse way), within the bound of {bound:g}, and its p95 and worst "
                      f"errors ({pp_err['p95_m'] * 1e3:.3g}, {pp_err['max_m'] * 1e3:.3g} mm) within "
                      f"a cage texel of the cage route's ({cage_err['p95_m'] * 1e3:.3g}, "
                      f"{cage_err['max_m'] * 1e3:.3g} mm)")
    if worst > bound:
        return False, (f"the preserve route's reconstruction error is {worst:.3g} texel (p95, the "
                       f"worse way), above the bound of {bound:g}: the cage route is used")
    which, mine, theirs = (("worst", pp_err["max_m"], cage_err["max_m"]) if not max_ok
                           else ("p95", pp_err["p95_m"], cage_err["p95_m"]))
    return False, (f"the preserve route's {which} error ({mine * 1e3:.3g} mm) is more than a cage "
                   f"texel ({t_cage * 1e3:.3g} mm) above the cage route's ({theirs * 1e3:.3g} mm): "
                   f"the cage route is used")


def _preserve_or_auto(input, full, settings, progress, warn):
    """``method = "pp"``: the preserve route (TargetUnreachableError propagates).
    ``method = "auto"``: both routes; the preserve bundle when it reaches the target, both
    its reconstruction errors (p95) are within ``preserve.auto_max_error`` texels, and
    neither its p95 nor its worst error (both ways, metres) is more than one cage texel
    above the cage bundle's (a p95 alone kept a preserve bundle whose worst error was
    4.4 texels against the cage's 1.3 mm); else the cage bundle. A preserve candidate that
    fails for any reason is dropped with its one-line reason: auto never fails where the
    cage route succeeds. Returns (coarse, param, baked, manifest["route"])."""
    from hbake.routes.preserve import bake_preserve

    name = Path(input).name
    target = settings.simplify.target_faces
    pp = pp_error = None
    try:
        pp = bake_preserve(full.vertices, full.faces, settings, input_name=name,
                           input_closed=full.closed, stage=lambda n, t=None: progress.stage(f"pp {n}", t),
                           warn=warn if settings.method == "pp" else None)
    except TargetUnreachableError as exc:
        if settings.method == "pp":
            raise
        pp_error = str(exc)
    except HbakeError as exc:
        if settings.method == "pp":
            raise
        pp_error = f"failed: {exc}"
    if settings.method == "pp":
        return pp.coarse, pp.param, pp.baked, {"requested": "pp", "chosen": "pp",
                                               "reason": "asked for", "pp": pp.stats}
    with progress.stage("cage simplify"):
        cage_coarse = simplify(full.vertices, full.faces, settings.simplify,
                               input_closed=full.closed, warn=warn)
    cage_param, cage_baked = _cage_atlas(full, cage_coarse, settings, progress, warn)
    bound = settings.preserve.auto_max_error
    with progress.stage("auto choice"):
        cage_err = route_errors(full, cage_coarse, cage_param, cage_baked, C.AUTO_SAMPLES, settings.seed)
        cands = {"cage": cage_err}
        if pp is not None:
            pp_err = route_errors(full, pp.coarse, pp.param, pp.baked, C.AUTO_SAMPLES, settings.seed)
            cands["pp"] = {**pp_err, **pp.stats}
            keep, reason = choose_route(cage_err, pp_err, bound, target)
            if keep:
                return pp.coarse, pp.param, pp.baked, {"requested": "auto", "chosen": "pp",
                                                       "reason": reason, "candidates": cands}
        else:
            cands["pp"] = {"error": pp_error}
            reason = (f"the preserve route {pp_error}: the cage route is used" if pp_error.startswith("failed: ")
                      else f"the preserve route cannot reach the target ({pp_error}): the cage route is used")
    warn(reason)
    return cage_coarse, cage_param, cage_baked, {"requested": "auto", "chosen": "cage",
                                                 "reason": reason, "candidates": cands}


class _Background:
    """Runs ``fn`` in a daemon thread; ``result()`` waits and returns its value or raises
    its exception. Daemon: a Ctrl-C in the main thread ends the process without waiting
    for it (nothing of it is written anywhere)."""

    def __init__(self, fn):
        self._fn = fn
        self._value = None
        self._error: BaseException | None = None
        self.seconds = 0.0
        self._thread = threading.Thread(target=self._run, name="hbake-decompose", daemon=True)

    def _run(self):
        t0 = time.perf_counter()
        try:
            self._value = self._fn()
        except BaseException as exc:      # handed to the main thread by result()
            self._error = exc
        finally:
            self.seconds = time.perf_counter() - t0

    def start(self):
        self._thread.start()

    def result(self):
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value


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
