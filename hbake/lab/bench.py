"""Bake benchmark: ``hbake bench`` / ``examples/bench_bake.py``.

Bakes the shared models (``../shared/models`` from the repository root; absent
ones are skipped) and the generated ~650k-triangle CAD part
(:func:`hbake.lab.procedural.cad_part`), each bake in a fresh Python process so that
the peak resident set size is that bake's alone (``os.wait4`` returns the
child's own ``ru_maxrss``; Linux carries a parent's peak RSS into a forked
child, so the parent never loads a big mesh itself). Prints a Markdown table: triangles in and out,
convex pieces, seconds per stage, total wall time, peak RSS, and the
reconstruction error (p95 of both directions, in texel sizes), plus the machine
it ran on. With ``repeat > 1`` every figure is the median over the runs.

Not a timed test: the targets (650k part in <= 30 s and <= 4 GiB on a 2-core
machine) are printed next to the figures, and ``run_bench`` returns the rows
for a caller that wants to check them.
"""
from __future__ import annotations

import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence


#: The shared models and the unit each is baked in (none of the files records
#: one; these give hand-sized or plausible parts, and the figures of the table
#: that matter, errors relative to the texel size, do not depend on it).
SHARED_MODELS: dict[str, str] = {
    "stanford_bunny.obj": "m",        # 0.156 m: the real bunny figurine
    "armadillo.obj": "m",
    "fandisk.obj": "cm",
    "rocker_arm.obj": "m",
    "hammer_scan.obj": "in",          # 8.2 in = 21 cm: a hand tool
    "planetary_gears.stl": "mm",      # OpenSCAD output: millimetres
    "mountain_terrain.obj": "cm",
}

#: Settings of a shared model where the defaults do not suit it (also used by
#: tests/hbake/stages/test_bake_models.py). planetary_gears.stl is an assembly of 7 gears baked as
#: one object: at the default 600 coarse faces the coarse gears cannot follow the teeth
#: (full->coarse p95 0.73 texel) and CoACD at threshold 0.05 takes 117 s (305 pieces);
#: at 1200 faces and threshold 0.1: p95 0.14 texel, 51 pieces, 25 s in all (measured
#: with `hbake bake`, 2026-11-22).
SHARED_OVERRIDES: dict[str, dict] = {
    "planetary_gears.stl": {"simplify.target_faces": 1200, "decompose.threshold": 0.1},
}

#: Targets for the 650k-triangle part on a 2-core machine.
TARGET_SECONDS = 30.0
TARGET_RSS_BYTES = 4 * 1024 ** 3
#: The target for the preserve route on the same part and machine.
TARGET_SECONDS_PRESERVE = 300.0

#: ``--method`` of the benchmark: one route, or ``both`` (cage and preserve, side by side).
BENCH_METHODS = ("cage", "preserve", "pp", "auto", "both")
#: hbake's exit code of a preserve bake that cannot reach its target (hbake/errors.py):
#: a row of its own in the table, not a failed bake.
_EXIT_UNREACHABLE = 9

REPO_ROOT = Path(__file__).resolve().parents[2]
#: The environment variable naming the shared models' folder (README, "The first hour").
MODELS_ENV = "HBAKE_MODELS"


def shared_models_dir() -> Path:
    """The shared models' folder: ``$HBAKE_MODELS``, else ``../shared/models`` beside the
    repository (the layout of the project's own machines)."""
    env = os.environ.get(MODELS_ENV)
    return Path(env) if env else REPO_ROOT.parent / "shared" / "models"


SHARED_DIR = shared_models_dir()


class BenchFailed(RuntimeError):
    """Some bakes failed; the table of the others was printed."""


@dataclass
class BenchRow:
    """Figures of one model (medians when repeated)."""

    model: str
    triangles_in: int
    triangles_out: int
    pieces: int
    stages: dict[str, float]        # seconds per stage, in pipeline order
    total_s: float                  # bake's own wall time (inside the process)
    process_s: float                # process wall time, interpreter start and imports included
    peak_rss: int                   # bytes
    p95_c2f_texels: float           # coarse -> full, p95 / texel size
    p95_f2c_texels: float           # full -> coarse, p95 / texel size
    texel_size: float               # m
    runs: int

    def to_dict(self) -> dict:
        return dict(self.__dict__)


