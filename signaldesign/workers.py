"""Independent search tasks (annealing restarts, kick chains) run in worker processes.

Each task gets its own seed, so the results do not depend on how many workers run them. On Linux
the workers are forked: the objective (matrices of a few to a few hundred MB) is inherited, not
pickled. Every worker caps BLAS at one thread (the tasks are many small matrix products; two
workers on two cores must not each start a BLAS pool) and ignores Ctrl-C, which the parent handles
by terminating the workers. A task that raises or a worker that dies ends the search with one
:class:`~signaldesign.evaluate.DesignError` line.
"""
from __future__ import annotations

import multiprocessing
import os
import signal
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool

from identify import PseudostepError

from .evaluate import DesignError

_STATE: dict = {}  # the worker's objective and flyability (set once per worker by _init)


def available_cpus() -> int:
    """CPUs this process may run on (the default number of workers)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def check_jobs(jobs) -> int:
    """``jobs`` as a positive int (None: the available CPUs)."""
    if jobs is None:
        return available_cpus()
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise DesignError(f"jobs must be a positive whole number, got {jobs!r}")
    return jobs


def _init(objective, fly) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops the workers
    # a fork inherits the parent's handlers: after pygame's SDL has caught SIGTERM in the parent
    # (the cueing display), terminate() would only queue a quit event in the worker
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        from threadpoolctl import threadpool_limits
        _STATE["blas"] = threadpool_limits(limits=1, user_api="blas")
    except ImportError:  # only the environment (read by a BLAS loaded after this point)
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = "1"
    _STATE["objective"], _STATE["fly"] = objective, fly


def _call(task, args):
    return task(_STATE["objective"], _STATE["fly"], *args)


def run_tasks(task, arg_list, objective, fly, jobs: int = 1, progress=None) -> list:
    """``[task(objective, fly, *args) for args in arg_list]``, in ``jobs`` worker processes when
    ``jobs`` > 1 (in order; ``progress(done, total)`` after each)."""
    n = len(arg_list)
    jobs = min(check_jobs(jobs), n)
    if jobs <= 1:
        out = []
        for i, args in enumerate(arg_list):
            out.append(task(objective, fly, *args))
            if progress is not None:
                progress(i + 1, n)
        return out
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("fork" if "fork" in methods else None)
    # children that exist before the pool are not ours to stop
    others = {c.pid for c in multiprocessing.active_children()}
    pool = ProcessPoolExecutor(jobs, mp_context=context, initializer=_init, initargs=(objective, fly))
    try:
        futures = {pool.submit(_call, task, args): i for i, args in enumerate(arg_list)}
        out = [None] * n
        for done, future in enumerate(as_completed(futures), 1):
            out[futures[future]] = future.result()
            if progress is not None:
                progress(done, n)
        pool.shutdown(wait=True)
        return out
    except BrokenProcessPool as exc:
        _stop(pool, others)
        raise DesignError(f"a design worker process died ({exc}); retry with jobs=1 to see why") from None
    except PseudostepError:
        _stop(pool, others)
        raise
    except Exception as exc:
        _stop(pool, others)
        raise DesignError(f"design worker failed: {type(exc).__name__}: {exc}") from exc
    except BaseException:  # KeyboardInterrupt, SystemExit: no worker outlives the parent's search
        _stop(pool, others)
        raise


def _stop(pool: ProcessPoolExecutor, others: set) -> None:
    """Cancel what has not started and terminate the workers (a running task is not waited for);
    kill what survives 5 s. Returns when every worker's exit is recorded.
    ``others``: pids of children that are not the pool's."""
    # an interrupt inside submit() can land after a worker is forked but before the pool lists
    # it: every child born since the pool was made is one of its workers
    processes = list((getattr(pool, "_processes", None) or {}).values())
    listed = {p.pid for p in processes}
    processes += [c for c in multiprocessing.active_children() if c.pid not in others | listed]
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown(wait=False) forgets it
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        if p.is_alive():
            p.terminate()
    if not _exited(processes, 5):
        for p in processes:
            if p.is_alive():
                p.kill()
    if manager is not None and manager.is_alive():
        manager.join(timeout=5)  # it reaps a broken pool's workers: its dying workers end it
    # the manager thread reaps workers too, and a join that loses that race returns before the
    # exit is recorded (the process would still be listed as alive): wait for the record
    _exited(processes, 5)


def _exited(processes, timeout: float) -> bool:
    """Whether every process's exit is recorded within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while any(p.is_alive() for p in processes):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True
