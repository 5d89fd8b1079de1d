"""``method = "pp"`` and ``method = "auto"``: the preserve route, and the choice between it and
the cage route on the two bundles' reconstruction errors (the manifest's ``route``)."""
from __future__ import annotations
from pathlib import Path
import numpy as np
from hbake import constants as C
from hbake.errors import (HbakeError, TargetUnreachableError)
from hbake.stages.simplify import simplify
from hbake.routes.cage import cage_atlas

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


def preserve_or_auto(input, full, settings, progress, warn):
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
    cage_param, cage_baked = cage_atlas(full, cage_coarse, settings, progress, warn)
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
