"""The upper bound on the design criterion (signaldesign.bound): valid for every sequence."""
import numpy as np
import pytest

from identify import LinearModel, load_profile
from signaldesign.baselines import doublet, m3211
from signaldesign.bound import ModelBound, _spanning_rows, model_bound, objective_bound
from signaldesign.design import Flyability, Objective, StepBasis, anneal, enumerate_sequences, prior_weights
from signaldesign.evaluate import Evaluator
from signaldesign.robust import design_set


@pytest.fixture(scope="module")
def s61m():
    return LinearModel(load_profile("s61_hover_8state"))


class Recorder(Objective):
    """An objective that keeps every value it scores (the candidates a search visits)."""

    def __call__(self, levels):
        value = super().__call__(levels)
        self.seen = getattr(self, "seen", []) + [value]
        return value


@pytest.mark.parametrize("criterion, amplitude", [("nominal", None), ("robust", None), ("nominal", 0.004)])
def test_bound_exceeds_every_sequence_and_every_visited_candidate(s61m, criterion, amplitude):
    ev = Evaluator(s61m, "theta_s", record=10.0, dt=0.05)
    models, _ = design_set(s61m)
    basis = StepBasis(ev, 0.5, 9, models=models[:4])
    kw = dict(amplitude=amplitude, offsets=np.arange(4.0), weights=prior_weights(4, 0.5))
    fly = Flyability(1, 8, 2)
    L = enumerate_sequences(9, fly)
    values = Objective(basis, criterion, **kw).batch(L)
    best = L[int(np.argmax(values))]
    bound = objective_bound(Objective(basis, criterion, **kw), best)
    assert np.all(values <= bound.value + 1e-9)
    # the bound is a bound, not a reached value: the relaxation is wider than the flyable set
    assert bound.value >= values.max() and np.isfinite(bound.value)
    rec = Recorder(basis, criterion, **kw)
    anneal(rec, fly, n_iter=200, restarts=2, seed=0)
    assert len(rec.seen) > 100 and max(rec.seen) <= bound.value + 1e-9
    # the classic inputs, on the grid (pulse widths multiples of 0.5 s)
    for sig in (m3211(0.5), doublet(1.5)):
        levels = np.zeros(9)
        levels[:sig.levels.size] = sig.levels
        assert Objective(basis, criterion, **kw)(levels) <= bound.value + 1e-9


def test_bound_is_tight_where_the_relaxation_is_the_problem(s61m):
    """One step and one parameter: M(l) = l^2 G and the relaxation's optimum is the flyable one
    (the unit pulse at its equal-peak amplitude), so the bound meets the optimum; within 0.01 because
    the weights mu spread over the samples next to the peak (the update converges slowly there)."""
    ev = Evaluator(s61m, "theta_s", record=10.0, dt=0.05, params=[0])
    basis = StepBasis(ev, 1.0, 1)
    obj = Objective(basis, "nominal")
    value = obj(np.ones(1))
    assert objective_bound(obj, np.ones(1)).value == pytest.approx(value, abs=1e-2)


def test_levels_that_move_no_limited_output_leave_the_information_unbounded():
    """A step whose response no limit sees can grow without end: the bound is +inf, not an error."""
    G = np.zeros((2, 2, 1, 1))
    G[0, 0] = G[1, 1] = 1.0
    A = np.array([[1.0, 0.0], [0.5, 0.0]])  # only the first step is seen by a limit
    assert model_bound(G, A, np.eye(1), start=np.array([1.0, 1.0])).value == np.inf
    A[:, 1] = [0.0, 1.0]  # both limited: |v1| <= 1, |v1/2 + v2| <= 1; the optimum v = (1, -1.5)
    bound = model_bound(G, A, np.eye(1) * 3.25, start=np.array([1.0, -1.5]))
    assert bound.relaxed <= np.log(3.25) + 1e-9 <= bound.value + 2e-9 and bound.value < np.inf
    assert bound.value - bound.relaxed < 1e-3  # one parameter: the relaxation is the problem


def test_the_bound_meets_the_relaxation_it_bounds(s61m):
    """The bound is the semidefinite relaxation's dual: on the S 61 (16 parameters, 20 steps) it
    lies within 1 log det unit of a value the relaxation reaches (the bound's own slack), and above
    every flyable sequence."""
    ev = Evaluator(s61m, "theta_s", record=10.0, dt=0.05)
    basis = StepBasis(ev, 0.3, 20)
    obj = Objective(basis, "nominal")
    best = anneal(obj, Flyability(1, 8, 2), n_iter=300, restarts=1, seed=0)
    bound = objective_bound(obj, best.levels)
    assert best.objective <= bound.relaxed[0] <= bound.value
    assert bound.value - bound.relaxed[0] < 1.5


def test_the_rows_kept_span_every_level():
    """On large problems the weights use a subset of the rows (the most pressed and a spread); a
    subset that misses a level's direction leaves H singular and the bound infinite (a four-input run
    kept rows of rank 244 of 280), so K rows spanning every level are kept too."""
    rng = np.random.default_rng(0)
    A = np.zeros((400, 30))
    A[:, :25] = rng.standard_normal((400, 25))
    A[rng.choice(400, 5, replace=False), 25:] = np.eye(5)  # five rows alone see the last five levels
    rows = _spanning_rows(A)
    assert rows.size == 30 and np.linalg.matrix_rank(A[rows]) == 30


def test_an_infinite_model_bound_bounds_nothing(s61m, monkeypatch):
    """One model's infinite bound makes the criterion's bound infinite (the combination once read it
    as -inf, and the design printed a certified D-efficiency of 1); the certificate then says none."""
    import signaldesign.bound as bound_module

    ev = Evaluator(s61m, "theta_s", record=10.0, dt=0.05)
    models, _ = design_set(s61m)
    basis = StepBasis(ev, 0.5, 9, models=models[:3])
    obj = Objective(basis, "robust", offsets=np.zeros(3), weights=prior_weights(3, 0.5))
    real = bound_module._model_term

    def one_unbounded(objective, fly, m, levels, effort):
        return ModelBound(np.inf, np.inf) if m == 1 else real(objective, fly, m, levels, effort)

    monkeypatch.setattr(bound_module, "_model_term", one_unbounded)
    levels = m3211(0.5).levels[:9]
    assert objective_bound(obj, np.concatenate([levels, np.zeros(9 - levels.size)]), effort="quick").value == np.inf
