"""The ``hbake`` command: a thin click layer over the library.

``hbake bake`` turns its options into a ``BakeSettings`` (defaults, then ``--config``,
then ``--set``, then the named options) and calls ``hbake.bake``. Every user-facing
failure prints one line, ``hbake: error: <message>``, and exits with the code of its
error class (``hbake.errors``); Ctrl-C and SIGTERM print ``hbake: interrupted`` and
exit with 130, leaving no partial output.
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import click

from hbake import __version__
from hbake.errors import (EXIT_INTERRUPTED, ConfigError, HbakeError, OutputUnwritableError)
from hbake.fileio import write_json_atomic

#: Exit code of an unexpected exception (a bug): distinct from every error class.
EXIT_INTERNAL = 1

CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}


class _OneLineErrors(click.Group):
    """click's usage errors as one line, ``hbake: error: <problem>; see hbake CMD --help``
    (exit 2), like every other hbake error: click's three lines (Usage, Try, Error) are
    hard to read in a batch log and break the one-line rule scripts rely on."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.exceptions.UsageError as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":   # plain `hbake`: the help, as is
                print(exc.format_message(), file=sys.stderr, flush=True)
                sys.exit(exc.exit_code)
            where = exc.ctx.command_path if exc.ctx is not None else "hbake"
            msg = " ".join(exc.format_message().split()).rstrip(".")
            print(f"hbake: error: {msg}; see {where} --help", file=sys.stderr, flush=True)
            sys.exit(exc.exit_code)
        except click.exceptions.ClickException as exc:
            print(f"hbake: error: {' '.join(exc.format_message().split())}", file=sys.stderr, flush=True)
            sys.exit(exc.exit_code)
        except click.exceptions.Abort:
            print("hbake: interrupted", file=sys.stderr, flush=True)
            sys.exit(130)
        sys.exit(rv if isinstance(rv, int) else 0)


@click.group(context_settings=CONTEXT, cls=_OneLineErrors)
@click.version_option(__version__, prog_name="hbake")
def main() -> None:
    """Bake high-resolution meshes into haptic bundles (coarse mesh, haptic texture,
    convex pieces) for 6-DoF haptic texture rendering (Otaduy et al. 2004)."""


def _parse_atlas_size(ctx, param, value):
    if value is None:
        return None
    text = value.lower().strip()
    try:
        if "x" in text:
            w, h = text.split("x", 1)
            size = (int(w), int(h))
        else:
            size = (int(text), int(text))
    except ValueError:
        raise click.BadParameter(f"{value!r}: expected N or WxH, e.g. 1024 or 2048x1024") from None
    if min(size) <= 0:
        raise click.BadParameter(f"{value!r}: sizes must be positive")
    from hbake.constants import MAX_ATLAS_SIDE, MAX_ATLAS_TEXELS
    if max(size) > MAX_ATLAS_SIDE or size[0] * size[1] > MAX_ATLAS_TEXELS:
        raise click.BadParameter(f"{value!r}: at most {MAX_ATLAS_SIDE} texels per side and "
                                 f"{MAX_ATLAS_TEXELS:,} texels in all")
    return size


@main.command("bake", context_settings=CONTEXT)
# readable=False: click's own check would refuse an unreadable input with a usage error
# (exit 2, three lines); hbake.stages.load reports it as exit 3 in one line.
@click.argument("input", type=click.Path(path_type=Path, dir_okay=True, readable=False))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="Bundle directory to write (name ending in .hbundle).")
@click.option("-c", "--config", "config", type=click.Path(path_type=Path, readable=False),
              help="TOML settings file (see configs/); options below override it.")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override any setting, e.g. --set simplify.quality_threshold=0.5 "
                   "(repeatable; VALUE is a TOML value).")
@click.option("--method", type=click.Choice(["cage", "pp", "preserve", "auto"]),
              help="Baking route [default: cage]: 'cage' (rays from the coarse mesh), "
                   "'preserve' or 'pp' (parameterization-preserving simplification, "
                   "Sec. 6.1; exit 9 when it cannot reach --target-faces), 'auto' (both; "
                   "the manifest's route says which was kept and why).")
@click.option("--units", type=click.Choice(["mm", "cm", "m", "in"]),
              help="Unit of the input coordinates [default: from the file, else meters "
                   "with a warning].")
@click.option("--target-faces", type=int, help="Coarse triangle count [default: 600].")
@click.option("--atlas-size", callback=_parse_atlas_size, metavar="N|WxH",
              help="Atlas size in texels [default: 1024].")
@click.option("--gutter", type=int, help="Gutter width in texels [default: 4].")
@click.option("--seed", type=int, help="Seed of CoACD and the quality sampling [default: 0].")
@click.option("--samples", type=int, help="Samples per direction of the reconstruction "
                                          "error [default: 100000].")
@click.option("--report", type=click.Path(path_type=Path),
              help="Also write timings, peak memory and the manifest as JSON here "
                   "(outside the bundle: timings are not deterministic).")
