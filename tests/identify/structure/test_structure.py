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


def _coefficient_runs(rng, n_runs=3, n=1500):
    """Runs of a coefficient-form aircraft whose C_L bends at alpha = 0.15 and whose C_m has an
    alpha^2 term, recorded with the pitch acceleration (q_dot) and the accelerometers."""
    p = load_profile("light_aircraft_coefficients_long")
    table = p.meta["coefficients"]
    runs = []
    for r in range(n_runs):
        t = np.arange(n) * 0.02
        alpha = 0.06 + 0.05 * r + 0.03 * np.sin(1.3 * t + r) + 0.01 * rng.standard_normal(n)
        de = 0.02 * np.sign(np.sin(0.9 * t + 2 * r))
        q = 0.05 * np.cos(1.7 * t + r)
        V = 40 + 3 * np.sin(0.2 * t)
        qS = 0.5 * table["density"] * V ** 2 * table["area"]
        cl = 0.3 + 4.5 * alpha - 3.0 * np.maximum(alpha - 0.15, 0) + 0.36 * de
        cm = 0.05 - 0.7 * alpha - 2.0 * alpha ** 2 - 12 * q * table["chord"] / (2 * V) - 1.1 * de
        cm = cm + 0.002 * rng.standard_normal(n)
        channels = {"u": V * np.cos(alpha), "w": V * np.sin(alpha), "q": q, "theta": alpha, "V": V, "alpha": alpha,
                    # no drag and no thrust: C_X = 0, C_L = -C_Z cos(alpha)
                    "a_x": np.zeros(n), "a_z": -cl * qS / table["mass"] / np.cos(alpha), "delta_e": de,
                    "q_dot": cm * qS * table["chord"] / table["inertia"]["M"]}
        runs.append(Run(t, channels, {}, source=f"<run {r}>"))
    return p, runs


def test_coefficient_form_ties_and_finds_the_nonlinear_terms_in_the_coefficients():
    p, runs = _coefficient_runs(np.random.default_rng(3))
    qbar0 = 0.5 * 1.225 * 40.0 ** 2
    assert p.ties["C_m_alpha"] == {"M_w": pytest.approx(qbar0 * 16.7 * 1.74 / (4070.0 * 40.0))}
    assert p.ties["C_L_delta_e"] == {"Z_delta_e": pytest.approx(-qbar0 * 16.7 / 1270.0)}
    search = StructureSearch(p, nonlinear=("alpha",), knots={"alpha": [0.15]}).fit(runs)
    assert search.skipped_  # output error does not judge a model over several trims
    fits = {s.problem.label: s.fit for s in search.selections_}
    assert {"C_L_alpha_k1", "C_L_alpha", "C_L_delta_e"} == set(fits["Z"].terms)
    assert {"C_m_alpha_sq", "C_m_alpha", "C_m_q", "C_m_delta_e"} == set(fits["M"].terms)
    assert fits["Z"].value("C_L_alpha_k1")[0] == pytest.approx(-3.0, abs=0.05)
    assert fits["M"].value("C_m_alpha_sq")[0] == pytest.approx(-2.0, abs=0.2)
    assert "C_L_alpha_k1" in search.profile_.free and "alpha_k1" in search.profile_.meta["pseudo_inputs"]
