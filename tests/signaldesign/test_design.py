"""Optimised three-level sequences: the quadratic information form, the searches, constraints."""
import itertools

import numpy as np
import pytest

from identify import LinearModel, load_profile
from signaldesign.baselines import m3211
from signaldesign.design import (Flyability, Objective, SequenceDesign, StepBasis, anneal, count_sequences,
                                 enumerate_sequences, exhaustive)
from signaldesign.evaluate import DesignError, Evaluator, record_inputs
from signaldesign.information import default_noise, fisher_information


@pytest.fixture(scope="module")
def s61m():
    return LinearModel(load_profile("s61_hover_8state"))


@pytest.fixture(scope="module")
def ev(s61m):
    return Evaluator(s61m, "theta_s", record=12.0, dt=0.05)


def test_step_basis_information_equals_the_direct_fisher_information(s61m):
    ev2 = Evaluator(s61m, ["theta_s", "theta_c"], record=10.0, dt=0.05)
    basis = StepBasis(ev2, 0.4, 9, [0.02, 0.015], delay=0.35)
    levels = np.random.default_rng(3).integers(-1, 2, 18).astype(float)
    signals = basis.signals(levels)
    u = record_inputs(s61m, signals, 10.0, 0.05)
    M = fisher_information(s61m, u, 0.05, default_noise(s61m.profile))[np.ix_(ev2.params, ev2.params)]
    np.testing.assert_allclose(basis.information(levels), M, rtol=1e-10, atol=1e-12 * np.abs(M).max())
    np.testing.assert_allclose(ev2.information(signals), M, rtol=1e-10, atol=1e-12 * np.abs(M).max())
    assert basis.log_dets(levels)[0] == pytest.approx(np.linalg.slogdet(M)[1], rel=1e-10)


@pytest.mark.parametrize("fly", [Flyability(), Flyability(2, 6, 1), Flyability(1, 5, 2), Flyability(3, None, 2)])
def test_enumeration_and_count_agree_with_brute_force(fly):
    for K in (5, 7):
        brute = [q for q in itertools.product((-1, 0, 1), repeat=K) if fly.feasible(q)]
        assert all(fly.feasible(q) == (not fly.violations(q)) for q in itertools.product((-1, 0, 1), repeat=K))
        canonical = {q for q in brute if next(v for v in q if v) == 1}
        listed = {tuple(int(v) for v in row) for row in enumerate_sequences(K, fly)}
        assert listed == canonical and count_sequences(K, fly) == len(canonical)


@pytest.mark.parametrize("K, width, fly, seed", [
    (9, 0.6, Flyability(), 0),
    (10, 0.5, Flyability(2, 8, 1), 1),
    (9, 0.7, Flyability(1, 6, 2), 2),
    (11, 0.45, Flyability(2, None, 1), 3),
])
def test_annealing_finds_the_exhaustive_optimum(ev, K, width, fly, seed):
    basis = StepBasis(ev, width, K, 0.02)
    best = exhaustive(Objective(basis), fly)
    found = anneal(Objective(basis), fly, n_iter=2000, restarts=2, seed=seed)
    assert found.objective == pytest.approx(best.objective, abs=1e-9)
    assert np.array_equal(found.levels, best.levels) or np.array_equal(found.levels, -best.levels)
    assert fly.feasible(found.levels)
    # and the exhaustive optimum really is the best of a random sample of flyable sequences
    L = enumerate_sequences(K, fly)
    assert best.objective >= Objective(basis).batch(L).max() - 1e-9


def test_two_axis_annealing_finds_the_exhaustive_optimum(s61m):
    ev2 = Evaluator(s61m, ["theta_s", "theta_c"], record=10.0, dt=0.05)
    basis = StepBasis(ev2, 0.8, 5, 0.02)
    fly = Flyability(1, 4, 1)
    best = exhaustive(Objective(basis), fly)
    found = anneal(Objective(basis), fly, n_iter=3000, restarts=2, seed=4)
    assert found.objective == pytest.approx(best.objective, abs=1e-9)


def test_design_respects_every_flyability_constraint(s61m):
    d = SequenceDesign("theta_s", duration=5.0, record=12.0, amplitude=0.02, min_width=0.4, max_width=0.7,
                       min_pulse=0.9, max_changes=6, n_iter=1500, restarts=1).fit(s61m)
    (sig,) = d.signals_
    levels = sig.levels
    assert set(np.unique(levels)) <= {-1.0, 0.0, 1.0}
    assert abs(sig.duration - 5.0) <= sig.dt / 2 + 1e-9
    padded = np.concatenate([[0], levels, [0]])  # starts from and returns to trim
    assert np.abs(np.diff(padded)).max() == 1  # no +1 -> -1 jump
    assert np.count_nonzero(np.diff(padded)) <= 6
    holds = np.diff(np.flatnonzero(np.diff(padded)))  # every hold between two changes
    assert holds.min() * sig.dt >= 0.9 - 1e-9
    assert d.flyability(sig.dt).violations(levels) == []
    # and it carries more information than the best 3211 of the same length and amplitude
    best3211 = max((m3211(w, 0.02) for w in np.arange(0.2, 0.75, 0.05).round(2)),
                   key=lambda s: np.linalg.slogdet(d.evaluator_.information(s))[1])
    assert np.linalg.slogdet(d.evaluator_.information(sig))[1] > np.linalg.slogdet(
        d.evaluator_.information(best3211))[1]


def test_robust_and_peak_limited_designs(s61m):
    ref = m3211(0.5, 0.02)
    kw = dict(duration=3.5, record=10.0, amplitude=0.02, widths=[0.5], reference=ref)  # 7 steps: exhaustive
    capped = SequenceDesign(max_peak=1.0, **kw).fit(s61m)
    ev = capped.evaluator_
    assert np.all(ev.peaks(capped.signals_) <= ev.peaks(ref) * (1 + 1e-9))
    free = SequenceDesign(**kw).fit(s61m)
    assert np.any(ev.peaks(free.signals_) > ev.peaks(ref))  # so the cap did bind
    assert free.result_.objective >= capped.result_.objective
    robust = SequenceDesign(criterion="worst", perturbations=4, **kw).fit(s61m)
    assert robust.result_.method == free.result_.method == "exhaustive"
    basis = robust.basis_
    assert len(basis.models) == 5
    offsets = np.concatenate([[ev._ref[0]], [np.linalg.slogdet(robust.evaluator_.information(ref, m))[1]
                                             for m in basis.models[1:]]])
    worst = Objective(basis, "worst", offsets)
    nominal = Objective(basis, "nominal", offsets)
    # each design is optimal for its own criterion on the same models
    assert worst(robust.result_.levels) == pytest.approx(robust.result_.objective, abs=1e-9)
    assert worst(robust.result_.levels) >= worst(free.result_.levels) - 1e-12
    assert nominal(free.result_.levels) >= nominal(robust.result_.levels) - 1e-12


@pytest.mark.parametrize("kwargs, message", [
    (dict(duration=0.2), "shorter than one pulse"),
    (dict(max_changes=1), "at least 2"),
    (dict(min_pulse=9.0), "exceeds the duration"),
    (dict(duration=7.0, record=5.0), "does not fit"),
    (dict(criterion="best"), "unknown criterion"),
    (dict(criterion="worst"), "needs perturbed models"),
    (dict(max_peak=1.0), "needs reference"),
])
def test_impossible_designs_give_one_clear_error(s61m, kwargs, message):
    with pytest.raises(DesignError, match=message):
        SequenceDesign(**{"record": 10.0, "n_iter": 100, "restarts": 1, **kwargs}).fit(s61m)
