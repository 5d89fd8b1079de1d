"""``hbake batch``: bake a folder of meshes into bundles, incrementally and failure-tolerant.

Data flow:

    inputs + batch config  -> jobs (one per mesh: input, output, effective settings)
    jobs + OUT_DIR         -> skip (bundle up to date) or bake (run_job, an executor)
    results                -> progress lines, summary, JSON report, exit code

A bundle is up to date when its manifest records the same source SHA-256, the same
effective settings, the same hbake version and the same library versions as this
bake would (the manifest's ``source.sha256``, ``settings``, ``generator.version`` and
``libraries``: docs/bundle-format.md), and its files still have the sizes and SHA-256s
the manifest names. Anything else is re-baked, and the report says why.

Each bake is the ``hbake bake`` command in a child process (``run_job``): the native
libraries, a crash or an out-of-memory kill stay inside it, its exit code is the error
class of the exit-code table (docs/guides/baking.md), and its peak RSS (wait4) is measured. The same function
runs on a Dask worker (hbake/batch/executors.py), so both executors share the caching, the
report and the error classes.
"""
from __future__ import annotations

import ctypes
import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from hbake import __version__
from hbake.constants import SUPPORTED_EXTENSIONS
from hbake.fileio import (FileTooLargeError, NotRegularFileError, check_regular, read_regular,
                          write_json_atomic)
from hbake.errors import (EXIT_BATCH_FAILED, EXIT_USAGE,
                          ConfigError, HbakeError, InputMissingError, error_class)

#: Peak RSS of one `hbake bake` process tree = base + per_triangle x input triangles.
#: Fitted above the measured envelope (the bake benchmark of docs/guides/baking.md, measured 2026-11-22: 13k-87k
#: triangles 488-602 MiB in-process, the 650k CAD part 997 MiB; the CLI's forked bake
#: adds about 100 MiB: fandisk 698 MiB, armadillo 722 MiB in `hbake batch`, 2026-12-02),
#: so it over- rather than under-estimates; a batch scales it up by the largest
#: measured / estimated ratio it has seen (MemoryModel.observe).
RSS_BASE_BYTES = 720 * 2**20
RSS_PER_TRIANGLE_BYTES = 700

#: Share of the memory available at the start that a batch uses by default.
DEFAULT_MEMORY_FRACTION = 0.8


# --------------------------------------------------------------------------
# The batch config file
# --------------------------------------------------------------------------

@dataclass
class BatchConfig:
    """A batch config (examples/batch.toml): a base settings file, overrides for every
    model, and overrides per model file name. Keys are dotted setting names as in
    ``hbake bake --set`` (a TOML table or dotted key gives the same)."""

    path: Path | None = None
    settings_file: Path | None = None
    defaults: dict[str, Any] = field(default_factory=dict)
    models: dict[str, dict[str, Any]] = field(default_factory=dict)

    def overrides_for(self, name: str) -> dict[str, Any]:
        return {**self.defaults, **self.models.get(name, {})}


def _flatten(table: dict, where: str, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, where, dotted + "."))
        elif isinstance(value, list):
            raise ConfigError(f"{where}: {dotted}: lists are not settings")
        else:
            out[dotted] = value
    return out