@click.option("-f", "--force", is_flag=True, help="Replace an existing bundle.")
@click.option("-q", "--quiet", is_flag=True,
              help="No progress, summary or warnings (errors are still printed). Progress "
                   "is a bar per stage on a terminal, else one line per completed stage on "
                   "stderr ('hbake: stage NAME SECONDS s').")
@click.option("--json", "as_json", is_flag=True,
              help="Print the report (as --report writes it, plus \"ok\": true) as JSON on "
                   "stdout instead of the summary; on an error {\"ok\": false, \"error\": "
                   "{class, exit_code, message}} (the line on stderr stays).")
def bake_command(input, output, config, sets, method, units, target_faces, atlas_size,
                 gutter, seed, samples, report, force, quiet, as_json=False):
    """Bake INPUT (OBJ, PLY, STL, OFF, glTF/GLB) into the bundle OUTPUT.

    Exit codes: 0 ok, 1 internal error, 2 bad option, 3 input missing, 4 input invalid,
    5 output exists, 6 output not writable, 7 bake failed, 8 bad config, 130 interrupted.
    """
    # SIGINT and SIGTERM both end the bake cleanly. The bake itself runs in a forked
    # child (hbake.guard): this process stays able to react while a native library
    # holds the GIL, kills the child on a signal and removes its temporary bundle.
    from hbake.guard import interrupts_end_the_command

    with interrupts_end_the_command():
        try:
            settings = build_settings(config, sets, method=method, units=units,
                                      target_faces=target_faces, atlas_size=atlas_size,
                                      gutter=gutter, seed=seed, samples=samples)
            if report is not None:
                _check_report_path(report)
        except HbakeError as exc:
            click.echo(f"hbake: error: {exc}", err=True)
            if as_json:
                _echo_json_error(exc.exit_code, str(exc))
            sys.exit(exc.exit_code)
        from hbake.guard import run_guarded

        code = run_guarded(lambda: _bake_here(input, output, settings, report, force, quiet,
                                              as_json), output, report)
    sys.exit(code)


def _bake_here(input, output, settings, report, force, quiet, as_json=False) -> int:
    """The bake in this process; returns the exit code (messages already printed)."""
    from hbake.progress import Progress

    progress = None
    try:
        from hbake.routes.pipeline import bake

        progress = Progress(quiet=quiet)
        result = bake(input, output, settings, progress, force=force)
        progress.close()
        if report is not None:
            _write_json(report, result)
        if as_json:
            click.echo(json.dumps({"ok": True, **result}, indent=2, sort_keys=True))
        elif not quiet:
            print_summary(result)
        return 0
    except HbakeError as exc:
        if progress is not None:
            progress.close()
        # Every error names the file it is about: a stage deep in the bake (a convex hull
        # that fails) does not know the input's name, so it is added here.
        msg = str(exc)
        if Path(input).name not in msg and str(output) not in msg:
            msg = f"{input}: {msg}"
        click.echo(f"hbake: error: {msg}", err=True)
        if as_json:
            _echo_json_error(exc.exit_code, msg)
        return exc.exit_code
    except KeyboardInterrupt:
        if progress is not None:
            progress.close()
        click.echo("hbake: interrupted", err=True)
        return EXIT_INTERRUPTED
    except Exception as exc:  # a bug, or a library failing in a way we do not know yet
        if progress is not None:
            progress.close()
        if os.environ.get("HBAKE_DEBUG"):
            raise
        click.echo(f"hbake: internal error: {type(exc).__name__}: {exc} "
                   f"(set HBAKE_DEBUG=1 for a traceback; please report it)", err=True)
        return EXIT_INTERNAL


def _echo_json_error(code: int, message: str) -> None:
    """--json's answer on a user error (stdout), beside the line on stderr."""
    from hbake.errors import error_class

    click.echo(json.dumps({"ok": False, "error": {"class": error_class(code), "exit_code": code,
                                                  "message": message}}, sort_keys=True))


def build_settings(config=None, sets=(), **named):
    """Defaults < --config < --set < named options; returns a BakeSettings."""
    from hbake.settings import BakeSettings, parse_value

    settings = BakeSettings.from_toml(config) if config is not None else BakeSettings()
    overrides = {}
    for item in sets:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {item}: expected KEY=VALUE")
        overrides[key.strip()] = parse_value(value.strip())
    mapping = {"method": "method", "units": "load.units", "target_faces": "simplify.target_faces",
               "gutter": "atlas.gutter", "seed": "seed", "samples": "quality.samples"}
    for name, key in mapping.items():
        if named.get(name) is not None:
            overrides[key] = named[name]
    if named.get("atlas_size") is not None:
        overrides["parameterize.atlas_width"], overrides["parameterize.atlas_height"] = named["atlas_size"]
    if overrides:
        settings = settings.with_overrides(overrides, source="command line")
    return settings


