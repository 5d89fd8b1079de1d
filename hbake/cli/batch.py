"""`hbake batch` and `hbake report`: thin click commands over hbake.batch.jobs and hbake.viz.report.

hbake/cli/main.py adds both to the `hbake` group. Errors are one line on stderr,
`hbake: error: <file>: <problem>`, with the exit codes of hbake.errors (and 18 when
a batch ran but some models failed).
"""
from __future__ import annotations

import json
import os
import re
import sys
import time
from pathlib import Path

import click

from hbake.errors import EXIT_INPUT_MISSING, EXIT_INTERRUPTED, EXIT_OUTPUT_UNWRITABLE, HbakeError

CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}

_SIZE = re.compile(r"^\s*([0-9]+(?:\.[0-9]+)?)\s*([kmgt]?)(i?b)?\s*$", re.IGNORECASE)


def _parse_size(ctx, param, value):
    if value is None:
        return None
    m = _SIZE.match(value)
    if not m:
        raise click.BadParameter(f"{value!r}: expected a size such as 8G, 512M or 2GiB")
    n = float(m.group(1)) * 1024 ** " kmgt".index((m.group(2) or " ").lower())
    if n < 1:
        raise click.BadParameter(f"{value!r}: must be positive")
    return int(n)


def _fail(exc: HbakeError, as_json: bool) -> None:
    from hbake.errors import error_class

    click.echo(f"hbake: error: {exc}", err=True)
    if as_json:
        click.echo(json.dumps({"ok": False, "error": {"class": error_class(exc.exit_code),
                                                      "exit_code": exc.exit_code,
                                                      "message": str(exc)}}, sort_keys=True))
    sys.exit(exc.exit_code)


@click.command("batch", context_settings=CONTEXT)
@click.argument("inputs", nargs=-1, required=True,
                type=click.Path(path_type=Path, readable=False))
@click.option("-o", "--output", "out_dir", type=click.Path(path_type=Path, file_okay=False),
              required=True, help="Directory of the bundles (NAME.hbundle per input "
                                  "NAME.ext); created if missing.")
@click.option("-j", "--jobs", type=click.IntRange(0), default=1, show_default=True,
              help="Bakes at once (0 = one per CPU); with the local executor also bounded "
                   "by --memory-budget. With --executor dask and no --scheduler: the "
                   "LocalCluster's worker count.")
@click.option("-c", "--config", "config", type=click.Path(path_type=Path, readable=False),
              help="Batch config TOML: [batch] settings = base settings file, [defaults] "
                   "and [models.\"NAME\"] setting overrides (examples/batch.toml).")
@click.option("--memory-budget", callback=_parse_size, metavar="SIZE",
              help="Memory the running bakes may use together, e.g. 8G [default: 80% of the "
                   "memory available at the start].")
@click.option("--executor", type=click.Choice(["local", "dask"]), default="local",
              show_default=True, help="Run the bakes here, or on a dask.distributed cluster.")
@click.option("--scheduler", metavar="ADDRESS",
              help="Dask scheduler address (tcp://host:8786) [default: $DASK_SCHEDULER_ADDRESS, "
                   "else a LocalCluster of --jobs workers]; inputs and output must be on a "
                   "directory every worker sees.")
@click.option("--retries", type=click.IntRange(0), default=1, show_default=True,
              help="Dask: times a job whose worker died is submitted again before it is "
                   "reported as failed (worker-died).")
@click.option("--report", "report_path", type=click.Path(path_type=Path, dir_okay=False),
              help="JSON report path [default: OUT_DIR/hbake-batch.json].")
@click.option("--rebuild", is_flag=True, help="Bake every model, up to date or not.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the JSON report on stdout; progress and summary go to stderr.")
@click.option("-q", "--quiet", is_flag=True,
              help="No progress lines or summary. Progress is one line per model on stderr "
                   "(the bakes run quietly: hbake bake's per-stage lines are not shown, so "
                   "parallel bakes never interleave).")
