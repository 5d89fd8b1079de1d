"""Running a bake so that signals always work and native libraries stay quiet.

Two problems of the native stages (xatlas, pymeshlab, embree, CoACD):

* Python runs a signal handler only in the main thread, between bytecodes, with the
  GIL. A native call that holds the GIL for minutes (xatlas looping on a normal it
  cannot normalise, at 1e20 m) makes the process deaf to Ctrl-C and SIGTERM, and a
  worker thread would not help: the main thread needs the GIL to react.
* They print to file descriptors 1 and 2 directly (xatlas ``ASSERT: ...`` through
  printf, CoACD's and MeshLab's logs), past ``-q`` and past ``sys.stdout``.

So ``hbake bake`` forks (``run_guarded``): the child ignores SIGINT/SIGTERM and bakes
with descriptors 1 and 2 pointing at /dev/null, while Python's ``sys.stdout`` and
``sys.stderr`` write to duplicates of the originals (so hbake's own messages, bars
and summary come out as before). The parent only waits; on SIGINT or SIGTERM it
kills the child (SIGKILL: it cannot be stuck), removes the child's temporary bundle
(``.NAME.hbundle.<child pid>.<hex>.tmp``, see ``hbake.bundle.write_bundle``), puts a
bundle being replaced back, and exits 130 at once. A child that dies of a signal
(a crash in a native library) is reported in one line and cleaned up the same way.
``HBAKE_DEBUG=1`` lets the native output through.
"""
from __future__ import annotations

import ctypes
import faulthandler
import io
import os
import signal
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

from hbake.errors import EXIT_INTERRUPTED

__all__ = ["silence_native_output", "run_guarded", "flush_c_stdio"]

#: Exit code for a child killed by a signal other than ours (a native crash).
EXIT_INTERNAL = 1


def flush_c_stdio() -> None:
    """fflush(NULL): C stdio buffers (xatlas's printf) would otherwise be written at exit,
    to whatever descriptor 1 is then."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


def _redirect(stream, fd: int, sink: int):
    """Point ``fd`` at ``sink``; return (saved fd, Python stream writing to the saved fd
    or None when ``stream`` does not write to ``fd``)."""
    try:
        uses_fd = stream is not None and stream.fileno() == fd
    except (AttributeError, ValueError, io.UnsupportedOperation):
        uses_fd = False
    saved = os.dup(fd)
    new = None
    if uses_fd:
        stream.flush()
        new = io.TextIOWrapper(io.FileIO(saved, "w", closefd=False),
                               encoding=stream.encoding, errors=stream.errors,
                               line_buffering=True, write_through=True)
    os.dup2(sink, fd)
    return saved, new


def _flush_python_streams() -> None:
    """Flush sys.stdout and sys.stderr (closed or replaced streams are skipped)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, ValueError):
            pass


@contextmanager
def silence_native_output():
    """Descriptors 1 and 2 go to /dev/null inside; sys.stdout and sys.stderr keep writing
    where they wrote before. Nothing changes with HBAKE_DEBUG=1."""
    if os.environ.get("HBAKE_DEBUG"):
        yield
        return
    flush_c_stdio()
    sink = os.open(os.devnull, os.O_WRONLY)
    old_out, old_err = sys.stdout, sys.stderr
    saved_out, new_out = _redirect(old_out, 1, sink)
    saved_err, new_err = _redirect(old_err, 2, sink)
    os.close(sink)
    if new_out is not None:
        sys.stdout = new_out
    if new_err is not None:
        sys.stderr = new_err
    if faulthandler.is_enabled():   # PYTHONFAULTHANDLER: keep its dumps visible
        faulthandler.enable(file=sys.stderr)
    try:
        yield
    finally:
        _flush_python_streams()
        flush_c_stdio()
        sys.stdout, sys.stderr = old_out, old_err
        os.dup2(saved_out, 1)
        os.dup2(saved_err, 2)
        os.close(saved_out)
        os.close(saved_err)
        if faulthandler.is_enabled():
            faulthandler.enable(file=sys.stderr)


def _die_with_parent() -> None:
    """PR_SET_PDEATHSIG: if the parent is SIGKILLed, the child goes too (its temporary
    bundle is then stale, and the next bake of the same output removes it)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def cleanup_after_child(pid: int, output: Path, report: Path | None) -> None:
    """Remove what a killed child may have left: its temporary bundle, the temporary
    report; put back a bundle it was replacing (renamed to .old, not yet replaced)."""
    import shutil

    out = Path(os.path.abspath(output))
    parent = out.parent
    try:
        for tmp in parent.glob(f".{out.name}.{pid}.*.tmp"):
            shutil.rmtree(tmp, ignore_errors=True)
        for old in parent.glob(f".{out.name}.{pid}.*.old"):
            if out.exists() or out.is_symlink():
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.rename(old, out)
    except OSError:
        pass
    if report is not None:
        tmp = report.with_name(f".{report.name}.tmp")
        if tmp.exists():
            try:
                tmp.unlink()
            except OSError:
                pass


def run_guarded(body: Callable[[], int], output: Path, report: Path | None = None) -> int:
    """Run ``body()`` (which returns an exit code) in a forked child as described above;
    return its exit code. Without fork (not POSIX), run it here."""
    if not hasattr(os, "fork"):
        return body()
    for s in (sys.stdout, sys.stderr):
        s.flush()
    flush_c_stdio()
    pid = os.fork()
    if pid == 0:                                         # the child
        code = EXIT_INTERNAL
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            _die_with_parent()
            with silence_native_output():
                code = body()
        except KeyboardInterrupt:        # a signal before SIG_IGN: the parent reports it
            code = EXIT_INTERRUPTED
        except BaseException:            # noqa: BLE001 -- body() already handles errors
            import traceback
            traceback.print_exc()
        finally:
            _flush_python_streams()
            os._exit(code)
    try:                                                 # the parent
        while True:
            try:
                _, status = os.waitpid(pid, 0)
                break
            except ChildProcessError:
                return EXIT_INTERNAL
    except KeyboardInterrupt:
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
        cleanup_after_child(pid, output, report)
        raise
    code = os.waitstatus_to_exitcode(status)
    if code < 0:
        cleanup_after_child(pid, output, report)
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        print(f"hbake: internal error: the bake process was killed by {name} (a crash in a "
              f"native library; set HBAKE_DEBUG=1 for its output; please report it)",
              file=sys.stderr, flush=True)
        return EXIT_INTERNAL
    return code


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


@contextmanager
def interrupts_end_the_command():
    """SIGINT and SIGTERM raise KeyboardInterrupt inside the block (SIGINT set explicitly:
    a shell starts background jobs with it ignored); one that arrives ends the command
    with "hbake: interrupted" and exit 130. The previous handlers come back after."""
    from hbake.errors import EXIT_INTERRUPTED

    previous = {sig: signal.signal(sig, _raise_interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    except KeyboardInterrupt:
        print("hbake: interrupted", file=sys.stderr, flush=True)
        sys.exit(EXIT_INTERRUPTED)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
