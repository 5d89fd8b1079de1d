"""Where the jobs of ``hbake batch`` run: this machine, or a Dask cluster.

Both take the job dicts of hbake.batch.jobs and call ``finished(result)`` once per job, with
the dict ``hbake.batch.jobs.run_job`` returns (plus ``attempts``); neither ever drops a job:
a job that could not run is reported as failed with its class.

* ``LocalExecutor``: up to ``jobs`` bakes at once on this machine, admitted only while
  the estimated peak RSS of the running bakes plus the next stays within the memory
  budget (a bake that alone exceeds it runs alone, with a warning).
* ``DaskExecutor``: the same jobs as tasks on a dask.distributed cluster (a scheduler
  address, or a LocalCluster of ``jobs`` single-threaded worker processes); inputs and
  outputs are paths on a directory every worker sees. A worker that dies mid-job makes
  the scheduler give up on the task (``KilledWorker``, after its own
  ``distributed.scheduler.allowed-failures`` retries); the job is then submitted again
  under a new key up to ``retries`` times, and reported as ``worker-died`` after that.
"""
from __future__ import annotations

import queue
import threading
import uuid
from typing import Callable

from hbake.batch.jobs import MemoryModel, run_job, terminate_running
from hbake.errors import EXIT_USAGE, HbakeError

#: How long the client tries to reach a --scheduler before the batch fails (exit 2).
CONNECT_TIMEOUT = "10s"


class LocalExecutor:
    def __init__(self, jobs: int, memory_budget: int, log: Callable[[str], None] = lambda s: None):
        self.jobs = max(1, jobs)
        self.memory = MemoryModel(memory_budget)
        self.log = log

    def describe(self) -> dict:
        return {"name": "local", "jobs": self.jobs, "memory_budget_bytes": self.memory.budget,
                "memory_scale": round(self.memory.scale, 3)}

    def run(self, jobs: list[dict], finished: Callable[[dict], None]) -> None:
        pending = list(jobs)
        running: dict[str, int] = {}          # name -> reserved bytes
        done: queue.Queue = queue.Queue()

        def work(job: dict) -> None:
            try:
                res = run_job(job)
            except Exception as exc:          # noqa: BLE001 -- reported, never lost
                res = {"name": job["name"], "status": "failed", "exit_code": 1,
                       "error_class": "internal", "error": f"{type(exc).__name__}: {exc}",
                       "seconds": 0.0, "peak_rss_bytes": None, "host": None, "report": None}
            done.put((job, res))

        threads = []
        try:
            self._loop(pending, running, done, threads, work, finished)
        except KeyboardInterrupt:
            # SIGINT/SIGTERM of the batch: stop the running bakes (each removes its
            # temporary) before the batch exits, instead of leaving them to finish.
            terminate_running()
            raise
        for t in threads:
            t.join()

    def _loop(self, pending, running, done, threads, work, finished) -> None:
        while pending or running:
            # Admit in order while a slot and the memory budget allow; the first job
            # that does not fit waits (no overtaking, so the order stays predictable).
            while pending and len(running) < self.jobs:
                job = pending[0]
                need = self.memory.estimate(job)
                in_use = sum(running.values())
                if running and in_use + need > self.memory.budget:
                    break
                if not running and need > self.memory.budget:
                    self.log(f"        warning: {job['name']}: estimated peak RSS "
                             f"{need / 2**20:,.0f} MiB exceeds the memory budget "
                             f"{self.memory.budget / 2**20:,.0f} MiB; baking it alone")
                pending.pop(0)
                running[job["name"]] = need
                t = threading.Thread(target=work, args=(job,), daemon=True)
                t.start()
                threads.append(t)
            job, res = done.get()
            del running[job["name"]]
            if res.get("peak_rss_bytes"):
                self.memory.observe(job, res["peak_rss_bytes"])
            res["attempts"] = 1
            finished(res)


