"""Optimised three-level sequences: the quadratic information form, the searches, constraints."""
import dataclasses
import itertools

import numpy as np
import pytest

from identify import LinearModel, load_profile, simulate
from signaldesign.baselines import m3211
from signaldesign.design import (Flyability, Objective, SequenceDesign, StepBasis, _changes, anneal,
                                 count_sequences, enumerate_sequences, exhaustive, prior_weights)
from signaldesign.robust import design_set, evaluation_set, frequency_scaled
from signaldesign.evaluate import DesignError, Evaluator, record_inputs
from signaldesign.information import default_noise, fisher_information


@pytest.fixture(scope="module")
def s61m():
    return LinearModel(load_profile("s61_hover_8state"))


@pytest.fixture(scope="module")
def ev(s61m):
    return Evaluator(s61m, "theta_s", record=12.0, dt=0.05)


def test_step_basis_information_and_outputs_equal_the_direct_ones(s61m):
    ev2 = Evaluator(s61m, ["theta_s", "theta_c"], record=10.0, dt=0.05)
    basis = StepBasis(ev2, 0.4, 9, delay=0.35)
    levels = np.random.default_rng(3).integers(-1, 2, 18).astype(float)
    signals = basis.signals(levels, [0.02, 0.015])
    u = record_inputs(s61m, signals, 10.0, 0.05)
    M = fisher_information(s61m, u, 0.05, default_noise(s61m.profile))[np.ix_(ev2.params, ev2.params)]
    scaled = levels * np.repeat([0.02, 0.015], 9)
    np.testing.assert_allclose(basis.information(scaled), M, rtol=1e-10, atol=1e-12 * np.abs(M).max())
    np.testing.assert_allclose(ev2.information(signals), M, rtol=1e-10, atol=1e-12 * np.abs(M).max())
    y = simulate(s61m, u, 0.05).y
    np.testing.assert_allclose(basis.peaks(scaled), np.abs(y).max(axis=0), rtol=1e-10, atol=1e-15)


def test_objective_low_rank_updates_match_scratch(s61m, ev):
    models, _ = design_set(s61m)
    basis = StepBasis(ev, 0.2, 20, models=models[:3])
    rng = np.random.default_rng(0)
    levels = rng.integers(-1, 2, 20).astype(float)
    obj = Objective(basis, "mean")
    obj.reset(levels)
    for _ in range(30):
        cand = levels.copy()
        start = int(rng.integers(0, 18))
        cand[start:start + 3] = rng.integers(-1, 2, 3)
        assert obj(cand) == pytest.approx(Objective(basis, "mean")(cand), rel=1e-9)
        if rng.random() < 0.5:
            obj.commit()
            levels = cand


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
def test_annealing_ranks_among_the_best_flyable_sequences(ev, K, width, fly, seed):
    """Information per unit of peak response is a rugged landscape (a switch moved by one step can
    move the late peak of an unstable response a lot): annealing with restarts is a heuristic, so
    the claim is its rank among every flyable sequence, scored exhaustively."""
    basis = StepBasis(ev, width, K)
    best = exhaustive(Objective(basis), fly)
    found = anneal(Objective(basis), fly, n_iter=400, restarts=20, seed=seed)
    assert fly.feasible(found.levels)
    values = np.sort(Objective(basis).batch(enumerate_sequences(K, fly)))[::-1]
    assert best.objective == pytest.approx(values[0], abs=1e-9)
    assert _rank(found.objective, values) < max(3, 0.002 * values.size), values[:3]


def test_two_axis_annealing_ranks_among_the_best(s61m):
    ev2 = Evaluator(s61m, ["theta_s", "theta_c"], record=10.0, dt=0.05)
    basis = StepBasis(ev2, 0.8, 5)
    fly = Flyability(1, 4, 1)
    best = exhaustive(Objective(basis), fly)
    found = anneal(Objective(basis), fly, n_iter=400, restarts=20, seed=4)
    one, full = enumerate_sequences(5, fly), enumerate_sequences(5, fly, canonical=False)
    L = np.array([np.concatenate([a, b]) for a in one for b in full])
    values = np.sort(Objective(basis).batch(L))[::-1]
    assert best.objective == pytest.approx(values[0], abs=1e-9)
    assert _rank(found.objective, values) < max(3, 0.002 * values.size), values[:3]


def _rank(value, values) -> int:
    """How many of ``values`` beat ``value``: within the top 0.2 % (at least the top 3) counts."""
    return int(np.sum(values > value + 1e-9))


