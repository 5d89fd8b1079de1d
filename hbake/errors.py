"""Error classes and exit codes of hbake.

Every user-facing failure is an ``HbakeError`` subclass carrying one line of
text (naming the file and what is wrong) and a distinct exit code; the CLI
prints ``hbake: error: <message>`` and exits with that code, never a traceback.
Exit codes are documented in docs/guides/baking.md ("Exit codes") and are stable.
"""
from __future__ import annotations

import signal

# Exit codes of `hbake bake` (and the commands that read meshes).
EXIT_OK = 0
EXIT_USAGE = 2            # bad option or argument (click's own code)
EXIT_INPUT_MISSING = 3    # input file missing or unreadable
EXIT_INPUT_INVALID = 4    # unsupported extension, unparsable, empty, NaN/Inf, nothing left after repair
EXIT_OUTPUT_EXISTS = 5    # output exists and --force was not given
EXIT_OUTPUT_UNWRITABLE = 6  # output directory missing or not writable
EXIT_BAKE_FAILED = 7      # a stage could not produce a valid result (e.g. parameterization failed)
EXIT_CONFIG = 8           # bad --config file or setting value
EXIT_TEXTURE_PARAMETERS = 20  # hbake texture: a parameter it cannot honour (amplitude, wavelength, region)
EXIT_TARGET_UNREACHABLE = 9  # --method preserve: the coarse mesh cannot reach the target with its chart borders kept
EXIT_INTERRUPTED = 130    # Ctrl-C / SIGINT / SIGTERM (128 + SIGINT, the shell convention)
EXIT_BATCH_FAILED = 18    # hbake batch: at least one model failed (the others were baked)

# Exit codes of `hbake validate`, one per error class of docs/bundle-format.md.
VALIDATE_EXIT = {
    "io": 10,
    "version": 11,
    "schema": 12,
    "hash": 13,
    "mesh": 14,
    "atlas": 15,
    "pieces": 16,
}


#: Error class names of the exit codes (docs/guides/baking.md, "Exit codes"); the JSON outputs use them.
ERROR_CLASSES = {
    0: "ok",
    1: "internal",
    EXIT_USAGE: "usage",
    EXIT_INPUT_MISSING: "input-missing",
    EXIT_INPUT_INVALID: "input-invalid",
    EXIT_OUTPUT_EXISTS: "output-exists",
    EXIT_OUTPUT_UNWRITABLE: "output-unwritable",
    EXIT_BAKE_FAILED: "bake-failed",
    EXIT_CONFIG: "config",
    EXIT_TARGET_UNREACHABLE: "target-unreachable",  # bake --method preserve
    EXIT_BATCH_FAILED: "batch-failed",
    EXIT_TEXTURE_PARAMETERS: "texture-parameters",  # hbake texture
    EXIT_INTERRUPTED: "interrupted",
}


def error_class(code: int) -> str:
    """The class name of an exit code; a negative code is a signal (killed, crashed)."""
    if code < 0:
        try:
            return f"killed-{signal.Signals(-code).name}"
        except ValueError:
            return f"killed-signal-{-code}"
    return ERROR_CLASSES.get(code, f"exit-{code}")


class HbakeError(Exception):
    """A user-facing error: one line of text and an exit code."""

    exit_code = EXIT_BAKE_FAILED

    def __init__(self, message: str, exit_code: int | None = None):
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


class InputMissingError(HbakeError):
    exit_code = EXIT_INPUT_MISSING


class InputInvalidError(HbakeError):
    exit_code = EXIT_INPUT_INVALID


class OutputExistsError(HbakeError):
    exit_code = EXIT_OUTPUT_EXISTS


class OutputUnwritableError(HbakeError):
    exit_code = EXIT_OUTPUT_UNWRITABLE


class BakeFailedError(HbakeError):
    exit_code = EXIT_BAKE_FAILED


class ConfigError(HbakeError):
    exit_code = EXIT_CONFIG


class TargetUnreachableError(HbakeError):
    """The preserve route cannot simplify to the triangle target (``--method auto`` then
    takes the cage route)."""
    exit_code = EXIT_TARGET_UNREACHABLE


class Interrupted(HbakeError):
    exit_code = EXIT_INTERRUPTED


class BundleError(HbakeError):
    """A bundle failed a check; ``cls`` is one of VALIDATE_EXIT's keys."""

    def __init__(self, cls: str, message: str):
        super().__init__(message, VALIDATE_EXIT[cls])
        self.cls = cls