def batch_command(inputs, out_dir, jobs, config, memory_budget, executor, scheduler, retries,
                  report_path, rebuild, as_json, quiet):
    """Bake every mesh of INPUTS (directories of meshes, or mesh files) into OUT_DIR.

    A bundle whose manifest records the same source SHA-256, settings, hbake version and
    library versions (and whose files match it) is skipped. A model that fails is reported
    with its error class and the batch goes on. Exit codes: 0 all baked or skipped, 18 some
    model failed (see the report), 2 bad option, 3 input missing, 6 output not writable,
    8 bad config, 130 interrupted."""
    from hbake.batch.jobs import available_memory, load_batch_config, plan, run_batch, write_report
    from hbake.batch.jobs import DEFAULT_MEMORY_FRACTION

    def log(msg: str) -> None:
        if not quiet:
            click.echo(msg, err=True)

    from hbake.guard import interrupts_end_the_command

    with interrupts_end_the_command():
        try:
            cfg = load_batch_config(config)
            try:
                out_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise HbakeError(f"{out_dir}: cannot create the output directory: {exc.strerror}",
                                 EXIT_OUTPUT_UNWRITABLE) from None
            if not os.access(out_dir, os.W_OK | os.X_OK):
                raise HbakeError(f"{out_dir}: output directory is not writable", EXIT_OUTPUT_UNWRITABLE)
            report_path = report_path or out_dir / "hbake-batch.json"
            t_start = time.perf_counter()
            todo = plan(list(inputs), out_dir, cfg, rebuild=rebuild)
            if not todo:
                raise HbakeError(f"{', '.join(map(str, inputs))}: no mesh files "
                                 f"(.obj .ply .stl .off .gltf .glb)", EXIT_INPUT_MISSING)
        except HbakeError as exc:
            _fail(exc, as_json)
        n = jobs or os.cpu_count() or 1
        if executor == "dask":
            from hbake.batch.executors import DaskExecutor

            ex = DaskExecutor(scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS"), n, retries, log)
        else:
            from hbake.batch.executors import LocalExecutor

            budget = memory_budget or int(DEFAULT_MEMORY_FRACTION * available_memory())
            ex = LocalExecutor(n, budget, log)
        try:
            report = run_batch(todo, ex, log=log)
        except HbakeError as exc:
            _fail(exc, as_json)
        # The whole batch, the up-to-date checks (hashing every mesh) included.
        report["wall_seconds"] = round(time.perf_counter() - t_start, 3)
        try:
            write_report(report_path, report)
        except HbakeError as exc:
            _fail(exc, as_json)
        if not quiet:
            print_batch_summary(report, report_path, err=as_json)
        if as_json:
            click.echo(json.dumps(report, indent=2, sort_keys=True))
        sys.exit(report["exit_code"])


def print_batch_summary(report: dict, report_path: Path, err: bool = False) -> None:
    from rich.console import Console
    from rich.table import Table

    c = report["counts"]
    table = Table(title=f"hbake batch: {c['baked']} baked, {c['skipped']} skipped, "
                        f"{c['failed']} failed of {report['total']} in "
                        f"{report['wall_seconds']:.1f} s ({report['executor']['name']})",
                  title_justify="left")
    for col, just in (("model", "left"), ("status", "left"), ("s", "right"),
                      ("peak RSS MiB", "right"), ("pieces", "right"), ("note", "left")):
        table.add_column(col, justify=just)
    for m in report["models"]:
        rss = f"{m['peak_rss_bytes'] / 2**20:,.0f}" if m.get("peak_rss_bytes") else ""
        pieces = str(m["bake"]["pieces"]) if m.get("bake") else ""
        if m["status"] == "failed":
            note = f"{m['error_class']}: {m['error']}"
        elif m["status"] == "skipped":
            note = "up to date"
        else:
            note = m["reason"] + (f", attempt {m['attempts']}" if m["attempts"] > 1 else "")
        table.add_row(m["name"], m["status"], f"{m['seconds']:.1f}" if m["status"] != "skipped" else "",
                      rss, pieces, note)
    console = Console(stderr=err, highlight=False, soft_wrap=False, width=200)
    console.print(table)
    console.print(f"report: {report_path}")


@click.command("report", context_settings=CONTEXT)
@click.argument("bundle", type=click.Path(path_type=Path, readable=False))
@click.option("-o", "--output", "out_dir", type=click.Path(path_type=Path, file_okay=False),
              required=True, help="Directory to write index.html and the PNGs into (created; "
                                  "replaced as a whole with --force).")
@click.option("--source", type=click.Path(path_type=Path, readable=False),
              help="The bundle's source mesh (same SHA-256 as manifest source.sha256): "
                   "needed for the reconstruction-error histogram and surface map.")
@click.option("--samples", type=click.IntRange(100, 10_000_000), default=20000, show_default=True,
              help="Coarse-surface samples of the error pictures (seeded by the bundle's seed).")
@click.option("-f", "--force", is_flag=True, help="Replace an existing report directory.")
@click.option("--json", "as_json", is_flag=True,
              help="Print {ok, output, page, images, figures, errors, heights} as JSON on stdout.")
def report_command(bundle, out_dir, source, samples, force, as_json):
    """Write an HTML page with pictures of BUNDLE: the coarse mesh and its convex pieces,
    the atlas (positions as colours, displacement as a height map), the reconstruction
    error (histogram and surface map) and the manifest's figures.

    Exit codes: 0 ok, 2 --source is not the bundle's source, 3/4 --source missing or
    unreadable, 5 output exists (no --force), 6 output not writable, 10-16 the bundle is
    invalid (as for validate)."""
    from hbake.viz.report import write_report as write_html_report

    try:
        result = write_html_report(bundle, out_dir, source=source, samples=samples, force=force)
    except HbakeError as exc:
        _fail(exc, as_json)
    except KeyboardInterrupt:
        click.echo("hbake: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    if as_json:
        click.echo(json.dumps({"ok": True, **result}, indent=2, sort_keys=True))
    else:
        click.echo(f"{result['page']}: report of {bundle} ({len(result['images'])} images)")
