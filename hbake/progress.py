"""Progress reporting and stage timings (wall and CPU seconds).

``Progress`` shows one rich progress bar per stage when stderr is a terminal. When it is
not (make, CI, a batch log), it prints one plain line per completed stage instead,
``hbake: stage <name> <seconds> s``, so a long bake is not silent in a log. ``quiet=True``
prints neither. A stage that fails prints no line (the error is the only line then).
Stage wall times are always recorded (``timings``, seconds) for the report and ``--report``.
Warnings go to stderr as ``hbake: warning: ...`` unless quiet.

``hbake batch`` runs each bake with ``--quiet`` in a child process and prints its own line
per model, so the per-stage lines of parallel bakes never interleave in its output.
"""
from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from typing import Callable, Iterator

#: Stages that run in a thread alongside others: their ``stage`` block only waits for the
#: result, so the plain line says so (the stage's own run time is in ``timings``).
BACKGROUND_STAGES = {"decompose"}

#: Stage names and their descriptions, in pipeline order.
STAGES = {
    "load": "load and repair",
    "simplify": "simplify",
    "parameterize": "parameterize (xatlas)",
    "bake": "bake atlas (rays)",
    "decompose": "convex pieces (CoACD)",
    "mass": "mass properties",
    "quality": "quality",
    "write": "write bundle",
}


class Progress:
    """Stage progress for ``hbake.bake``.

    ``enabled`` forces the bars on or off; by default they are shown when stderr is a
    terminal and ``quiet`` is false. ``lines`` forces the plain per-stage lines on or off;
    by default they are printed when no bar is shown and ``quiet`` is false.
    """

    def __init__(self, *, quiet: bool = False, enabled: bool | None = None, stream=None,
                 lines: bool | None = None):
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        if enabled is None:
            enabled = (not quiet) and _isatty(self.stream)
        self.enabled = enabled
        if lines is None:
            lines = (not quiet) and not enabled
        self.lines = lines
        self.timings: dict[str, float] = {}       # wall seconds per stage
        self.cpu_timings: dict[str, float] = {}   # CPU seconds (all threads) per stage
        self._rich = None
        self._console = None

    # --- stages ------------------------------------------------------------------------
    @contextmanager
    def stage(self, name: str, total: float | None = None) -> Iterator[Callable[[float], None]]:
        """Time a stage; yields ``update(completed)`` for stages with a known total."""
        label = STAGES.get(name, name)
        task = None
        if self.enabled:
            bar = self._bar()
            task = bar.add_task(label, total=total if total else 1)
        t0 = time.perf_counter()
        c0 = time.process_time()

        def update(completed: float) -> None:
            if task is not None:
                self._rich.update(task, completed=completed)

        completed = False
        try:
            yield update
            completed = True
        finally:
            wall = time.perf_counter() - t0
            self.timings[name] = self.timings.get(name, 0.0) + wall
            self.cpu_timings[name] = self.cpu_timings.get(name, 0.0) + time.process_time() - c0
            if task is not None:
                t = self._rich.tasks[task].total
                self._rich.update(task, completed=t)
                self._rich.stop_task(task)
            if completed and self.lines:
                self._line(name, wall)

    def warn(self, message: str) -> None:
        if self.quiet:
            return
        if self._rich is not None:
            self._console.print(f"[bold yellow]hbake: warning:[/] {message}", highlight=False,
                                markup=True, soft_wrap=True)
        else:
            print(f"hbake: warning: {message}", file=self.stream, flush=True)

    def close(self) -> None:
        if self._rich is not None:
            self._rich.stop()
            self._rich = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    # --- internals ---------------------------------------------------------------------
    def _line(self, name: str, wall: float) -> None:
        """One plain line for a completed stage (no terminal: make, CI, a log file)."""
        if name in BACKGROUND_STAGES:
            text = f"hbake: stage {name} {wall:.2f} s (the wait: it runs in the background)"
        else:
            text = f"hbake: stage {name} {wall:.2f} s"
        try:
            print(text, file=self.stream, flush=True)
        except (OSError, ValueError):   # a closed or broken stderr must not fail the bake
            pass

    def _bar(self):
        if self._rich is None:
            from rich.console import Console
            from rich.progress import (BarColumn, Progress as RichProgress, SpinnerColumn,
                                       TextColumn, TimeElapsedColumn)

            self._console = Console(file=self.stream)
            self._rich = RichProgress(SpinnerColumn(finished_text="[green]done"),
                                      TextColumn("{task.description:<24}"), BarColumn(),
                                      TimeElapsedColumn(), console=self._console,
                                      transient=False)
            self._rich.start()
        return self._rich


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False