def _dask_job(job: dict) -> dict:
    """run_job on a Dask worker, with the worker's address in the result."""
    from distributed import get_worker

    res = run_job(job)
    try:
        res["worker"] = get_worker().address
    except ValueError:
        res["worker"] = None
    return res


class DaskExecutor:
    def __init__(self, scheduler: str | None, jobs: int, retries: int = 1,
                 log: Callable[[str], None] = lambda s: None):
        self.scheduler = scheduler
        self.jobs = max(1, jobs)
        self.retries = retries
        self.log = log
        self._cluster = None

    def describe(self) -> dict:
        return {"name": "dask", "scheduler": self.scheduler or "LocalCluster",
                "workers": self.jobs if self.scheduler is None else None, "retries": self.retries}

    def _client(self):
        import logging

        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise HbakeError("--executor dask needs dask.distributed: pip install 'hbake[dask]'",
                             EXIT_USAGE) from None
        if self.scheduler:
            try:
                return Client(self.scheduler, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError, ValueError) as exc:
                raise HbakeError(f"--scheduler {self.scheduler}: cannot reach the Dask scheduler "
                                 f"within {CONNECT_TIMEOUT}: {exc}", EXIT_USAGE) from None
        import dask

        # One single-threaded worker process per job slot: a bake uses its own cores
        # (embree, CoACD), so more threads per worker would only oversubscribe them.
        # Saturation 1.0: a worker holds only the task it runs (bakes are long; a task
        # queued on a worker that dies would die with it).
        with dask.config.set({"distributed.scheduler.worker-saturation": 1.0}):
            self._cluster = LocalCluster(n_workers=self.jobs, threads_per_worker=1,
                                         processes=True, dashboard_address=None,
                                         silence_logs=logging.ERROR)
        return Client(self._cluster)

    def run(self, jobs: list[dict], finished: Callable[[dict], None]) -> None:
        if not jobs:
            return
        from distributed import as_completed
        from distributed.scheduler import KilledWorker

        client = self._client()
        try:
            # Tasks ask for a MEMORY resource only where the workers were started with one
            # (dask-worker --resources MEMORY=16e9): then the scheduler bounds the bakes a
            # worker runs at once by their estimated peak RSS, as the local executor does.
            has_memory = any("MEMORY" in (w.get("resources") or {})
                             for w in client.scheduler_info()["workers"].values())
            token = uuid.uuid4().hex[:8]
            futures = {}

            def submit(job: dict, attempt: int):
                # A new key per attempt: resubmitting the erred key would return its error.
                fut = client.submit(_dask_job, job, key=f"hbake-{job['name']}-{token}-{attempt}",
                                    pure=False,
                                    resources={"MEMORY": job["estimated_rss"]} if has_memory else None)
                futures[fut] = (job, attempt)
                return fut

            ac = as_completed([submit(j, 1) for j in jobs])
            for fut in ac:
                job, attempt = futures.pop(fut)
                try:
                    res = fut.result()
                except KilledWorker as exc:
                    if attempt <= self.retries:
                        self.log(f"        retry   {job['name']}: its worker died "
                                 f"(attempt {attempt}); submitting it again")
                        ac.add(submit(job, attempt + 1))
                        continue
                    res = {"name": job["name"], "status": "failed", "exit_code": 1,
                           "error_class": "worker-died",
                           "error": f"the Dask worker running it died {attempt} time(s): {exc}",
                           "seconds": 0.0, "peak_rss_bytes": None, "host": None,
                           "report": None, "worker": None}
                except Exception as exc:      # noqa: BLE001 -- reported, never lost
                    res = {"name": job["name"], "status": "failed", "exit_code": 1,
                           "error_class": "internal", "error": f"{type(exc).__name__}: {exc}",
                           "seconds": 0.0, "peak_rss_bytes": None, "host": None,
                           "report": None, "worker": None}
                res["attempts"] = attempt
                finished(res)
        finally:
            client.close()
            if self._cluster is not None:
                self._cluster.close()
