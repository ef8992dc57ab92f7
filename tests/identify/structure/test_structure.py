"""Structure determination: stepwise regression's choices on regressions with a known answer, and
the equation-error pass on a simulated aircraft whose a priori declares a truly zero derivative."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from identify import LinearModel, load_profile, simulate_run
from identify.data.runs import Run
from identify.errors import EstimationError
from identify.model.pseudo_inputs import channel, spline
from identify.structure import StructureSearch
from identify.structure.regression import Problem, Stepwise, orthogonal_ranking


def _problem(rng, n=2000, declared=("x1", "x3")):
    cols = {f"x{i}": rng.standard_normal(n) for i in range(1, 6)}
    cols["x2"] = 0.6 * cols["x1"] + 0.8 * cols["x2"]  # correlated with a true term
    y = 2.0 * cols["x1"] - 1.0 * cols["x4"] + 0.5 * rng.standard_normal(n) + 3.0
    return Problem("E", y, cols, [(0, n // 2), (n // 2, n)], declared=declared)


def test_stepwise_keeps_the_true_terms_drops_the_declared_zero_and_adds_the_missing_one():
    sel = Stepwise().select(_problem(np.random.default_rng(1)))
    assert sorted(sel.fit.terms) == ["x1", "x4"]  # x3 (declared, truly 0) left; x4 (undeclared) entered
    assert sel.fit.value("x1")[0] == pytest.approx(2.0, abs=0.05)
    actions = {(d.term, d.action) for d in sel.decisions}
    assert ("x3", "leave") in actions and ("x4", "enter") in actions
    assert sel.ranking[0][0] == "x4"  # the orthogonal ranking of candidates on what x1, x3 leave
    assert sel.fit.press >= sel.fit.sse  # leave-one-out residuals are never smaller


def test_orthogonal_ranking_sse_falls_and_skips_collinear_columns():
    rng = np.random.default_rng(2)
    a = rng.standard_normal(500)
    cols = {"a": a, "a2": 2 * a, "b": rng.standard_normal(500)}
    y = a + 0.1 * cols["b"] + 0.01 * rng.standard_normal(500)
    ranking = orthogonal_ranking(y, cols, ["a", "a2", "b"], [])
    assert [t for t, _ in ranking[1:]] in (["a", "b"], ["a2", "b"])  # one of the collinear pair only
    sse = [s for _, s in ranking]
    assert all(x > y for x, y in zip(sse, sse[1:]))


def test_spline_pseudo_input_is_the_hinge():
    run = Run(np.arange(4) * 0.1, {"alpha": np.array([0.0, 0.1, 0.2, 0.3])})
    np.testing.assert_allclose(channel("a_k1", spline("alpha", 0.15), run), [0, 0, 0.05, 0.15])


def _runs(truth, n_runs=2):
    t = np.arange(0, 12, 0.02)
    runs = []
    for k in range(n_runs):
        u = np.zeros((t.size, truth.n_inputs))
        j = k % truth.n_inputs
        u[(t > 1) & (t < 3), j], u[(t >= 3) & (t < 5), j] = 0.01, -0.01
        u[(t >= 5) & (t < 6), j] = 0.01
        runs.append(simulate_run(truth, t, u, noise_fraction=0.01, seed=k))
    return runs


def test_equation_error_pass_drops_a_declared_zero_and_writes_nothing_unsupported():
    base = load_profile("navion_cruise_long")
    truth = LinearModel(base)
    apriori = replace(base, free={**base.free, "X_delta_e": 0.5})  # declared, truly zero
    search = StructureSearch(apriori, confirm=False, candidates=False).fit(_runs(truth, 1))
    assert "X_delta_e" in search.dropped_
    assert search.profile_.fixed["X_delta_e"] == 0.0
    assert {"M_q", "M_w", "M_delta_e", "Z_w"} <= set(search.kept_)
    rows = {r["parameter"]: r for r in search.table()}
    assert rows["X_delta_e"]["fate"] == "dropped" and rows["X_delta_e"]["statistic"] < rows["X_delta_e"]["threshold"]


def test_nonlinear_names_must_be_channels():
    base = load_profile("navion_cruise_long")
    with pytest.raises(EstimationError, match="not in every run"):
        StructureSearch(base, nonlinear=("alpha",), confirm=False).fit(_runs(LinearModel(base), 1))
