"""``hbake view``: the command over hbake.viz.viewer (docs/viewer.md)."""
from __future__ import annotations

import signal
import sys
import webbrowser
from pathlib import Path

import click

from hbake.errors import HbakeError


@click.command("view", context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
               short_help="A live 3-D view in the browser: a bundle, a session driven with the mouse, a trace.")
@click.argument("target", type=click.Path(path_type=Path, readable=False))
@click.option("--trace", type=click.Path(path_type=Path, dir_okay=False, readable=False),
              help="Replay this trace of `hrt run` (docs/trace-format.md) with TARGET, its scene file.")
@click.option("--play", is_flag=True,
              help="Live: play the scene file's own device (a scripted trajectory) instead of the mouse's "
                   "virtual device.")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address the page is served on (loopback: only this machine can open it).")
@click.option("--port", type=click.IntRange(0, 65535), default=8080, show_default=True,
              help="Port of the page; taken: the next free one (0: any free port). The URL is printed.")
@click.option("--duration", type=click.FloatRange(min=0.001), default=3600.0, show_default=True, metavar="S",
              help="Live: length of the session (session time, s).")
@click.option("--max-triangles", type=click.IntRange(min=1000), default=400_000, show_default=True,
              help="Most triangles of each object's reconstructed surface (each coarse triangle cut into k x k).")
@click.option("--force-scale", type=click.FloatRange(min=0, min_open=True), metavar="MM_PER_N",
              help="Length of the force arrow per newton, mm [default: a quarter of the scene's size per N].")
@click.option("--torque-scale", type=click.FloatRange(min=0, min_open=True), metavar="MM_PER_NM",
              help="Length of the torque arrow per N m, mm [default: 5 times the scene's size per N m].")
@click.option("--open", "open_browser", is_flag=True, help="Open the page in the default browser.")
def view_command(target, trace, play, host, port, duration, max_triangles, force_scale, torque_scale,
                 open_browser):
    """Show TARGET in the browser: a bundle (BUNDLE.hbundle), a live session of a scene file
    (SCENE.toml, the probe moved with the mouse), or with --trace a recorded session.

    Serves until Ctrl-C or SIGTERM (exit 0). Exit codes: 0 ok, 2 bad option, 3 input missing,
    4 input invalid.
    """
    from hbake.viz.viewer import Viewer

    if trace is not None and target.suffix == ".hbundle":
        click.echo(f"hbake: error: {target}: --trace needs the scene file the trace was run from, not a bundle",
                   err=True)
        sys.exit(2)
    try:
        v = Viewer(target, trace, host=host, port=port, play=play, max_triangles=max_triangles,
                   force_scale=force_scale, torque_scale=torque_scale, duration=duration)
    except HbakeError as exc:
        click.echo(f"hbake: error: {exc}", err=True)
        sys.exit(exc.exit_code)
    click.echo(f"hbake view: {v.mode} at {v.url} (Ctrl-C to stop)", err=True)
    # Ctrl-C and SIGTERM stop the server the same way (exit 0: stopping is how it ends).
    signal.signal(signal.SIGINT, lambda *_: v.stop_event.set())
    signal.signal(signal.SIGTERM, lambda *_: v.stop_event.set())
    if open_browser:
        webbrowser.open(v.url)
    try:
        v.wait()
    finally:
        v.close()
