"""`hbake validate` and `hbake inspect`: thin click commands over hbake.bundle.

hbake/cli/main.py adds both to the `hbake` group. Output goes to stdout (it is the
command's result); the exit code of `validate` is the one of the first
problem's error class (docs/bundle-format.md, hbake.errors.VALIDATE_EXIT).
"""
from __future__ import annotations

import json
import sys

import click

from hbake.bundle import check_bundle, check_bundle_data
from hbake.bundle.surface_coverage import surface_coverage
from hbake.errors import VALIDATE_EXIT

__all__ = ["validate", "inspect"]


@click.command("validate")
@click.argument("bundle", type=click.Path(file_okay=True, dir_okay=True, path_type=str))
@click.option("--json", "as_json", is_flag=True, default=False,
              help="Print {path, valid, exit_code, problems: [{class, message}], surface} as JSON "
                   "instead of the lines (same exit code).")
def validate(bundle: str, as_json: bool = False) -> None:
    """Check BUNDLE against the format spec.

    Prints 'BUNDLE: OK', or one line 'BUNDLE: <class>: <message>' per problem
    (classes io, version, schema, hash, mesh, atlas, pieces). Exit code 0 when
    valid, else that of the first problem's class: io 10, version 11, schema 12,
    hash 13, mesh 14, atlas 15, pieces 16.

    A valid bundle whose atlas has quads cut by a discontinuity inside the coarse UV
    triangles gets a second line, 'BUNDLE: note: surface: ...': where the runtime's
    mesh heights see no surface (docs/bundle-format.md, "Heights over a texel's
    square"). It is not a problem (exit 0)."""
    _, problems, data = check_bundle_data(bundle)
    surface = surface_coverage(data) if data is not None else None
    if as_json:
        code = VALIDATE_EXIT[problems[0].cls] if problems else 0
        click.echo(json.dumps({"path": bundle, "valid": not problems, "exit_code": code,
                               "problems": [{"class": p.cls, "message": p.message}
                                            for p in problems],
                               "surface": surface}, indent=2, sort_keys=True))
        sys.exit(code)
    if not problems:
        click.echo(f"{bundle}: OK")
        if surface and surface["cut_quads"]:
            click.echo(f"{bundle}: note: surface: {surface['cut_quads']:,} of the {surface['quads']:,} atlas "
                       f"quads inside the UV triangles are cut by a discontinuity (corners up to "
                       f"{_length(surface['widest_cut'])} apart): the mesh heights see no surface there")
        sys.exit(0)
    for p in problems:
        click.echo(f"{bundle}: {p.cls}: {p.message}")
    sys.exit(VALIDATE_EXIT[problems[0].cls])


def _length(x: float) -> str:
    """A length in metres with a readable unit."""
    ax = abs(x)
    if ax == 0:
        return "0 m"
    if ax >= 1:
        return f"{x:.4g} m"
    if ax >= 1e-3:
        return f"{x * 1e3:.4g} mm"
    return f"{x * 1e6:.4g} um"


def _vec(v) -> str:
    return "[" + ", ".join(f"{float(c):.4g}" for c in v) + "]"


def _bytes(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n} B"


