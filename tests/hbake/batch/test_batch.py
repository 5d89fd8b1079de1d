"""`hbake batch`: caching, failure isolation, the report, memory-bounded jobs,
examples/Makefile, and the Dask executor against a real LocalCluster with a worker
killed mid-job.

Bakes are tiny (1,280-triangle blobs, 60 coarse faces, 32 x 32 atlas, 1,000 samples: about
2 s each alone), made once per session where a test only reads them.
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
import trimesh
from batchcli import LOW, blob, env, hbake, one_error_line, run  # noqa: F401

REPO = Path(__file__).resolve().parents[3]







@pytest.fixture(scope="session")
def models(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("models")
    blob(d / "a.ply", 40.0)
    blob(d / "b.ply", 25.0)
    (d / "broken.stl").write_text("solid x\nfacet normal 0 0 0\nendsolid x\n")
    (d / "notes.txt").write_text("not a mesh: ignored")
    return d


@pytest.fixture(scope="session")
def low_config(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("cfg") / "batch.toml"
    p.write_text(LOW)
    return p


@pytest.fixture(scope="session")
def first_batch(models, low_config, tmp_path_factory):
    """One batch of the models: (output dir, completed process, report)."""
    out = tmp_path_factory.mktemp("batch") / "bundles"
    proc = run(["batch", models, "-o", out, "-c", low_config, "-j", "2", "--json"])
    return out, proc, json.loads(proc.stdout)


def by_name(report: dict) -> dict:
    return {m["name"]: m for m in report["models"]}


def test_batch_bakes_good_models_and_reports_the_bad_one(first_batch, models):
    out, proc, report = first_batch
    assert proc.returncode == 18, proc.stderr          # EXIT_BATCH_FAILED: one model failed
    m = by_name(report)
    assert sorted(m) == ["a.ply", "b.ply", "broken.stl"]   # notes.txt is not a mesh
    assert report["counts"] == {"baked": 2, "skipped": 0, "failed": 1}
    bad = m["broken.stl"]
    assert bad["status"] == "failed" and bad["exit_code"] == 4 and bad["error_class"] == "input-invalid"
    assert "broken.stl" in bad["error"] and "Traceback" not in proc.stderr
    for name in ("a.ply", "b.ply"):
        assert m[name]["status"] == "baked" and m[name]["reason"] == "new"
        assert m[name]["peak_rss_bytes"] > 50 * 2**20
        assert m[name]["bake"]["coarse_triangles"] <= 60
        bundle = out / f"{Path(name).stem}.hbundle"
        assert run(["validate", bundle]).returncode == 0
    assert not (out / "broken.hbundle").exists()
    assert not [p for p in out.iterdir() if p.name.startswith(".")]   # no temporaries
    # The report file is the --json output; progress and the summary went to stderr.
    assert json.loads((out / "hbake-batch.json").read_text()) == report
    assert "[3/3]" in proc.stderr and "1 failed of 3" in proc.stderr
    # Each model's warnings are printed (a PLY records no unit: baked as meters, which a
    # part drawn in mm would be 1000x too large for) and listed in the report.
    for name in ("a.ply", "b.ply"):
        assert any("records no unit" in w for w in m[name]["bake"]["warnings"]), m[name]["bake"]["warnings"]
        assert f"warning {name}: {name} records no unit" in proc.stderr, proc.stderr


def test_batch_skips_what_is_up_to_date_and_rebakes_what_changed(first_batch, models, low_config,
                                                                  tmp_path):
    out0, _, _ = first_batch
    src = tmp_path / "in"
    shutil.copytree(models, src)
    out = tmp_path / "out"
    shutil.copytree(out0, out)
    (src / "broken.stl").unlink()
    proc = run(["batch", src, "-o", out, "-c", low_config, "--json"])
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["counts"] == {"baked": 0, "skipped": 2, "failed": 0}
    assert "0 baked, 2 skipped, 0 failed" in proc.stderr
    # Settings of one model change (a per-model table), the other's source changes:
    # both are re-baked, each with its reason; nothing else.
    cfg = tmp_path / "batch.toml"
    cfg.write_text(LOW + '[models."a.ply"]\nseed = 5\n')
    blob(src / "b.ply", 31.0)
    proc = run(["batch", src, "-o", out, "-c", cfg, "-j", "2", "--json"])
    assert proc.returncode == 0, proc.stderr
    m = by_name(json.loads(proc.stdout))
    assert (m["a.ply"]["status"], m["a.ply"]["reason"]) == ("baked", "settings changed (seed)")
    assert (m["b.ply"]["status"], m["b.ply"]["reason"]) == ("baked", "source changed")
    assert json.loads((out / "a.hbundle" / "manifest.json").read_text())["seeds"]["coacd"] == 5


def test_up_to_date_checks_the_manifest_fields(first_batch, models, tmp_path):
    """The four recorded fields decide, and a damaged file forces a re-bake."""
    from hbake.batch.jobs import sha256_file, up_to_date
    from hbake.routes.pipeline import library_versions

    out0, _, _ = first_batch
    bundle = tmp_path / "a.hbundle"
    shutil.copytree(out0 / "a.hbundle", bundle)
    m = json.loads((bundle / "manifest.json").read_text())
    src_hash, settings, libs = sha256_file(models / "a.ply"), m["settings"], library_versions()
    assert up_to_date(bundle, src_hash, settings, libs) == (True, "up to date")
    assert up_to_date(bundle, "0" * 64, settings, libs)[1] == "source changed"
    assert up_to_date(bundle, src_hash, {**settings, "seed": 9}, libs)[1] == "settings changed (seed)"
    other = {**settings, "simplify": {**settings["simplify"], "target_faces": 7}}
    assert up_to_date(bundle, src_hash, other, libs)[1] == "settings changed (simplify.target_faces)"
    newer = {**libs, "coacd": "9.9.9"}
    assert up_to_date(bundle, src_hash, settings, newer)[1] == "library versions changed (coacd)"
    changed = dict(m, generator={"name": "hbake", "version": "0.0.1"})
    (bundle / "manifest.json").write_text(json.dumps(changed))
    assert up_to_date(bundle, src_hash, settings, libs)[1].startswith("hbake version changed")
    (bundle / "manifest.json").write_text(json.dumps(m))
    with open(bundle / "pieces.ply", "r+b") as fh:
        fh.seek(-1, 2)
        last = fh.read(1)
        fh.seek(-1, 2)
        fh.write(bytes([last[0] ^ 1]))
    assert up_to_date(bundle, src_hash, settings, libs)[1].startswith("bundle damaged")
    assert up_to_date(tmp_path / "none.hbundle", src_hash, settings, libs)[1] == "new"


def test_memory_budget_serialises_jobs(models, low_config, tmp_path):
    """-j 2 with a budget that holds one estimated bake: the two bakes never overlap;
    the measured peak RSS per job is in the report."""
    from hbake.batch.jobs import RSS_BASE_BYTES

    src = tmp_path / "in"
    src.mkdir()
    for n in ("a.ply", "b.ply"):
        shutil.copy(models / n, src / n)
    budget = int(RSS_BASE_BYTES * 1.5)
    proc = run(["batch", src, "-o", tmp_path / "out", "-c", low_config, "-j", "2",
                "--memory-budget", str(budget), "--json"])
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    a, b = sorted(rep["models"], key=lambda m: m["started"])
    assert a["finished"] <= b["started"] + 0.05, (a, b)
    assert rep["executor"]["memory_budget_bytes"] == budget
    assert all(m["peak_rss_bytes"] for m in rep["models"])


def test_memory_model_scales_up_on_measurement():
    from hbake.batch.jobs import MemoryModel

    mm = MemoryModel(budget=10**10)
    job = {"estimated_rss": 1000}
    assert mm.estimate(job) == 1000
    mm.observe(job, 500)                  # below the estimate: stays conservative
    assert mm.estimate(job) == 1000
    mm.observe(job, 3000)                 # above: every later estimate grows with it
    assert mm.estimate({"estimated_rss": 2000}) == 6000


def test_batch_user_errors_are_one_line(models, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[models."a.ply"]\nsimplify.target_facez = 10\n')
    proc = run(["batch", models, "-o", tmp_path / "o", "-c", bad])
    assert proc.returncode == 8
    line = one_error_line(proc.stderr)
    assert "bad.toml" in line and "target_facez" in line
    proc = run(["batch", tmp_path / "missing", "-o", tmp_path / "o"])
    assert proc.returncode == 3 and "missing" in one_error_line(proc.stderr)
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = run(["batch", empty, "-o", tmp_path / "o", "--json"])
    assert proc.returncode == 3 and "no mesh files" in one_error_line(proc.stderr)
    assert json.loads(proc.stdout)["error"]["class"] == "input-missing"
    blocker = tmp_path / "file"
    blocker.write_text("x")
    proc = run(["batch", models, "-o", blocker / "sub"])
    assert proc.returncode == 6 and "file" in one_error_line(proc.stderr)


def test_count_triangles_from_headers(tmp_path):
    from hbake.batch.jobs import count_triangles

    m = trimesh.creation.icosphere(subdivisions=2)
    for ext in ("ply", "stl", "obj", "off"):
        p = tmp_path / f"m.{ext}"
        m.export(p)
        assert count_triangles(p) == len(m.faces), ext


# --------------------------------------------------------------------------
# examples/Makefile
# --------------------------------------------------------------------------

def test_examples_makefile_is_incremental(models, tmp_path):
    """Pattern rules over a folder: everything once, then nothing, then only the touched
    model; a config change re-runs the rules, and hbake's own check re-bakes only the
    model whose settings changed."""
    if shutil.which("make") is None:
        # `make test` itself runs under make, so CI always has it.
        if os.environ.get("CI"):
            pytest.fail("make is not installed")
        pytest.skip("make not installed")
    src = tmp_path / "models"
    src.mkdir()
    for n in ("a.ply", "b.ply"):
        shutil.copy(models / n, src / n)
    cfg = tmp_path / "batch.toml"
    cfg.write_text(LOW)
    out = tmp_path / "bundles"
    args = ["make", "-C", str(REPO / "examples"), f"MODELS={src}", f"OUT={out}",
            f"CONFIG={cfg}", f"HBAKE={' '.join(hbake())}"]
    p = subprocess.run(args + ["-j2"], capture_output=True, text=True, env=env(), timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    assert sorted(x.name for x in out.glob("*.hbundle")) == ["a.hbundle", "b.hbundle"]
    assert subprocess.run(args + ["-q"], env=env()).returncode == 0       # up to date
    time.sleep(1.1)                  # make compares modification times (1 s on some FS)
    os.utime(src / "b.ply")
    p = subprocess.run(args + ["-n"], capture_output=True, text=True, env=env())
    assert "b.ply" in p.stdout and "a.ply" not in p.stdout, p.stdout
    p = subprocess.run(args, capture_output=True, text=True, env=env(), timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "skipped b.ply" in p.stderr            # same bytes: hbake's check skips the bake
    assert subprocess.run(args + ["-q"], env=env()).returncode == 0
    time.sleep(1.1)
    cfg.write_text(LOW + '[models."a.ply"]\nseed = 4\n')
    p = subprocess.run(args + ["-j2"], capture_output=True, text=True, env=env(), timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "baked   a.ply" in p.stderr and "skipped b.ply" in p.stderr, p.stderr
    assert subprocess.run(args + ["-q"], env=env()).returncode == 0


# --------------------------------------------------------------------------
# The Dask executor on a real LocalCluster
# --------------------------------------------------------------------------

@contextlib.contextmanager
def local_cluster(n_workers: int):
    """A LocalCluster of ``n_workers`` single-threaded worker processes under nannies, and
    its client. The nannies set their pre-spawn environment (OMP_NUM_THREADS=1,
    MALLOC_TRIM_THRESHOLD_, ...) in this process's os.environ before spawning a worker and
    leave it there: every later test, and the programs it runs, would bake with one OpenMP
    thread. The environment is put back when the cluster closes."""
    distributed = pytest.importorskip("distributed")
    import logging

    saved = dict(os.environ)
    cluster = distributed.LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    try:
        yield cluster, client
    finally:
        client.close()
        cluster.close()
        os.environ.clear()
        os.environ.update(saved)


@pytest.fixture(scope="module")
def dask_cluster():
    """Two workers (a killed worker is restarted by its nanny). allowed-failures 0: the
    scheduler gives up on a task at the first worker death, so hbake's own resubmission is
    what the test sees; worker-saturation 1.0: a worker holds one task at a time, so the
    quick job is never queued on the worker that is killed."""
    dask = pytest.importorskip("dask")
    with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                          "distributed.scheduler.worker-saturation": 1.0}):
        with local_cluster(2) as (cluster, client):
            yield cluster, client


def test_a_local_cluster_leaves_the_environment_as_it_found_it():
    before = dict(os.environ)
    with local_cluster(1) as (_, client):
        # a worker exists, so its nanny has set its pre-spawn variables here
        assert client.run(os.getpid)
        if "OMP_NUM_THREADS" not in before:      # a value already set takes precedence
            assert os.environ.get("OMP_NUM_THREADS") == "1", "distributed no longer sets it"
    assert dict(os.environ) == before


def _executing(dask_worker) -> tuple[int, list[str]]:
    """(pid, keys of the tasks this worker is executing now); run on each worker."""
    return os.getpid(), [str(ts.key) for ts in dask_worker.state.executing]


def _kill_worker_running(client, prefix: str, killed: list, timeout: float = 120.0) -> None:
    """Wait until a task whose key starts with ``prefix`` is executing on a worker, then
    SIGKILL that worker process (its nanny restarts it)."""
    t_end = time.time() + timeout
    while time.time() < t_end:
        try:
            states = client.run(_executing)
        except Exception:                # a worker coming or going: ask again
            states = {}
        for addr, (pid, keys) in states.items():
            if any(k.startswith(prefix) for k in keys):
                time.sleep(1.0)          # let the bake's child process start
                os.kill(pid, signal.SIGKILL)
                killed.append((addr, pid))
                return
        time.sleep(0.1)


def _dask_batch(models_dir, out, cfg, scheduler, retries, prefix, client):
    killed: list = []
    t = threading.Thread(target=_kill_worker_running, args=(client, prefix, killed), daemon=True)
    t.start()
    proc = run(["batch", models_dir, "-o", out, "-c", cfg, "--executor", "dask",
                "--scheduler", scheduler, "--retries", str(retries), "--json"])
    t.join(timeout=5)
    return proc, killed


@pytest.fixture
def dask_models(tmp_path):
    """A slow model (20,480 triangles, so the kill lands mid-bake) and a quick one."""
    src = tmp_path / "in"
    src.mkdir()
    blob(src / "slow.ply", 30.0, subdivisions=5)
    blob(src / "quick.ply", 40.0)
    cfg = tmp_path / "batch.toml"
    cfg.write_text(LOW + '[models."slow.ply"]\nquality.samples = 20000\n'
                         'parameterize.atlas_width = 256\nparameterize.atlas_height = 256\n')
    return src, cfg


def test_dask_worker_killed_mid_job_is_retried(dask_cluster, dask_models, tmp_path):
    cluster, client = dask_cluster
    src, cfg = dask_models
    out = tmp_path / "out"
    proc, killed = _dask_batch(src, out, cfg, cluster.scheduler_address, 1, "hbake-slow.ply", client)
    assert killed, "the slow job never ran on a worker"
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    m = by_name(rep)
    assert rep["executor"]["name"] == "dask" and rep["counts"]["baked"] == 2, proc.stderr
    assert m["slow.ply"]["attempts"] == 2 and m["slow.ply"]["status"] == "baked", (m, proc.stderr)
    assert m["quick.ply"]["attempts"] == 1, (m, proc.stderr)
    assert "worker died" in proc.stderr
    for name in ("slow", "quick"):
        assert run(["validate", out / f"{name}.hbundle"]).returncode == 0
    # The killed attempt's `hbake bake` got SIGTERM with its worker and cleaned up.
    t_end = time.time() + 10
    while [p for p in out.iterdir() if p.name.startswith(".")] and time.time() < t_end:
        time.sleep(0.2)
    assert not [p for p in out.iterdir() if p.name.startswith(".")], list(out.iterdir())
    # Same caching as the local executor: a second run skips both.
    proc = run(["batch", src, "-o", out, "-c", cfg, "--executor", "dask",
                "--scheduler", cluster.scheduler_address, "--json"])
    assert proc.returncode == 0 and json.loads(proc.stdout)["counts"]["skipped"] == 2


def test_dask_unreachable_scheduler_is_one_line(models, low_config, tmp_path):
    pytest.importorskip("distributed")
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(models / "a.ply", src / "a.ply")
    proc = run(["batch", src, "-o", tmp_path / "out", "-c", low_config, "--executor", "dask",
                "--scheduler", "tcp://127.0.0.1:9", "--json"], timeout=120)
    assert proc.returncode == 2, proc.stderr
    line = [ln for ln in proc.stderr.splitlines() if ln.startswith("hbake: error: ")]
    assert len(line) == 1 and "tcp://127.0.0.1:9" in line[0] and "Traceback" not in proc.stderr
    assert json.loads(proc.stdout)["error"]["class"] == "usage"


def test_dask_worker_killed_without_retries_is_reported(dask_cluster, dask_models, tmp_path):
    cluster, client = dask_cluster
    src, cfg = dask_models
    out = tmp_path / "out"
    # The cluster may still be restarting the worker the previous test killed.
    client.wait_for_workers(2, timeout=60)
    proc, killed = _dask_batch(src, out, cfg, cluster.scheduler_address, 0, "hbake-slow.ply", client)
    assert killed
    assert proc.returncode == 18, proc.stderr
    m = by_name(json.loads(proc.stdout))
    assert m["slow.ply"]["status"] == "failed" and m["slow.ply"]["error_class"] == "worker-died"
    assert m["quick.ply"]["status"] == "baked"
    assert not (out / "slow.hbundle").exists()


def test_batch_sigterm_stops_and_leaves_nothing_half_written(models, low_config, tmp_path):
    """SIGTERM mid-batch: exit 130 at once; the running bakes get SIGTERM with their
    parent (PR_SET_PDEATHSIG) and remove their temporaries; no report is half-written."""
    src = tmp_path / "in"
    src.mkdir()
    blob(src / "slow.ply", 30.0, subdivisions=5)
    out = tmp_path / "out"
    cfg = tmp_path / "batch.toml"
    cfg.write_text(LOW + '[models."slow.ply"]\nquality.samples = 20000\n')
    proc = subprocess.Popen(hbake() + ["batch", str(src), "-o", str(out), "-c", str(cfg)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env())
    import psutil

    t_end = time.time() + 60
    bakes = []
    while time.time() < t_end and not bakes:   # until `hbake bake` runs under the batch
        bakes = [c for c in psutil.Process(proc.pid).children(recursive=True)
                 if "bake" in c.cmdline()]
        time.sleep(0.05)
    assert bakes, "the bake never started"
    time.sleep(2.0)                              # well inside the bake (about 10 s)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1] == "hbake: interrupted"
    t_end = time.time() + 15
    while time.time() < t_end and list(out.iterdir()):
        time.sleep(0.2)
    assert list(out.iterdir()) == [], list(out.iterdir())
    assert not any(b.is_running() and b.status() != psutil.STATUS_ZOMBIE for b in bakes)


def test_merging_an_stl_s_duplicate_vertices_is_no_warning(tmp_path):
    """An STL stores every triangle's corners apart: merging them is routine and stays in the
    manifest's repair record, out of the warnings (it hid the ones that matter)."""
    src = tmp_path / "blob.stl"
    trimesh.load(blob(tmp_path / "blob.ply"), process=False).export(src)
    out = tmp_path / "blob.hbundle"
    r = run(["bake", src, "-o", out, "--units", "m", "--target-faces", "60"])
    assert r.returncode == 0, r.stderr
    assert "duplicate vertices" not in r.stderr, r.stderr
    m = json.loads((out / "manifest.json").read_text())
    assert not any("duplicate vertices" in w for w in m["warnings"])
    assert m["source"]["repair"]["merged_vertices"] > 0