def test_design_respects_flyability_and_limits_and_beats_the_3211_at_equal_peak(s61m):
    d = SequenceDesign("theta_s", duration=5.0, record=12.0, grid=0.1, min_pulse=0.5, max_changes=8,
                       allow_double_jumps=False, criterion="nominal", n_iter=1500, restarts=2).fit(s61m)
    (sig,) = d.signals_
    levels = sig.levels
    assert set(np.unique(levels)) <= {-1.0, 0.0, 1.0} and abs(sig.duration - 5.0) <= 1e-9
    padded = np.concatenate([[0], levels, [0]])  # starts from and returns to trim
    assert np.abs(np.diff(padded)).max() == 1  # no +1 -> -1 jump
    assert 4 <= np.count_nonzero(np.diff(padded)) <= 8
    holds = np.diff(np.flatnonzero(np.diff(padded)))  # every hold between two changes
    assert holds.min() * sig.dt >= 0.5 - 1e-9
    # the simulated peak of every output stays within its limit, and one of them is at it
    u = record_inputs(s61m, d.signals_, 12.0, 0.05)
    ratio = np.abs(simulate(s61m, u, 0.05).y).max(axis=0) / [s61m.profile.limits[y] for y in s61m.profile.outputs]
    assert ratio.max() <= 1 + 1e-9 and ratio.max() > 0.999
    assert d.binding_ == s61m.profile.outputs[int(np.argmax(ratio))] and "BINDS" in d.summary()
    # more information than every 3211 of 0.5 s pulses or longer, each at equal peak response
    ev = Evaluator(s61m, "theta_s", 12.0, 0.05)
    best3211 = max(ev.equal_peak_log_det(m3211(w)) for w in np.arange(0.5, 0.75, 0.05))
    assert ev.equal_peak_log_det(d.signals_) > best3211
    # the restarts' agreement is said (D-efficiency of the worst restart against the best) and recorded
    spread = max(d.result_.trace) - min(d.result_.trace)
    assert d.spread_efficiency_ == pytest.approx(np.exp(-spread / d.evaluator_.p))
    said = "they agree" if spread <= -d.evaluator_.p * np.log(0.99) else "they DISAGREE beyond 1 %"
    assert said in d.summary() and f"{d.spread_efficiency_:.3f} of the best" in d.summary()
    assert d.signals_[0].params["restarts_spread"] == pytest.approx(spread)


def test_fixed_amplitude_is_flown_or_reported_infeasible(s61m):
    kw = dict(duration=3.0, record=8.0, grid=0.3, criterion="nominal", n_iter=300, restarts=1)
    d = SequenceDesign(amplitude=0.005, **kw).fit(s61m)
    assert d.amplitude_[0] == 0.005 and np.all(d.peaks_ <= d.limits_)
    with pytest.raises(DesignError, match=r"infeasible: .* keeps \w+ within its limit"):
        SequenceDesign(amplitude=2.0, **kw).fit(s61m)


def test_without_profile_limits_the_3211_peaks_are_the_limits(s61m):
    bare = LinearModel(dataclasses.replace(s61m.profile, limits={}))
    d = SequenceDesign(duration=3.5, record=8.0, grid=0.5, criterion="nominal", min_pulse=0.5).fit(bare)
    assert "best-width 3211" in d.evaluator_.limits_source
    ev = d.evaluator_
    widths = np.arange(0.5, 0.51, 0.05)  # a 3.5 s 3211 has 0.5 s pulses
    ref = max((m3211(w, 0.02) for w in widths), key=lambda s: np.linalg.slogdet(ev.information(s))[1])
    np.testing.assert_allclose(ev.limits[ev.limits > 0], ev.peaks(ref)[ev.limits > 0], rtol=1e-12)
    assert np.all(d.peaks_ <= ev.limits * (1 + 1e-9))


def test_frequency_scaling_scales_every_eigenvalue(s61m):
    k = 1.6
    fast = frequency_scaled(s61m, k)
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(fast.A)),
                               np.sort_complex(k * np.linalg.eigvals(s61m.A)), rtol=1e-9)
    np.testing.assert_allclose(fast.B, k * s61m.B)
    models, labels = evaluation_set(s61m)
    assert len(models) == 20 and labels[0] == "a priori" and models[0] is s61m