def load_batch_config(path: str | os.PathLike | None) -> BatchConfig:
    """Read and check a batch config; every error is a ConfigError naming the file."""
    if path is None:
        return BatchConfig()
    from hbake.settings import MAX_CONFIG_BYTES

    path = Path(path)
    try:
        # The reader of every hbake input: a regular file (a FIFO would block, /dev/zero
        # never end) within the config size limit, checked before it is read.
        data = tomllib.loads(read_regular(path, MAX_CONFIG_BYTES).decode("utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: batch config not found") from None
    except (NotRegularFileError, FileTooLargeError, IsADirectoryError) as exc:
        raise ConfigError(f"{path}: cannot read the batch config: {exc.strerror}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the batch config: "
                          f"{getattr(exc, 'strerror', None) or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    unknown = set(data) - {"batch", "defaults", "models"}
    if unknown:
        raise ConfigError(f"{path}: unknown table(s) {', '.join(sorted(unknown))} "
                          f"(known: batch, defaults, models)")
    cfg = BatchConfig(path=path)
    batch = data.get("batch", {})
    if set(batch) - {"settings"}:
        raise ConfigError(f"{path}: [batch]: unknown key(s) {', '.join(sorted(set(batch) - {'settings'}))} "
                          f"(known: settings)")
    if "settings" in batch:
        if not isinstance(batch["settings"], str):
            raise ConfigError(f"{path}: [batch] settings must be a path (string)")
        # Relative to the batch config, so the file works from any directory (make -C).
        cfg.settings_file = (path.parent / batch["settings"]).resolve()
    cfg.defaults = _flatten(data.get("defaults", {}), f"{path}: [defaults]")
    models = data.get("models", {})
    if not isinstance(models, dict) or not all(isinstance(v, dict) for v in models.values()):
        raise ConfigError(f'{path}: [models] must hold tables, e.g. [models."part.stl"]')
    cfg.models = {name: _flatten(t, f'{path}: [models."{name}"]') for name, t in models.items()}
    # Check every table now, before any bake: a typo must fail the batch at once (exit 8).
    base = _base_settings(cfg)
    for name in cfg.models:
        base.with_overrides(cfg.overrides_for(name), source=f'{path}: [models."{name}"]')
    base.with_overrides(cfg.defaults, source=f"{path}: [defaults]")
    return cfg


def _base_settings(cfg: BatchConfig):
    from hbake.settings import BakeSettings

    return BakeSettings.from_toml(cfg.settings_file) if cfg.settings_file else BakeSettings()


# --------------------------------------------------------------------------
# Jobs
# --------------------------------------------------------------------------

def discover(inputs: list[Path]) -> list[Path]:
    """Mesh files of the inputs: a directory gives its entries with a supported extension
    (not recursive, sorted by name), a file is taken as it is.

    An entry with a mesh extension that is not a regular file (a FIFO, a link to a device,
    a dangling link, a folder) is kept: its bake fails with one line naming what it is, and
    the report lists it, instead of the model vanishing from the batch unseen. A dangling
    link named on the command line is kept the same way; a path that is nothing at all is
    a typo and stops the batch."""
    found: list[Path] = []
    for item in inputs:
        if item.is_dir():
            found.extend(sorted(p for p in item.iterdir() if p.suffix.lower() in SUPPORTED_EXTENSIONS))
        elif item.exists() or item.is_symlink():
            found.append(item)
        else:
            raise InputMissingError(f"{item}: no such file or directory")
    return found


def count_triangles(path: Path) -> int:
    """Triangles of a mesh file from its header or a line count (no full parse): the
    memory estimate needs it before the bake. Polygons count once; unknown layouts
    fall back to 50 bytes per triangle."""
    try:
        # Regular files only: opening a FIFO would block the whole batch here (its bake
        # then fails with one line naming what it is).
        size = check_regular(path).st_size
        ext = path.suffix.lower()
        with open(path, "rb") as fh:
            head = fh.read(4096)
            if ext == ".stl":
                if head[:5].lower() == b"solid" and b"facet" in head:
                    fh.seek(0)
                    return fh.read().count(b"facet normal")
                if len(head) >= 84:
                    return int.from_bytes(head[80:84], "little")
            elif ext == ".ply":
                for line in head.split(b"\n"):
                    parts = line.split()
                    if parts[:2] == [b"element", b"face"] and len(parts) == 3:
                        return int(parts[2])
            elif ext == ".off":
                lines = [ln for ln in head.split(b"\n") if ln.strip() and not ln.startswith(b"#")]
                counts = lines[0][3:].split() or lines[1].split()
                return int(counts[1])
            elif ext == ".obj":
                fh.seek(0)
                data = fh.read()
                return data.count(b"\nf ") + data.startswith(b"f ")
    except (OSError, ValueError, IndexError):
        pass
    return max(1, size // 50) if "size" in locals() else 1


def _is_regular(path: Path) -> bool:
    try:
        check_regular(path)
        return True
    except OSError:
        return False


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _normalized(obj):
    """The JSON form of ``obj`` (tuples become lists), as a manifest stores it."""
    return json.loads(json.dumps(obj, sort_keys=True))


def _changed_keys(a: dict, b: dict, prefix: str = "") -> str:
    """Dotted keys whose values differ between two settings dicts (at most 4 named)."""
    keys = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k), b.get(k)
        if isinstance(va, dict) and isinstance(vb, dict):
            inner = _changed_keys(va, vb, f"{prefix}{k}.")
            keys += inner.split(", ") if inner else []
        elif va != vb:
            keys.append(f"{prefix}{k}")
    return ", ".join(keys[:4] + ([f"{len(keys) - 4} more"] if len(keys) > 4 else []))


def up_to_date(output: Path, source_sha256: str, settings: dict, libraries: dict) -> tuple[bool, str]:
    """(True, "up to date") when the bundle at ``output`` is what this bake would write,
    else (False, why it must be baked)."""
    manifest_path = output / "manifest.json"
    if not output.exists():
        return False, "new"
    try:
        m = json.loads(manifest_path.read_text(encoding="utf-8"))
        if m["source"]["sha256"] != source_sha256:
            return False, "source changed"
        if m["settings"] != _normalized(settings):
            return False, f"settings changed ({_changed_keys(m['settings'], _normalized(settings))})"
        if m["generator"]["version"] != __version__:
            return False, f"hbake version changed ({m['generator']['version']} -> {__version__})"
        if m["libraries"] != _normalized(libraries):
            changed = sorted(k for k in set(m["libraries"]) | set(libraries)
                             if m["libraries"].get(k) != libraries.get(k))
            return False, f"library versions changed ({', '.join(changed)})"
        for f in m["files"].values():
            p = output / f["path"]
            if p.stat().st_size != f["bytes"] or sha256_file(p) != f["sha256"]:
                return False, f"bundle damaged ({f['path']} differs from the manifest)"
    except (OSError, ValueError, KeyError, TypeError):
        return False, "bundle unreadable"
    return True, "up to date"


@dataclass
class Job:
    """One model of a batch; ``to_dict`` is what run_job receives (JSON-able, so a Dask
    worker gets plain data)."""

    name: str
    input: str
    output: str
    overrides: dict[str, Any]
    settings_file: str | None
    triangles: int
    estimated_rss: int
    skip: bool = False
    reason: str = "new"

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def plan(inputs: list[Path], out_dir: Path, cfg: BatchConfig, *, rebuild: bool = False) -> list[Job]:
    """The jobs of a batch, each marked skip or not (with the reason)."""
    from hbake.routes.pipeline import library_versions

    files = discover(inputs)
    outputs: dict[str, Path] = {}
    for f in files:
        out = f"{f.stem}.hbundle"
        if out in outputs:
            raise HbakeError(f"{f}: {outputs[out]} would write the same bundle {out}; "
                             f"rename one of them", EXIT_USAGE)
        outputs[out] = f
    libraries = library_versions()
    base = _base_settings(cfg)
    where = str(cfg.path) if cfg.path else "batch"
    jobs = []
    for f in files:
        ov = cfg.overrides_for(f.name)
        settings = base.with_overrides(ov, source=f'{where}: [models."{f.name}"]') if ov else base
        out = (out_dir / f"{f.stem}.hbundle").absolute()
        tris = count_triangles(f)
        job = Job(name=f.name, input=str(f.absolute()), output=str(out), overrides=ov,
                  settings_file=str(cfg.settings_file) if cfg.settings_file else None,
                  triangles=tris, estimated_rss=RSS_BASE_BYTES + RSS_PER_TRIANGLE_BYTES * tris)
        if rebuild:
            job.reason = "--rebuild"
        elif _is_regular(f):
            job.skip, job.reason = up_to_date(out, sha256_file(f), settings.to_dict(), libraries)
        jobs.append(job)
    return jobs


def _toml_value(value: Any) -> str:
    """A setting value as a TOML literal for ``--set`` (a JSON scalar is one)."""
    return json.dumps(value)


def bake_command_line(job: dict) -> list[str]:
    cmd = [sys.executable, "-m", "hbake.cli", "bake", job["input"], "-o", job["output"],
           "--force", "--quiet", "--json"]
    if job.get("settings_file"):
        cmd += ["-c", job["settings_file"]]
    for key, value in sorted(job["overrides"].items()):
        cmd += ["--set", f"{key}={_toml_value(value)}"]
    return cmd


_PRCTL = None

#: The bake processes run_job has running in this process (terminate_running stops them).
_RUNNING: set = set()
_RUNNING_LOCK = threading.Lock()


def terminate_running(timeout: float = 30.0) -> None:
    """SIGTERM every running bake and wait for it: `hbake bake` then removes its
    temporary bundle and exits 130, so an interrupted batch leaves nothing behind."""
    with _RUNNING_LOCK:
        procs = list(_RUNNING)
    for proc in procs:
        try:
            proc.terminate()
        except ProcessLookupError:
            pass
    # The threads of run_job reap them (one waiter per process: no double wait4).
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        with _RUNNING_LOCK:
            if not _RUNNING:
                return
        time.sleep(0.02)
    for proc in procs:
        proc.kill()


def _term_with_parent() -> None:
    """In the bake child: SIGTERM when the process that started it dies (a killed Dask
    worker, a batch killed with SIGKILL), so `hbake bake` cleans up and stops instead of
    baking on as an orphan. SIGTERM, not SIGKILL: the bake then removes its temporary."""
    if _PRCTL is not None:
        _PRCTL(1, signal.SIGTERM)          # 1 = PR_SET_PDEATHSIG


def run_job(job: dict) -> dict:
    """Bake one job with ``hbake bake`` in a child process; never raises for a failed
    bake. Returns {name, status "baked"|"failed", exit_code, error_class, error,
    seconds, peak_rss_bytes, host, report (the bake's JSON)}."""
    global _PRCTL
    if _PRCTL is None:
        try:
            _PRCTL = ctypes.CDLL(None, use_errno=True).prctl   # resolved before fork
        except (OSError, AttributeError):
            pass
    t0 = time.perf_counter()
    started = time.time()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        env = dict(os.environ, NO_COLOR="1")
        proc = subprocess.Popen(bake_command_line(job), stdin=subprocess.DEVNULL, stdout=out,
                                stderr=err, env=env, preexec_fn=_term_with_parent)
        with _RUNNING_LOCK:
            _RUNNING.add(proc)
        try:
            # wait4, not wait: this child's rusage, whose ru_maxrss covers the forked bake
            # process too (the kernel folds waited-for descendants in).
            _, status, usage = os.wait4(proc.pid, 0)
        except BaseException:
            proc.terminate()               # hbake bake removes its temporary on SIGTERM
            proc.wait()
            raise
        finally:
            with _RUNNING_LOCK:
                _RUNNING.discard(proc)
        proc.returncode = code = os.waitstatus_to_exitcode(status)
        seconds = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout = out.read().decode("utf-8", "replace")
        stderr = err.read().decode("utf-8", "replace")
    result = {"name": job["name"], "exit_code": code, "error_class": error_class(code),
              "seconds": round(seconds, 3), "peak_rss_bytes": usage.ru_maxrss * 1024,
              "started": round(started, 3), "finished": round(started + seconds, 3),
              "host": socket.gethostname(), "status": "baked" if code == 0 else "failed",
              "error": None, "report": None}
    if code == 0:
        try:
            result["report"] = json.loads(stdout)
        except ValueError:
            result.update(status="failed", exit_code=1, error_class="internal",
                          error="hbake bake printed no JSON report")
    else:
        lines = [ln for ln in stderr.splitlines() if ln.startswith("hbake: ")]
        result["error"] = (lines[-1].removeprefix("hbake: error: ") if lines else
                           f"hbake bake ended with {error_class(code)} and no message")
    return result


# --------------------------------------------------------------------------
# Memory
# --------------------------------------------------------------------------

def available_memory() -> int:
    import psutil

    return int(psutil.virtual_memory().available)


class MemoryModel:
    """Estimated peak RSS of a job: the triangle model times the largest measured /
    estimated ratio seen so far in the batch (never below 1)."""

    def __init__(self, budget: int):
        self.budget = budget
        self.scale = 1.0

    def estimate(self, job: dict) -> int:
        return int(job["estimated_rss"] * self.scale)

    def observe(self, job: dict, peak_rss: int) -> None:
        if peak_rss > 0 and job["estimated_rss"] > 0:
            self.scale = max(self.scale, peak_rss / job["estimated_rss"])


# --------------------------------------------------------------------------
# The batch
# --------------------------------------------------------------------------

def skipped_result(job: Job) -> dict:
    return {"name": job.name, "status": "skipped", "exit_code": 0, "error_class": "ok",
            "error": None, "seconds": 0.0, "peak_rss_bytes": None, "host": None,
            "report": None}


def run_batch(jobs: list[Job], executor, *, log: Callable[[str], None] = lambda s: None) -> dict:
    """Run the jobs that are not up to date on ``executor`` (hbake.batch.executors) and return
    the report (docs/guides/pipelines.md, "hbake batch"). Progress lines go to ``log``."""
    t0 = time.perf_counter()
    todo = [j for j in jobs if not j.skip]
    results: dict[str, dict] = {}
    n = len(jobs)
    done = 0
    for j in jobs:
        if j.skip:
            done += 1
            results[j.name] = skipped_result(j)
            log(f"[{done}/{n}] skipped {j.name} (up to date)")

    def finished(res: dict) -> None:
        nonlocal done
        done += 1
        results[res["name"]] = res
        if res["status"] == "baked":
            log(f"[{done}/{n}] baked   {res['name']} in {res['seconds']:.1f} s, "
                f"peak RSS {res['peak_rss_bytes'] / 2**20:,.0f} MiB"
                + (f" (attempt {res['attempts']})" if res.get("attempts", 1) > 1 else ""))
            # Each model's warnings, as `hbake bake` prints them: a part with no unit
            # (baked in meters: 1000x too large if it was in mm) must not pass unseen.
            for w in ((res.get("report") or {}).get("manifest") or {}).get("warnings", []):
                log(f"        warning {res['name']}: {w}")
        else:
            log(f"[{done}/{n}] FAILED  {res['name']}: {res['error_class']}: {res['error']}")

    for j in todo:
        log(f"        bake    {j.name} ({j.reason}; {j.triangles:,} triangles)")
    executor.run([j.to_dict() for j in todo], finished)
    by_job = {j.name: j for j in jobs}
    models = []
    for j in jobs:
        r = dict(results.get(j.name) or {"name": j.name, "status": "failed", "exit_code": 1,
                                         "error_class": "internal", "seconds": 0.0,
                                         "error": "the executor returned no result",
                                         "peak_rss_bytes": None, "host": None, "report": None})
        bake_report = r.pop("report", None)
        entry = {"name": j.name, "input": j.input, "output": j.output, "reason": by_job[j.name].reason,
                 "triangles_in": j.triangles, "estimated_rss_bytes": j.estimated_rss,
                 "attempts": r.pop("attempts", 0 if j.skip else 1), **r}
        if bake_report is not None:
            m = bake_report["manifest"]
            entry["bake"] = {"timings": bake_report["timings"],
                             "total_seconds": bake_report["total_seconds"],
                             "coarse_triangles": m["coarse"]["triangles"],
                             "pieces": m["pieces"]["count"],
                             "warnings": m["warnings"],
                             "p95_coarse_to_full_texels": m["quality"]["reconstruction"]["coarse_to_full"]["p95"]
                             / m["atlas"]["texel_size"]}
        models.append(entry)
    counts = {s: sum(1 for m in models if m["status"] == s) for s in ("baked", "skipped", "failed")}
    return {"hbake_version": __version__, "executor": executor.describe(),
            "models": models, "counts": counts, "total": len(models),
            "wall_seconds": round(time.perf_counter() - t0, 3),
            "exit_code": EXIT_BATCH_FAILED if counts["failed"] else 0}


def write_report(path: Path, report: dict) -> None:
    """The JSON report, written to a temporary sibling and renamed (never half-written)."""
    write_json_atomic(path, report, "cannot write the report")