def _summary_rows(m: dict) -> list[tuple[str, str]]:
    src, units, coarse, atlas = m["source"], m["units"], m["coarse"], m["atlas"]
    files, mass, q = m["files"], m["mass"], m["quality"]
    fa = files["atlas"]
    rec = q["reconstruction"]
    rows = [
        ("format", f"{m['format']} {m['format_version']}, written by {m['generator']['name']} "
                   f"{m['generator']['version']}, method {m['method']}"),
        ("source", f"{src['name']}: {src['vertices']:,} vertices, {src['triangles']:,} triangles, "
                   f"{src['bodies']} {'body' if src['bodies'] == 1 else 'bodies'}, "
                   f"{'closed' if src['closed'] else 'open'}; "
                   f"unit {units['source_unit']} (x {units['scale_to_meters']:g} to m)"),
        ("coarse", f"{coarse['vertices']:,} vertices, {coarse['triangles']:,} triangles, "
                   f"area {coarse['area']:.4g} m^2, bbox {_vec(coarse['bbox_min'])} - {_vec(coarse['bbox_max'])} m"),
        ("atlas", f"{atlas['width']} x {atlas['height']} {'/'.join(fa['channels'])} {fa['pixel_type']} "
                  f"{fa['compression'].upper()}, gutter {atlas['gutter']}, texel {_length(atlas['texel_size'])}, "
                  f"coverage {100 * atlas['coverage']:.1f} %"),
        ("pieces", f"{m['pieces']['count']} convex {'piece' if m['pieces']['count'] == 1 else 'pieces'}, map tolerance {_length(m['pieces']['map_tolerance'])}"),
        ("mass", f"basis {mass['basis']}, volume {mass['volume']:.4g} m^3 at density {mass['density']:g}, "
                 f"centre of mass {_vec(mass['center_of_mass'])} m"),
        ("displacement", f"outward {_length(q['displacement_outward'])}, inward {_length(q['displacement_inward'])}, "
                         f"hull deviation {_length(q['hull_deviation'])}, "
                         f"hull volume excess {100 * q['hull_volume_excess']:.2f} %"),
        ("reconstruction", "coarse->full p95 {} (max {}), full->coarse p95 {} (max {}); bbox diagonal {}".format(
            _length(rec["coarse_to_full"]["p95"]), _length(rec["coarse_to_full"]["max"]),
            _length(rec["full_to_coarse"]["p95"]), _length(rec["full_to_coarse"]["max"]),
            _length(q["bbox_diagonal"]))),
        ("min wavelength", _length(q["min_wavelength"])),
        ("seeds", ", ".join(f"{k} {v}" for k, v in sorted(m["seeds"].items()))),
        ("files", "; ".join(f"{f['path']} {_bytes(f['bytes'])}" for _, f in sorted(files.items()))),
    ]
    for w in m["warnings"]:
        rows.append(("warning", w))
    return rows


@click.command("inspect")
@click.argument("bundle", type=click.Path(file_okay=True, dir_okay=True, path_type=str))
@click.option("--json", "as_json", is_flag=True, default=False,
              help="Print {path, valid, problems, manifest} as JSON instead of a summary.")
def inspect(bundle: str, as_json: bool) -> None:
    """Summarise BUNDLE: source, coarse mesh, atlas, pieces, mass, quality, files.

    Also validates it and lists its problems. Exit code 0 when the summary could
    be printed (even for an invalid bundle: see 'valid'), else the exit code of
    the error class that prevented reading the manifest (as for validate)."""
    manifest, problems = check_bundle(bundle)
    if as_json:
        out = {"path": bundle, "valid": not problems,
               "problems": [{"class": p.cls, "message": p.message} for p in problems],
               "manifest": manifest}
        click.echo(json.dumps(out, indent=2, sort_keys=True))
        sys.exit(0 if manifest is not None else VALIDATE_EXIT[problems[0].cls])
    if manifest is None:
        for p in problems:
            click.echo(f"{bundle}: {p.cls}: {p.message}")
        sys.exit(VALIDATE_EXIT[problems[0].cls])

    from rich.console import Console
    from rich.table import Table

    console = Console(highlight=False, soft_wrap=False)
    table = Table(title=bundle, title_justify="left", box=None, show_header=False, pad_edge=False)
    table.add_column(style="bold", no_wrap=True)
    table.add_column(overflow="fold")
    for key, value in _summary_rows(manifest):
        table.add_row(key, value, style="yellow" if key == "warning" else None)
    if problems:
        for p in problems:
            table.add_row("problem", f"{p.cls}: {p.message}", style="red")
    else:
        table.add_row("valid", "yes (schema, hashes and invariants checked)", style="green")
    console.print(table)
    sys.exit(0)
