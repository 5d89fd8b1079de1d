"""The commands of the lab: `hbake bench` (the bake benchmark), `hbake texture` (a relief on
a mesh) and `hbake plot` (the paper's figures from a session trace). Each is a thin layer
over its library module (hbake.lab.bench, hbake.lab.texture, hbake.viz.plot): options in, one call,
the result or one error line out. Registered by hbake/cli/main.py."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import click

from hbake.lab.bench import BENCH_METHODS, MODELS_ENV, run_bench
from hbake.errors import HbakeError
from hbake.viz.plot import DEFAULT_FIGURES, FIGURES, plot_trace
from hbake.lab.texture import (ALONG, DEFAULT_MAX_TRIANGLES, DEFAULT_NORMAL_SMOOTHING, DEFAULT_SAMPLES, MAPPINGS,
                           PATTERNS, PROFILES, Region, TextureSettings, texture_file)

# ----------------------------------------------------------------------------
# hbake bench
# ----------------------------------------------------------------------------


@click.command("bench", context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("models", nargs=-1, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="keep the bundles (and the generated CAD part) here [default: a "
                   "temporary directory, removed]")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="also write the figures and the machine as JSON")
@click.option("--repeat", type=click.IntRange(1), default=1, show_default=True,
              help="runs per model; the table shows medians")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="settings override for every bake, as in `hbake bake --set`")
@click.option("--method", type=click.Choice(BENCH_METHODS), default=None,
              help="baking route of every bake [default: the settings' (cage)]; 'both' bakes "
                   "each model by the cage and the preserve route, rows side by side (a "
                   "preserve bake that cannot reach its target is listed, not failed)")
@click.option("--models-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              envvar=MODELS_ENV, show_envvar=True,
              help="folder of the shared models [default: ../shared/models beside the repository]")
@click.option("--skip-missing", is_flag=True,
              help="leave missing shared models out of the table with a warning instead of failing")
def bench_command(models, out_dir, json_path, repeat, sets, method, models_dir, skip_missing):
    """Bake the shared models and the generated 650k-triangle CAD part; print a table.

    MODELS: mesh files to bake instead (in meters unless the file name is one of
    the shared models). Each bake runs in a fresh process, so peak RSS is per model.
    """
    from hbake.settings import parse_value

    overrides = {}
    for item in sets:
        key, sep, value = item.partition("=")
        if not sep:
            raise click.UsageError(f"--set {item}: expected KEY=VALUE")
        overrides[key.strip()] = parse_value(value.strip())
    if method is not None:
        overrides["method"] = method
    try:
        run_bench(list(models) or None, out_dir, json_path, repeat, overrides,
                  log=lambda msg: click.echo(msg), models_dir=models_dir, allow_missing=skip_missing)
    except (RuntimeError, FileNotFoundError) as exc:
        click.echo(f"hbake bench: error: {exc}", err=True)
        sys.exit(1)


# ----------------------------------------------------------------------------
# hbake plot
# ----------------------------------------------------------------------------


def _plot_vec3(ctx, param, value):
    try:
        v = tuple(float(x) for x in value.split(","))
    except ValueError:
        raise click.BadParameter(f"{value!r}: expected X,Y,Z") from None
    if len(v) != 3 or not all(math.isfinite(x) for x in v) or not any(v):
        raise click.BadParameter(f"{value!r}: expected three finite numbers, not all zero")
    return v


@click.command("plot", context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
               short_help="Figures of a session trace: Fig. 7, 8, 9 styles and a scene picture.")
@click.argument("trace", type=click.Path(path_type=Path, dir_okay=True, readable=False))
@click.option("--figure", "figures", multiple=True, type=click.Choice(FIGURES + ("all",)),
              help="Figure to make (repeatable) [default: fig7, fig8, fig9; 'all' adds the scene "
                   "picture, which needs --scene].")
@click.option("-o", "--out", type=click.Path(path_type=Path, file_okay=False),
              help="Folder of the PNGs, made if missing [default: the trace's folder]; each is named "
                   "<trace stem>.<figure>.png.")
@click.option("--scene", type=click.Path(path_type=Path, readable=False),
              help="The scene file the trace was run from (for the scene picture).")
@click.option("--frame", type=int, help="Frame of the scene picture [default: the middle one].")
@click.option("--axis", callback=_plot_vec3, default="0,0,1", show_default=True, metavar="X,Y,Z",
              help="fig8: the contact normal n (rotation about it, translation along it).")
@click.option("--hrt", "hrt", type=click.Path(path_type=Path),
              help="The hrt binary for the scene picture [default: $HRT, else hrt on PATH].")
@click.option("--audio", is_flag=True,
              help="Also write <trace stem>.wav: the contact force's vibration (above --audio-cutoff) "
                   "as 44.1 kHz mono sound, in real time.")
@click.option("--audio-source", type=click.Choice(["contact", "device"]), default="contact", show_default=True,
              help="The force heard: the texture contact force on the probe, or the force written to the device.")
@click.option("--audio-cutoff", type=click.FloatRange(min=0.1, max=2000.0), default=20.0, show_default=True,
              metavar="HZ", help="High-pass cutoff of the sound (Hz): slower changes are force, not vibration.")
def plot_command(trace, figures, out, scene, frame, axis, hrt, audio, audio_source, audio_cutoff):
    """Make the paper's figures (Fig. 7, 8 and 9 styles, a scene picture) from the trace TRACE of `hrt run`.

    Exit codes: 0 ok, 1 internal error, 2 bad option, 3 trace or scene missing, 4 trace or
    scene invalid, 6 output not writable, 7 hrt query failed.
    """
    figs = list(dict.fromkeys(f for x in (figures or DEFAULT_FIGURES)
                              for f in (FIGURES if x == "all" else (x,))))
    try:
        for p in plot_trace(trace, figs, out, scene, frame, axis, str(hrt) if hrt else None,
                            audio, audio_source, audio_cutoff):
            click.echo(str(p))
    except HbakeError as exc:
        click.echo(f"hbake: error: {exc}", err=True)
        sys.exit(exc.exit_code)


# ----------------------------------------------------------------------------
# hbake texture
# ----------------------------------------------------------------------------


def _texture_vec3(ctx, param, value):
    if value is None:
        return None
    try:
        v = tuple(float(x) for x in value.split(","))
    except ValueError:
        raise click.BadParameter(f"{value!r}: expected X,Y,Z") from None
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise click.BadParameter(f"{value!r}: expected three finite numbers X,Y,Z")
    return v


def _check_pattern(ctx, param, value):
    # A pattern that is no pattern is a usage error (exit 2) before anything is read,
    # not a parameter the texture "cannot honour" (exit 20).
    if value is not None and value not in PATTERNS and not (value.startswith("image:") and len(value) > 6):
        raise click.BadParameter(f"{value!r}: one of {', '.join(PATTERNS)}, image:FILE")
    return value


@click.command("texture", context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.argument("input", type=click.Path(path_type=Path, dir_okay=True, readable=False))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="Mesh file to write (.ply, .obj, .stl, .off), in the input's units.")
@click.option("--pattern", required=True, metavar="ridges|grooves|knurl|bumps|noise|image:FILE",
              callback=_check_pattern, help="The relief (see hbake/lab/texture.py for each formula).")
@click.option("--amplitude", type=float, required=True,
              help="Half the peak-to-peak height of the relief (input units), > 0.")
@click.option("--wavelength", type=float, required=True,
              help="Period of the relief (input units), > 0; the mesh is refined to edges of "
                   "wavelength / --samples where the relief goes.")
@click.option("--profile", type=click.Choice(PROFILES), default="sine", show_default=True,
              help="Cross-section of --pattern ridges (trapezoid: flat tops, a quarter wavelength each).")
@click.option("--flank", type=float, default=0.25, show_default=True,
              help="--profile trapezoid: the fraction of the wavelength each flank takes, in (0, 0.5) "
                   "(the two plateaus share the rest equally).")
@click.option("--along", type=click.Choice(ALONG), default="normal", show_default=True,
              help="Displace along the smoothed vertex normals, or along --axis (a height field: "
                   "exact heights up to the region's rim, e.g. the top of a block).")
@click.option("--fade", type=float, metavar="LENGTH",
              help="Width over which the relief fades out inside the region's border, input units; "
                   "0: none [default: one wavelength].")
@click.option("--mapping", type=click.Choice(MAPPINGS), default="planar", show_default=True,
              help="Surface coordinates of the pattern: planar (normal --axis, u along --direction) or "
                   "cylindrical (about --axis through --origin, u around, v along).")
@click.option("--axis", callback=_texture_vec3, default="0,0,1", show_default=True, metavar="X,Y,Z",
              help="Planar: the projection plane's normal; cylindrical: the cylinder's axis.")
@click.option("--direction", callback=_texture_vec3, default="1,0,0", show_default=True, metavar="X,Y,Z",
              help="Planar: the direction of u, across the ridges (projected on the plane).")
@click.option("--origin", callback=_texture_vec3, metavar="X,Y,Z",
              help="A point of the mapping (phase 0; the cylinder's axis goes through it) "
                   "[default: the centroid of the region's vertices].")
@click.option("--region", "regions", multiple=True, metavar="all|box:X0,Y0,Z0,X1,Y1,Z1|facing:NX,NY,NZ[,DEG]",
              help="Faces to texture: centroid in the box, normal within DEG (default 30) of the "
                   "direction; repeat to intersect [default: all]. The relief fades out over one "
                   "wavelength at the region's border.")
@click.option("--samples", type=int, default=DEFAULT_SAMPLES, show_default=True,
              help="Edges per wavelength after refinement (at least 2).")
@click.option("--normal-smoothing", type=click.IntRange(0, 1000), default=DEFAULT_NORMAL_SMOOTHING,
              show_default=True, help="Rounds of one-ring averaging of the vertex normals that the "
                                      "relief is displaced along.")
@click.option("--max-triangles", type=click.IntRange(1), default=DEFAULT_MAX_TRIANGLES, show_default=True,
              help="The refinement limit: refuse a wavelength that would make more triangles.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of --pattern noise.")
@click.option("-f", "--force", is_flag=True, help="Replace an existing output file.")
@click.option("-q", "--quiet", is_flag=True, help="Print nothing but errors.")
def texture_command(input, output, pattern, amplitude, wavelength, profile, flank, along, fade, mapping, axis, direction,
                    origin, regions, samples, normal_smoothing, max_triangles, seed, force, quiet):
    """Add the relief PATTERN to the mesh INPUT and write OUTPUT (prints the triangle count).

    Exit codes: 0 ok, 1 internal error, 2 bad option, 3 input missing, 4 input invalid,
    5 output exists, 6 output not writable, 20 bad texture parameter, 130 interrupted.
    """
    import sys

    from hbake.errors import EXIT_INTERRUPTED

    try:
        settings = TextureSettings(pattern=pattern, amplitude=amplitude, wavelength=wavelength,
                                   profile=profile, flank=flank, along=along, fade=fade,
                                   mapping=mapping, axis=axis, direction=direction,
                                   origin=origin, region=Region.parse(regions, f"{input}: --region"), samples=samples,
                                   normal_smoothing=normal_smoothing, max_triangles=max_triangles,
                                   seed=seed)
        res = texture_file(input, output, settings, force=force)
    except HbakeError as exc:
        click.echo(f"hbake: error: {exc}", err=True)
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        click.echo("hbake: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    if not quiet:
        click.echo(res.summary(input, output))