# --------------------------------------------------------------------------
# Machine description
# --------------------------------------------------------------------------

def machine() -> dict[str, Any]:
    """CPU model, core counts and memory of this machine (for the table's caption)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                mem = int(line.split()[1]) * 1024
                break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return {"cpu": cpu, "logical_cpus": os.cpu_count(), "usable_cpus": usable,
            "memory_bytes": mem, "python": platform.python_version(),
            "system": f"{platform.system()} {platform.release()}"}


# --------------------------------------------------------------------------
# One bake in a child process
# --------------------------------------------------------------------------

def _child(input_path: str, output_path: str, overrides_json: str, result_path: str) -> int:
    """Run one bake in this (fresh) process and write its figures as JSON."""
    from hbake import bake
    from hbake.settings import BakeSettings

    settings = BakeSettings().with_overrides(json.loads(overrides_json))
    t0 = time.perf_counter()
    from hbake.errors import HbakeError

    try:
        report = bake(input_path, output_path, settings, force=True)   # quiet progress by default
    except HbakeError as exc:          # one line and hbake's own exit code (9: unreachable)
        print(f"hbake: error: {exc}", file=sys.stderr)
        return exc.exit_code
    total = time.perf_counter() - t0
    manifest = report["manifest"]
    stages = _stage_seconds(report)
    q = manifest["quality"]["reconstruction"]
    texel = manifest["atlas"]["texel_size"]
    out = {
        "triangles_in": manifest["source"]["triangles"],
        "triangles_out": manifest["coarse"]["triangles"],
        "pieces": manifest["pieces"]["count"],
        "stages": stages,
        "total_s": total,
        "p95_c2f_texels": q["coarse_to_full"]["p95"] / texel,
        "p95_f2c_texels": q["full_to_coarse"]["p95"] / texel,
        "texel_size": texel,
        "self_peak_rss": report.get("peak_rss_bytes"),
    }
    Path(result_path).write_text(json.dumps(out))
    return 0


def _stage_seconds(report: dict) -> dict[str, float]:
    """Per-stage seconds of the report ``hbake.bake`` returns, in pipeline order."""
    return {str(k): float(v) for k, v in report.get("timings", {}).items()}


def _bake_in_child(input_path: Path, output_path: Path, overrides: dict) -> tuple[dict, float, int]:
    """Bake in a fresh interpreter; return (figures, process wall seconds, peak RSS bytes)."""
    with tempfile.NamedTemporaryFile("r", suffix=".json", delete=False) as fh:
        result_path = fh.name
    try:
        cmd = [sys.executable, "-m", "hbake.lab.bench", "--child", str(input_path), str(output_path),
               json.dumps(overrides, sort_keys=True), result_path]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        # wait4 (not wait): the rusage of this child alone, so ru_maxrss is its peak RSS.
        stderr = proc.stderr.read()
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            tail = stderr.decode(errors="replace").strip().splitlines()[-1:] or ["(no output)"]
            err = RuntimeError(f"bake of {input_path.name} failed with exit code "
                               f"{proc.returncode}: {tail[0]}")
            err.exit_code = proc.returncode
            raise err
        figures = json.loads(Path(result_path).read_text())
    finally:
        if os.path.exists(result_path):
            os.unlink(result_path)
    # Linux reports ru_maxrss in KiB (macOS in bytes).
    rss = usage.ru_maxrss * (1 if sys.platform == "darwin" else 1024)
    return figures, wall, rss


# --------------------------------------------------------------------------
# The benchmark
# --------------------------------------------------------------------------

def default_models(work_dir: Path, log=print, models_dir: Path | None = None,
                   allow_missing: bool = False) -> list[tuple[str, Path, str]]:
    """(name, path, unit) of the shared models plus the generated CAD part.

    A missing folder or model is an error (FileNotFoundError naming the folder and how to
    point at it), not a silent skip, unless ``allow_missing``: a table without the shared
    models would look complete."""
    shared = Path(models_dir) if models_dir is not None else shared_models_dir()
    models, missing = [], []
    for name, unit in SHARED_MODELS.items():
        path = shared / name
        if path.is_file():
            models.append((name, path, unit))
        else:
            missing.append(name)
    if missing:
        what = (f"the shared models folder {shared} does not exist" if not shared.is_dir()
                else f"{shared} lacks {', '.join(missing)}")
        if not allow_missing:
            raise FileNotFoundError(f"{what}; set {MODELS_ENV} (or --models-dir) to the folder "
                                    f"of the shared models, or pass --skip-missing")
        log(f"bench: warning: {what}: the table leaves them out (--skip-missing)")
    cad = work_dir / "cad_part.ply"
    if not cad.exists():
        # In a child process: Linux carries a process's peak RSS across fork and exec,
        # so a parent that had grown by making the 650k part would inflate every
        # child's ru_maxrss.
        subprocess.run([sys.executable, "-c",
                        "import sys; from hbake.lab.procedural import generate; "
                        "generate('cad_part', sys.argv[1])", str(cad)], check=True)
    models.append(("cad_part (generated)", cad, "m"))
    return models


def _median_row(name: str, runs: list[tuple[dict, float, int]]) -> BenchRow:
    med = statistics.median
    figs = [r[0] for r in runs]
    stage_names: list[str] = []
    for f in figs:
        for k in f["stages"]:
            if k not in stage_names:
                stage_names.append(k)
    return BenchRow(
        model=name,
        triangles_in=figs[0]["triangles_in"],
        triangles_out=figs[0]["triangles_out"],
        pieces=figs[0]["pieces"],
        stages={k: med([f["stages"].get(k, 0.0) for f in figs]) for k in stage_names},
        total_s=med([f["total_s"] for f in figs]),
        process_s=med([r[1] for r in runs]),
        peak_rss=int(med([r[2] for r in runs])),
        p95_c2f_texels=figs[0]["p95_c2f_texels"],
        p95_f2c_texels=figs[0]["p95_f2c_texels"],
        texel_size=figs[0]["texel_size"],
        runs=len(runs),
    )


def format_table(rows: Sequence[BenchRow], info: dict) -> str:
    """Markdown table of the rows plus a caption naming the machine."""
    stage_names: list[str] = []
    for r in rows:
        for k in r.stages:
            if k not in stage_names:
                stage_names.append(k)
    head = (["model", "tris in", "tris out", "pieces"] + [f"{s} s" for s in stage_names]
            + ["total s", "process s", "peak RSS MiB", "p95 c->f /texel", "p95 f->c /texel"])
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(
        ["---"] + ["---:"] * (len(head) - 1)) + "|"]
    for r in rows:
        cells = ([r.model, f"{r.triangles_in:,}", f"{r.triangles_out:,}", str(r.pieces)]
                 + [f"{r.stages.get(s, 0.0):.2f}" for s in stage_names]
                 + [f"{r.total_s:.1f}", f"{r.process_s:.1f}", f"{r.peak_rss / 2**20:,.0f}",
                    f"{r.p95_c2f_texels:.3f}", f"{r.p95_f2c_texels:.3f}"])
        lines.append("| " + " | ".join(cells) + " |")
    mem = f", {info['memory_bytes'] / 2**30:.0f} GiB RAM" if info.get("memory_bytes") else ""
    runs = rows[0].runs if rows else 1
    lines.append("")
    lines.append(f"Machine: {info['cpu']}, {info['usable_cpus']} usable of "
                 f"{info['logical_cpus']} logical CPUs{mem}; Python {info['python']}, "
                 f"{info['system']}. "
                 + (f"Median of {runs} runs. " if runs > 1 else "One run. ")
                 + "total = the bake inside its process; process = the whole child "
                 "(interpreter start and imports included); peak RSS of that child. "
                 "decompose runs alongside parameterize and bake, so the stage columns add "
                 "up to more than total. "
                 + "Default settings" + "".join(
                     f"; {m}: " + ", ".join(f"{k} = {v}" for k, v in ov.items())
                     for m, ov in SHARED_OVERRIDES.items() if any(r.model == m for r in rows))
                 + ".")
    return "\n".join(lines)


def run_bench(models: Sequence[str | os.PathLike] | None = None,
              out_dir: str | os.PathLike | None = None,
              json_path: str | os.PathLike | None = None,
              repeat: int = 1,
              overrides: dict | None = None,
              log=print, models_dir: str | os.PathLike | None = None,
              allow_missing: bool = False) -> list[BenchRow]:
    """Bake each model in a fresh process and print the table.

    ``models``: mesh files (baked in meters unless listed in ``SHARED_MODELS``),
    default: the shared models (in ``models_dir``, default :func:`shared_models_dir`; a
    missing one is an error unless ``allow_missing``) and the generated CAD part. ``out_dir``:
    where the bundles (and the generated part) go, default a temporary
    directory removed afterwards. ``json_path``: also write the rows and the
    machine as JSON. ``overrides``: settings overrides (dotted keys) for every bake.
    """
    if repeat < 1:
        raise ValueError("repeat must be at least 1")
    tmp = None
    if out_dir is None:
        tmp = tempfile.mkdtemp(prefix="hbake-bench-")
        work = Path(tmp)
    else:
        work = Path(out_dir)
        work.mkdir(parents=True, exist_ok=True)
    try:
        if models is None:
            todo = default_models(work, log, models_dir, allow_missing)
        else:
            todo = []
            for m in models:
                p = Path(m)
                if not p.is_file():
                    raise FileNotFoundError(f"bench: {p}: no such file")
                todo.append((p.name, p, SHARED_MODELS.get(p.name, "m")))
        rows, failures, unreachable = [], [], []
        ov_all = dict(overrides or {})
        method = ov_all.pop("method", None)
        routes = ["cage", "preserve"] if method == "both" else [method]
        for name, path, unit in todo:
            for route in routes:
                ov = {"load.units": unit, **SHARED_OVERRIDES.get(name, {}), **ov_all}
                if route is not None:
                    ov["method"] = route
                label = name if method != "both" else f"{name} [{route}]"
                stem = Path(name.split(" ")[0]).stem + ("" if route is None else f"-{route}")
                runs = []
                try:
                    for _ in range(repeat):
                        runs.append(_bake_in_child(path, work / f"{stem}.hbundle", ov))
                except RuntimeError as exc:
                    if getattr(exc, "exit_code", None) == _EXIT_UNREACHABLE:
                        unreachable.append(f"{label}: {exc}")
                    else:
                        failures.append(f"{label}: {exc}")
                    log(f"bench: {exc}")
                    continue
                row = _median_row(label, runs)
                rows.append(row)
                log(f"bench: {label}: {row.total_s:.1f} s, peak RSS {row.peak_rss / 2**20:,.0f} MiB")
        info = machine()
        log("")
        log(format_table(rows, info))
        for f in unreachable:
            log(f"target not reachable by the preserve route (exit 9): {f}")
        for f in failures:
            log(f"FAILED: {f}")
        cad = [r for r in rows if r.model.startswith("cad_part")]
        for r in cad:
            pp = "[preserve]" in r.model or method in ("preserve", "pp")
            limit = TARGET_SECONDS_PRESERVE if pp else TARGET_SECONDS
            ok = r.process_s <= limit and r.peak_rss <= TARGET_RSS_BYTES
            log(f"\ntarget for the {r.triangles_in:,}-triangle CAD part{' by preserve' if pp else ''}: <= {limit:.0f} s "
                f"and <= {TARGET_RSS_BYTES / 2**30:.0f} GiB: "
                f"{'met' if ok else 'NOT met'} ({r.process_s:.1f} s, "
                f"{r.peak_rss / 2**30:.2f} GiB)")
        if json_path is not None:
            Path(json_path).write_text(json.dumps(
                {"machine": info, "repeat": repeat, "rows": [r.to_dict() for r in rows],
                 "failures": failures, "unreachable": unreachable},
                indent=2, sort_keys=True) + "\n")
        if failures:
            raise BenchFailed(f"{len(failures)} of {len(todo)} bakes failed")
        return rows
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry of ``python -m hbake.lab.bench`` (the child protocol, or the bench command)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--child"]:
        return _child(*argv[1:5])
    from hbake.cli.lab import bench_command

    bench_command.main(args=argv, prog_name="hbake bench")
    return 0


if __name__ == "__main__":
    sys.exit(main())