def _check_report_path(path: Path) -> None:
    parent = path.absolute().parent
    if not parent.is_dir():
        raise OutputUnwritableError(f"--report: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputUnwritableError(f"--report: directory {parent} is not writable")


def _write_json(path: Path, data: dict) -> None:
    write_json_atomic(path, data, "--report")


def _len(x: float) -> str:
    """A length in the most readable of m, mm, um."""
    a = abs(x)
    if a >= 0.1 or a == 0:
        return f"{x:.4g} m"
    if a >= 1e-4:
        return f"{x * 1e3:.4g} mm"
    return f"{x * 1e6:.4g} um"


def print_summary(result: dict) -> None:
    """The summary table of a bake (stdout)."""
    from rich.console import Console
    from rich.table import Table

    m = result["manifest"]
    q = m["quality"]
    texel = m["atlas"]["texel_size"]
    table = Table(title=f"hbake: {m['source']['name']} -> {result['output']}", show_header=False,
                  title_justify="left")
    table.add_column("what", style="bold")
    table.add_column("value")
    rows = []
    route = m.get("route")
    if route:
        # Which route made the bundle and why (with --method auto: the choice).
        rows.append(("route", f"{route.get('chosen')} ({route.get('requested')}): {route.get('reason')}"))
    rows += [
        ("triangles", f"{m['source']['triangles']:,} -> {m['coarse']['triangles']:,} coarse"),
        ("convex pieces", f"{m['pieces']['count']}"),
        ("atlas", f"{m['atlas']['width']} x {m['atlas']['height']}, texel {_len(texel)}, "
                  f"coverage {100 * m['atlas']['coverage']:.1f}%"),
        ("min wavelength", _len(q["min_wavelength"])),
        ("displacement", f"out {_len(q['displacement_outward'])}, in {_len(q['displacement_inward'])}"),
        ("hull deviation", f"{_len(q['hull_deviation'])}, volume excess "
                           f"{100 * q['hull_volume_excess']:.1f}%"),
    ]
    for key, label in (("coarse_to_full", "error coarse->full"), ("full_to_coarse", "error full->coarse")):
        e = q["reconstruction"][key]
        rows.append((label, f"mean {_len(e['mean'])}, p95 {_len(e['p95'])} "
                            f"({e['p95'] / texel:.2g} texel), max {_len(e['max'])}"))
    u = q["reconstruction"].get("coarse_to_full_uncut")
    if u is not None:
        rows.append(("coarse->full, uncut", f"max {_len(u['max'])} ({u['max'] / texel:.2g} texel), "
                                             f"{u['cut_samples']} of {u['samples'] + u['cut_samples']} "
                                             f"samples in quads with a discontinuity"))
    dc = m["atlas"].get("discontinuities")
    if dc is not None:
        rows.append(("discontinuities", f"{dc['cut']:,} cut edges (> {dc['rule_texels']:g} texels); "
                                        f"{dc['off_before']} -> {dc['off_after']} chords off the surface "
                                        f"by > {dc['repair_threshold_texels']:g} texel, "
                                        f"{dc['texels_moved']} texels re-chosen"))
    ms = m["mass"]
    rows.append(("mass (unit density)", f"{ms['basis']}: volume {ms['volume']:.4g} m^3, "
                                        f"COM [{', '.join(f'{c:.4g}' for c in ms['center_of_mass'])}]"))
    rows.append(("time", ", ".join(f"{k} {v:.2f}s" for k, v in result["timings"].items())
                 + f"; total {result['total_seconds']:.1f} s (decompose runs alongside "
                   f"parameterize and bake)"))
    rows.append(("peak memory", f"{result['peak_rss_bytes'] / 2**20:,.0f} MiB"))
    if m["warnings"]:
        rows.append(("warnings", f"{len(m['warnings'])} (in manifest.json)"))
    for r in rows:
        table.add_row(*r)
    Console(soft_wrap=False).print(table)


# --- other commands --------------------------------------------------------------------
from hbake.cli.bundle import inspect, validate  # noqa: E402

main.add_command(validate)
main.add_command(inspect)

from hbake.cli.lab import bench_command  # noqa: E402

main.add_command(bench_command, "bench")

from hbake.cli.lab import texture_command  # noqa: E402

main.add_command(texture_command, "texture")

from hbake.cli.lab import plot_command  # noqa: E402

main.add_command(plot_command, "plot")

from hbake.cli.view import view_command  # noqa: E402

main.add_command(view_command, "view")

from hbake.cli.batch import batch_command, report_command  # noqa: E402

main.add_command(batch_command, "batch")
main.add_command(report_command, "report")


@main.command("generate", context_settings=CONTEXT)
@click.argument("name")
@click.argument("path", type=click.Path(path_type=Path))
def generate_command(name, path):
    """Write the procedural test model NAME to PATH (.ply, .stl, .obj, .off; meters).

    Models: ridged_block, ridged_gear, wrinkled_torus, grating, cad_part, rasp."""
    from hbake.lab.procedural import MODELS, generate

    if name not in MODELS:
        click.echo(f"hbake: error: unknown model {name!r} (known: {', '.join(MODELS)})", err=True)
        sys.exit(2)
    try:
        mesh = generate(name, path)
    except KeyboardInterrupt:
        click.echo("hbake: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except (OSError, ValueError) as exc:
        click.echo(f"hbake: error: {path}: {exc}", err=True)
        sys.exit(6)
    click.echo(f"{path}: {name}, {len(mesh.faces):,} triangles (meters)")