def test_robust_and_nominal_designs_are_each_optimal_for_their_criterion(s61m):
    models, labels = design_set(s61m)
    kw = dict(duration=2.4, record=8.0, grid=0.4, min_pulse=0.4, models=models[:4], model_labels=labels[:4])
    robust = SequenceDesign(criterion="mean", **kw).fit(s61m)  # 6 steps: exhaustive
    nominal = SequenceDesign(criterion="nominal", **kw).fit(s61m)
    assert robust.result_.method == nominal.result_.method == "exhaustive" and robust.gap_ == 0
    w = prior_weights(4, robust.apriori_weight)
    mean = Objective(robust.basis_, "mean", weights=w)
    nom = Objective(robust.basis_, "nominal")
    assert mean(robust.levels_) >= mean(nominal.levels_) - 1e-9
    assert nom(nominal.levels_) >= nom(robust.levels_) - 1e-9


def test_robust_criterion_mixes_mean_and_worst_and_keeps_the_nominal_floor(s61m):
    models, labels = design_set(s61m)
    assert len(models) == 13 and sum("x0.60, derivs" in x for x in labels) == 3
    kw = dict(duration=2.8, record=8.0, grid=0.4, min_pulse=0.4, models=models[:5], model_labels=labels[:5])
    d = SequenceDesign(**kw).fit(s61m)  # default criterion: robust; 6 steps: exhaustive
    assert d.criterion == "robust" and d.result_.method == "exhaustive"
    obj = Objective(d.basis_, "robust", offsets=np.arange(5.0), weights=prior_weights(5, 0.5), worst_weight=2.0)
    levels = d.levels_
    rel = np.array([Objective(d.basis_, "mean", weights=np.eye(5)[m])(levels) for m in range(5)]) - np.arange(5.0)
    assert obj(levels) == pytest.approx(rel @ prior_weights(5, 0.5) + 2.0 * rel.min(), rel=1e-9)
    soft = Objective(d.basis_, "robust", offsets=np.arange(5.0), weights=prior_weights(5, 0.5), softness=1.0)
    assert soft(levels) < Objective(d.basis_, "robust", offsets=np.arange(5.0), weights=prior_weights(5, 0.5))(levels)
    floored = Objective(d.basis_, "robust", offsets=np.arange(5.0), weights=prior_weights(5, 0.5),
                        nominal_floor=rel[0] + 1.0)
    plain = Objective(d.basis_, "robust", offsets=np.arange(5.0), weights=prior_weights(5, 0.5))
    assert floored(levels) == pytest.approx(plain(levels) - Objective.FLOOR_PENALTY)
    # a floor the nominal optimum clears is kept by the robust optimum (exhaustive; the penalty,
    # 20 per unit of log det, outweighs what the mean and the worst gain); out of reach (the default
    # here), the design says so
    best = SequenceDesign(criterion="nominal", **kw).fit(s61m)
    floored = SequenceDesign(nominal_margin=0.8 * best.nominal_gain_, **kw).fit(s61m)
    assert floored.nominal_gain_ >= 0.8 * best.nominal_gain_ * (1 - 1e-9)
    assert d.nominal_gain_ < d.nominal_margin and "NOT REACHED" in d.summary()


@pytest.mark.parametrize("profile", ["s61_hover_8state", "s61_hover_4dof", "bo105_70kt", "navion_cruise_long",
                                     "hover_4input"])
def test_default_design_on_every_bundled_profile_is_no_plain_step(profile):
    model = LinearModel(load_profile(profile))
    d = SequenceDesign(model.profile.input_names[0], n_iter=200, restarts=1, kicks=4, nominal_kicks=2).fit(model)  # small budget
    assert _changes(d.levels_) >= 4
    u = record_inputs(model, d.signals_, 20.0, 0.05)
    y = simulate(model, u, 0.05).y
    limits = np.array([model.profile.limits.get(o, np.inf) for o in model.profile.outputs])
    assert np.max(np.abs(y).max(axis=0) / limits) <= 1 + 1e-9


@pytest.mark.parametrize("kwargs, message", [
    (dict(duration=0.1), "fewer than two"),
    (dict(max_changes=1), "at least 2"),
    (dict(min_pulse=9.0), "exceeds the duration"),
    (dict(duration=7.0, record=5.0), "does not fit"),
    (dict(criterion="best"), "unknown criterion"),
    (dict(dt=0.0), "time step"),
    (dict(grid=0.07), "not a multiple"),
    (dict(limits={"zz": 1.0}), "'zz': not an output"),
    (dict(limits={"theta": 0.0}), "must be positive"),
])
def test_impossible_designs_give_one_clear_error(s61m, kwargs, message):
    with pytest.raises(DesignError, match=message):
        SequenceDesign(**{"record": 10.0, "n_iter": 100, "restarts": 1, **kwargs}).fit(s61m)
