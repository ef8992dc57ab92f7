"""Several inputs in one run at equal per-input peak response (each input as large as its own
response allows): the criterion's low-rank updates, its bound, and the design."""
import itertools

import numpy as np
import pytest

from identify import LinearModel, load_profile
from signaldesign.bound import objective_bound
from signaldesign.design import DesignError, SequenceDesign
from signaldesign.evaluate import Evaluator
from signaldesign.quadform import PerInputObjective, StepBasis
from signaldesign.robust import design_set

INPUTS = ["theta_s", "theta_c"]


@pytest.fixture(scope="module")
def s61m():
    return LinearModel(load_profile("s61_hover_8state"))


def _direct(basis, inv_limits, levels, m):
    """log det of model m's information with each axis scaled alone to peak/limit 1, from scratch."""
    K, v = basis.n_steps, np.array(levels, float)
    for a in range(len(basis.inputs)):
        alone = np.where(np.arange(v.size) // K == a, levels, 0.0)
        v[a * K:(a + 1) * K] /= (basis.peaks(alone, m) * inv_limits).max()
    return np.linalg.slogdet(basis.information(v, m))[1]


def _walk(obj, rng, axes: int, steps: int, starts: int, trials: int):
    """Random proposals of one or two steps on one axis from a base that moves on two trials in
    three (the objective's low-rank state committed with it); the caller scores each proposal
    and may edit it before the commit."""
    levels = rng.integers(-1, 2, axes * steps).astype(float)
    obj.reset(levels)
    for trial in range(trials):
        cand = levels.copy()
        a, k = rng.integers(axes), rng.integers(starts)
        cand[a * steps + k:a * steps + k + rng.integers(1, 3)] = rng.integers(-1, 2)
        yield trial, cand
        if trial % 3:
            obj.commit()
            levels = cand


def test_low_rank_updates_match_the_information_from_scratch(s61m):
    ev = Evaluator(s61m, INPUTS, record=12.0, dt=0.05)
    models, _ = design_set(s61m, draws=1, extreme_draws=1)
    basis = StepBasis(ev, 0.2, 15, models=models[:3])
    obj = PerInputObjective(basis, "mean")
    for _, cand in _walk(obj, np.random.default_rng(1), axes=2, steps=15, starts=14, trials=25):
        want = np.mean([_direct(basis, obj.inv_limits, cand, m) for m in range(3)])
        assert obj(cand) == pytest.approx(want, abs=1e-8)


def test_low_rank_updates_on_three_axes_match_from_scratch():
    """With more than two axes a proposal on axis c leaves the others' scales and blocks alone:
    the update splits the information by axis (the four-input hover's case), checked against
    scores from scratch, including proposals that put an axis at rest and bring it back."""
    model = LinearModel(load_profile("hover_4input"))
    ev = Evaluator(model, ["theta_s", "theta_0", "theta_TR"], record=6.0, dt=0.05)
    models, _ = design_set(model, draws=1, extreme_draws=1)
    basis = StepBasis(ev, 0.3, 8, models=models[:2])
    obj = PerInputObjective(basis, "robust", offsets=np.zeros(2), weights=np.ones(2))
    for trial, cand in _walk(obj, np.random.default_rng(2), axes=3, steps=8, starts=8, trials=30):
        if trial == 10:
            cand[8:16] = 0.0  # the collective at rest: its scale 0
        fresh = PerInputObjective(basis, "robust", offsets=np.zeros(2), weights=np.ones(2))(cand)
        assert obj(cand) == pytest.approx(fresh, abs=1e-8)


def test_bound_exceeds_every_two_axis_sequence(s61m):
    ev = Evaluator(s61m, INPUTS, record=8.0, dt=0.05, params=[0, 3, 5, 7])
    basis = StepBasis(ev, 0.5, 3)
    obj = PerInputObjective(basis, "nominal")
    one = [np.array(s, float) for s in itertools.product((-1, 0, 1), repeat=3) if any(s)]
    values = np.array([obj(np.concatenate([a, b])) for a in one for b in one])
    best = np.argmax(values)
    bound = objective_bound(obj, np.concatenate([one[best // len(one)], one[best % len(one)]]))
    assert np.isfinite(bound.value) and values.max() <= bound.value + 1e-9


def test_design_flies_each_input_at_its_own_limit_and_beats_the_shared_design_there(s61m):
    kw = dict(duration=3.0, grid=0.3, min_pulse=0.3, max_changes=6, criterion="nominal", restarts=2, n_iter=150,
              kicks=2, nominal_kicks=0, jobs=1, record=12.0)
    per = SequenceDesign(INPUTS, peak="per-input", **kw).fit(s61m)
    shared = SequenceDesign(INPUTS, **kw).fit(s61m)
    ev = Evaluator(s61m, INPUTS, record=12.0, dt=0.05)
    for a, sig in enumerate(per.signals_):
        assert Evaluator(s61m, [sig.input], record=12.0, dt=0.05).response([sig])[0] == pytest.approx(1.0, abs=1e-9)
    assert per.amplitude_[0] != pytest.approx(per.amplitude_[1])
    # scored by the rule it was designed for, the per-input design carries more information
    score = PerInputObjective(per.basis_, "nominal")
    assert score(per.levels_) > score(shared.levels_)
    assert "equal per-input peak response" in per.summary()
    assert ev.p == per.evaluator_.p
    with pytest.raises(DesignError, match="amplitude"):
        SequenceDesign(INPUTS, peak="per-input", amplitude=0.01, **kw).n_steps()


def test_robust_per_input_yardsticks_are_the_3211_flown_by_the_same_rule(s61m):
    """Each model's yardstick is the grid 3211 with every input at its own peak on that model, so
    the 3211 scores exactly 0 (relative D-efficiency 1) on every model; the shared-peak yardsticks
    would leave it a different offset per model and mislead the worst-model term."""
    from signaldesign.robust import frequency_scaled
    models = [s61m, frequency_scaled(s61m, 0.7), frequency_scaled(s61m, 1.4)]
    d = SequenceDesign(INPUTS, peak="per-input", criterion="robust", models=models, duration=3.0, grid=0.3,
                       min_pulse=0.3, max_changes=6, restarts=1, n_iter=60, kicks=0, nominal_kicks=0, jobs=1,
                       record=12.0).fit(s61m)
    start = d._starts(d.evaluator_, d.basis_)[0][0]
    assert d._objective_.exact().terms(start) == pytest.approx(np.zeros(3), abs=1e-9)
