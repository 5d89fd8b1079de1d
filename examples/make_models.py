#!/usr/bin/env python3
"""Write the procedural test models (hbake/lab/procedural.py) into a folder.

    .venv/bin/python examples/make_models.py out/models                 # all of them
    .venv/bin/python examples/make_models.py out/models ridged_block rasp
    .venv/bin/python examples/make_models.py out/models --format stl

Files are named ``<model>.<format>`` (binary PLY by default), in meters, so bake
them with ``hbake bake out/models/ridged_block.ply --units m``. The same code
makes the same bytes every time; existing files are rewritten.
Used by ``make demo`` and by the benchmarks (``hbake bench``, ``hrt bench``).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from hbake.lab import procedural


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.argument("models", nargs=-1)
@click.option("--format", "fmt", type=click.Choice(["ply", "stl", "obj", "off"]), default="ply",
              show_default=True, help="mesh file format")
@click.option("--quiet", "-q", is_flag=True, help="print nothing")
def main(out_dir: Path, models: tuple[str, ...], fmt: str, quiet: bool) -> None:
    """Write MODELS (default: all registered models) into OUT_DIR."""
    names = list(models) or list(procedural.MODELS)
    unknown = [n for n in names if n not in procedural.MODELS]
    if unknown:
        raise click.UsageError(f"unknown model(s) {', '.join(unknown)}; "
                               f"known: {', '.join(procedural.MODELS)}")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        click.echo(f"make_models: error: cannot create {out_dir}: {exc.strerror}", err=True)
        sys.exit(6)
    for name in names:
        t0 = time.perf_counter()
        path = out_dir / f"{name}.{fmt}"
        mesh = procedural.generate(name, path)
        info = procedural.MODELS[name]
        if not quiet:
            click.echo(f"{path}: {len(mesh.faces):,} triangles, relief wavelength "
                       f"{info.wavelength * 1e3:g} mm, amplitude {info.amplitude * 1e3:g} mm "
                       f"({time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":
    main()
