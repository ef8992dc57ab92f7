"""Where test points run: serially, in a local process pool, or on a Dask cluster.

Every executor has ``start()`` (workers up, libraries loaded: timed apart), ``map(fn, tasks)``,
yielding ``(task, result)`` as each task finishes (in completion order), and ``close()``. At most ``window`` tasks are in flight at once: tasks are drawn
from the (lazy) iterable only as earlier ones finish, so the coordinator's memory does not grow
with the number of test points. ``fn`` must not raise (:func:`campaign.point.identify_point`
returns failures as records); a worker that dies is handled by the executor:

* :class:`LocalPool` restarts a broken pool and resubmits the tasks that were in flight; a task
  that has been in flight at ``max_crashes`` worker deaths comes back as a failure record;
* :class:`DaskExecutor` leaves it to the scheduler, which reruns a dead worker's tasks elsewhere
  (Dask's ``allowed-failures``); a task that keeps killing workers comes back as a failure.

BLAS threads: each job pins itself to one thread (threadpoolctl, in the job); the local pool's
and local cluster's worker processes also start with the usual variables set to 1.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator

from identify.errors import CampaignError

from .point import failure_record

ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def warm_up(pause: float = 0.0) -> int:
    """Load the identification libraries in a fresh worker (done once per worker at start, so
    that a campaign's timing is the points' work, not the imports), then wait ``pause`` s (a
    pool's workers each take one); returns the process id."""
    import time

    import identify.estimators.ml  # noqa: F401
    import identify.estimators.prediction  # noqa: F401
    time.sleep(pause)
    return os.getpid()


class Serial:
    """In this process, one task after the other (the reference the others must equal)."""

    name = "serial"
    workers = 1

    def start(self):
        warm_up()

    def map(self, fn: Callable, tasks: Iterable) -> Iterator:
        for task in tasks:
            yield task, fn(task)

    def close(self) -> None:
        pass


class LocalPool:
    """``workers`` processes on this machine (spawned: clean interpreters, BLAS pinned)."""

    name = "local"

    def __init__(self, workers: int | None = None, window: int | None = None, max_crashes: int = 3):
        self.workers = workers or os.cpu_count() or 1
        if self.workers < 1:
            raise CampaignError(f"workers must be at least 1, got {self.workers}")
        self.window = window or 4 * self.workers
        self.max_crashes = max_crashes
        self._pool = None

    def start(self):
        """Start the workers and load the libraries in each."""
        if self._pool is None:
            self._start()

    def _start(self):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        saved = {k: os.environ.get(k) for k in ONE_THREAD}
        os.environ.update(ONE_THREAD)  # inherited by the spawned workers before they import numpy
        try:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"))
            # the pool spawns its processes on the first submissions: every worker starts here,
            # inside the environment above, each loading the libraries once
            list(self._pool.map(warm_up, [0.2] * self.workers))
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v

    def map(self, fn: Callable, tasks: Iterable) -> Iterator:
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        if self._pool is None:
            self._start()
        source, pending, crashes = iter(tasks), {}, {}
        retry: list = []

        def fill():
            while len(pending) < self.window:
                task = retry.pop() if retry else next(source, None)
                if task is None:
                    return
                pending[self._pool.submit(fn, task)] = task

        fill()
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            broken = False
            for fut in done:
                task = pending.pop(fut)
                try:
                    yield task, fut.result()
                except BrokenProcessPool:
                    broken = True
                    retry.append(task)
            if broken:  # a worker died: every task in flight is lost with the pool
                retry += pending.values()
                pending.clear()
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._start()
                for task in list(retry):
                    crashes[task["key"]] = crashes.get(task["key"], 0) + 1
                    if crashes[task["key"]] >= self.max_crashes:
                        retry.remove(task)
                        yield task, failure_record(task, f"worker process died {crashes[task['key']]} times "
                                                       f"while this point was running")
            fill()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class DaskExecutor:
    """Tasks on a Dask cluster: a new :class:`distributed.LocalCluster` of ``workers`` processes
    listening on the loopback interface only (``scheduler=None``), or an existing scheduler at
    ``scheduler`` (``tls://host:8786``), reached with ``security`` (a
    :class:`distributed.security.Security`; TLS when its files are given)."""

    name = "dask"

    def __init__(self, scheduler: str | None = None, workers: int = 2, security=None,
                 window: int | None = None):
        self.scheduler, self.security = scheduler, security
        self.workers = workers
        self.window = window
        self.client = self.cluster = None

    def start(self):
        import dask
        from distributed import Client, LocalCluster

        if self.client is not None:
            return self.client
        if self.scheduler is None:
            # the workers' statistical profiler samples the running task every 10 ms: off, it only
            # costs CPU here
            with dask.config.set({"distributed.nanny.pre-spawn-environ": ONE_THREAD,
                                  "distributed.worker.profile.enabled": False}):
                self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                            host="127.0.0.1", dashboard_address=None, silence_logs=40)
            self.client = Client(self.cluster)
            self.client.run(warm_up)
        else:
            if self.security is None and self.scheduler.startswith("tls://"):
                raise CampaignError(f"{self.scheduler} is a TLS scheduler: give --tls-ca, --tls-cert and --tls-key")
            if self.security is None:
                import warnings
                warnings.warn(f"connecting to {self.scheduler} without TLS (no --tls-ca/--tls-cert/--tls-key): "
                              f"tasks and results travel unencrypted; only inside a network you trust")
            try:
                self.client = Client(self.scheduler, security=self.security, timeout="30s")
            except Exception as exc:  # unreachable, refused, a TLS mismatch: one line, not a traceback
                raise CampaignError(f"cannot reach the Dask scheduler at {self.scheduler} "
                                    f"({type(exc).__name__}: {exc})") from None
            self.workers = max(1, len(self.client.scheduler_info().get("workers", {})))
        return self.client

    def worker_pids(self) -> dict:
        """{worker address: process id} (tests kill one)."""
        return self.start().run(os.getpid)

    def map(self, fn: Callable, tasks: Iterable) -> Iterator:
        from distributed import as_completed

        client = self.start()
        window = self.window or 4 * max(self.workers, 1)
        source = iter(tasks)
        owner = {}

        def submit(task):
            fut = client.submit(fn, task, key=f"point-{task['key']}", pure=False)
            owner[fut.key] = task
            return fut

        first = [submit(t) for t in _take(source, window)]
        if not first:
            return
        # results gathered by as_completed itself (in batches, in the background): one round trip
        # per finished point is what costs a 2-core machine most of Dask's overhead
        queue = as_completed(first, with_results=True, raise_errors=False)
        for fut, result in queue:
            task = owner.pop(fut.key)
            if isinstance(result, BaseException):  # the scheduler gave up on it (KilledWorker)
                result = failure_record(task, f"{type(result).__name__} on the Dask cluster: {result}")
            fut.release()
            yield task, result
            nxt = next(source, None)
            if nxt is not None:
                queue.add(submit(nxt))

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None


def _take(it, n):
    out = []
    for _ in range(n):
        x = next(it, None)
        if x is None:
            break
        out.append(x)
    return out


def security_from(ca: str | None, cert: str | None, key: str | None):
    """A Dask :class:`~distributed.security.Security` for TLS from the three PEM files (None when
    none is given); a partial set is refused, one line."""
    given = [x is not None for x in (ca, cert, key)]
    if not any(given):
        return None
    if not all(given):
        raise CampaignError("TLS needs all of --tls-ca, --tls-cert and --tls-key")
    for path in (ca, cert, key):
        if not os.path.isfile(path):
            raise CampaignError(f"{path}: no such TLS file")
    from distributed.security import Security
    return Security(tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key, require_encryption=True)


def make_executor(kind: str = "local", workers: int | None = None, scheduler: str | None = None,
                  security=None):
    """``serial``, ``local`` (process pool) or ``dask`` (LocalCluster, or ``scheduler``)."""
    if scheduler is not None or kind == "dask":
        return DaskExecutor(scheduler, workers or 2, security)
    if kind == "serial":
        return Serial()
    if kind == "local":
        return LocalPool(workers)
    raise CampaignError(f"unknown executor '{kind}' (serial, local, dask)")
