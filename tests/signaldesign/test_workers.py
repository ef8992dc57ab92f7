"""The search in worker processes: the same design for any number of workers; a failing or dying
worker ends the search with one clear error and leaves no process behind."""
import multiprocessing
import os

import numpy as np
import pytest

from identify import LinearModel, load_profile
from signaldesign.design import Flyability, Objective, SequenceDesign, StepBasis, anneal
from signaldesign.evaluate import DesignError, Evaluator
from signaldesign.robust import design_set
from signaldesign.workers import run_tasks


@pytest.fixture(scope="module")
def s61m():
    return LinearModel(load_profile("s61_hover_8state"))


def test_annealing_gives_the_same_result_for_any_number_of_workers(s61m):
    ev = Evaluator(s61m, "theta_s", record=10.0, dt=0.05)
    basis = StepBasis(ev, 0.2, 20, models=design_set(s61m)[0][:3])
    runs = [anneal(Objective(basis, "mean"), Flyability(2, 8, 2), n_iter=150, restarts=3, seed=5, kicks=3, jobs=j)
            for j in (1, 2)]
    np.testing.assert_array_equal(runs[0].levels, runs[1].levels)
    assert runs[0].trace == runs[1].trace and runs[0].objective == runs[1].objective
    assert runs[0].evaluations == runs[1].evaluations


def test_design_levels_do_not_depend_on_jobs(s61m):
    kw = dict(duration=3.0, record=8.0, n_iter=100, restarts=2, kicks=2, nominal_kicks=1, draws=0, extreme_draws=1)
    a, b = (SequenceDesign("theta_s", jobs=j, **kw).fit(s61m) for j in (1, 2))
    np.testing.assert_array_equal(a.levels_, b.levels_)
    assert a.amplitude_[0] == b.amplitude_[0]


def _fails(objective, fly, i):
    if i == 1:
        raise ValueError("bad step 1")
    return i


def _dies(objective, fly, i):
    if i == 1:
        os._exit(3)
    return i


def test_a_failing_worker_is_one_clear_error_and_leaves_no_process():
    with pytest.raises(DesignError, match=r"^design worker failed: ValueError: bad step 1$"):
        run_tasks(_fails, [(i,) for i in range(4)], None, None, jobs=2)
    with pytest.raises(DesignError, match="worker process died"):
        run_tasks(_dies, [(i,) for i in range(4)], None, None, jobs=2)
    assert not multiprocessing.active_children()
    assert run_tasks(_fails, [(0,), (2,)], None, None, jobs=2) == [0, 2]


@pytest.mark.parametrize("jobs", [0, -1, 1.5])
def test_bad_jobs_is_one_clear_error(s61m, jobs):
    with pytest.raises(DesignError, match="jobs must be a positive whole number"):
        SequenceDesign("theta_s", jobs=jobs).n_steps()


def _sleeps(objective, fly, i):
    import time
    time.sleep(30)
    return i


def _interrupt_sleeping_tasks_after(seconds: float) -> None:
    """run_tasks on sleeping tasks in 2 workers, Ctrl-C in the parent (a KeyboardInterrupt raised
    by a timer) after ``seconds``; passes when the interrupt reaches the caller."""
    import signal

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, interrupt)
    try:
        signal.setitimer(signal.ITIMER_REAL, seconds)
        with pytest.raises(KeyboardInterrupt):
            run_tasks(_sleeps, [(i,) for i in range(4)], None, None, jobs=2)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def test_an_interrupt_stops_the_workers_at_once():
    """Ctrl-C in the parent ends the search without waiting for the running tasks, and no worker
    outlives it."""
    import time

    t0 = time.perf_counter()
    _interrupt_sleeping_tasks_after(0.5)
    assert time.perf_counter() - t0 < 10
    assert not multiprocessing.active_children()


def test_workers_die_of_the_terminate_even_when_the_parent_catches_sigterm(monkeypatch):
    """pygame's SDL catches SIGTERM in the process that shows the cueing display; a forked worker
    inherits that handler and would outlive terminate() until killed 5 s later. Each worker must
    end by the SIGTERM itself, and be recorded as ended when the interrupt reaches the caller."""
    import signal
    from concurrent.futures import ProcessPoolExecutor

    import signaldesign.workers as workers

    spawned = []

    class Recording(ProcessPoolExecutor):
        def _spawn_process(self):
            super()._spawn_process()
            spawned.extend(p for p in self._processes.values() if p not in spawned)

    monkeypatch.setattr(workers, "ProcessPoolExecutor", Recording)
    old = signal.signal(signal.SIGTERM, lambda signum, frame: None)
    try:
        _interrupt_sleeping_tasks_after(0.5)
    finally:
        signal.signal(signal.SIGTERM, old)
    assert len(spawned) == 2
    assert [p.exitcode for p in spawned] == [-signal.SIGTERM] * 2
    assert not multiprocessing.active_children()
