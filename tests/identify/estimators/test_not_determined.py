"""What a fit cannot determine is said, never printed as a number: a non-positive variance, an
exactly or nearly redundant pair (with the combination the fit does determine), a declared output
bias that duplicates the zero shift fitted per run (issue #21)."""
import json

import numpy as np

from identify import ML, LinearModel, parse_profile, simulate_run
from identify.estimators.result import IdentificationResult
from tests.identify.estimators.test_identifiability import LONGITUDINAL, NOISE
from tests.identify.estimators.test_ml import steps_3211

SHORT = """
name = "short period"
states = { w = "m/s", q = "rad/s" }
inputs = { de = "rad", de2 = "rad" }
outputs = ["w", "q"]
[free]
Z_w = -2.0
M_w = -0.05
M_q = -2.0
M_de = -6.0
M_de2 = -6.0
[fixed]
Z_q = 50.0
Z_de = -10.0
"""


def _short_run(de2_noise: float, seed: int = 1):
    p = parse_profile(SHORT)
    truth = LinearModel(p)
    t = np.arange(0, 20.0, 0.02)
    de = steps_3211(t, 0.5, width=0.5, amp=0.02)
    rng = np.random.default_rng(seed)
    u = np.column_stack([de, de + de2_noise * rng.standard_normal(len(t))])
    return p, simulate_run(truth, t, u, noise={"w": 0.05, "q": 0.002}, seed=seed)


def test_a_non_positive_variance_is_nan_and_not_determined_with_the_reason(tmp_path):
    p = parse_profile(LONGITUDINAL)
    std = np.full(len(p.free), 0.1)
    std[2] = 0.0  # a negative variance the estimator clipped to zero
    res = IdentificationResult("ml", p, np.array(list(p.free.values())), std, info={"converged": False})
    name = p.free_names[2]
    assert np.isnan(res.std[2])
    row = next(line for line in res.summary().splitlines() if line.startswith(name))
    assert "not determined" in row and " 0 " not in row
    assert f"not determined: {name}: variance not positive" in res.summary()
    res.save(tmp_path)
    saved = json.loads((tmp_path / "result.json").read_text())
    assert saved["parameters"][name]["std"] is None
    assert "variance not positive" in saved["info"]["not_determined"][name]


def test_exactly_redundant_parameters_are_named_with_the_combination_that_is_determined(tmp_path):
    p, run = _short_run(0.0)  # de2 = de: only M_de + M_de2 is determined
    res = ML(p, max_iter=30).fit(run).result_
    text = res.summary()
    assert "REDUNDANT (exactly): M_de, M_de2" in text
    (r,) = res.identifiability()["redundant"]
    assert r["exact"] and r["determined"] == "M_de + 1 M_de2"
    assert abs(r["value"] - (-12.0)) < 3 * r["std"] + 0.05  # the sum is determined, and right
    assert np.isnan(res.std[p.free_names.index("M_de")]) and np.isnan(res.std[p.free_names.index("M_de2")])
    res.save(tmp_path)
    saved = json.loads((tmp_path / "result.json").read_text())
    assert saved["parameters"]["M_de"]["std"] is None
    assert saved["identifiability"]["redundant"][0]["determined"] == "M_de + 1 M_de2"


def test_nearly_redundant_parameters_are_named_too():
    p, run = _short_run(1e-5)  # de2 differs from de by a trace: |rho| >= 0.999
    res = ML(p, max_iter=30).fit(run).result_
    (r,) = res.identifiability()["redundant"]
    assert not r["exact"] and abs(r["rho"]) >= 0.999 and set(r["parameters"]) == {"M_de", "M_de2"}
    assert np.isfinite(res.std).all()  # nearly redundant: the (huge) standard errors stand
    assert "REDUNDANT: M_de, M_de2" in res.summary() and "determined: M_de + " in res.summary()


def test_a_declared_output_bias_duplicating_the_zero_shift_is_said():
    text = LONGITUDINAL.replace("[fixed]", "b_q = 0.01\n[ties]\nb_q = { \"q:one\" = 1.0 }\n[fixed]")
    text = text.replace('inputs = { de = "rad" }', 'inputs = { de = "rad", one = "1" }')
    text += "\n[meta.pseudo_inputs]\none = { constant = 1.0 }\n"
    p = parse_profile(text)
    truth = LinearModel(parse_profile(LONGITUDINAL))
    t = np.arange(0, 15.0, 0.05)
    run = simulate_run(truth, t, steps_3211(t, 0.5, width=1.0, amp=0.02)[:, None], noise=NOISE, seed=3,
                       bias={"q": 0.004})
    res = ML(p, max_iter=30).fit(run).result_
    i = p.free_names.index("b_q")
    assert np.isnan(res.std[i])
    assert "b_q: a declared output bias on 'q' duplicating the zero shift" in res.summary()


def test_a_declared_output_bias_without_zero_shifts_keeps_its_bound_under_fem():
    """FEM lists every zero shift, held ones (std inf) too: without zero shifts the declared bias
    duplicates nothing and keeps its bound (it was NaN with a false 'duplicating' reason)."""
    from identify.estimators.filter_error import FEM

    text = LONGITUDINAL.replace("[fixed]", "b_q = 0.01\n[ties]\nb_q = { \"q:one\" = 1.0 }\n[fixed]")
    text = text.replace('inputs = { de = "rad" }', 'inputs = { de = "rad", one = "1" }')
    text += "\n[meta.pseudo_inputs]\none = { constant = 1.0 }\n"
    p = parse_profile(text)
    t = np.arange(0, 15.0, 0.05)
    run = simulate_run(LinearModel(parse_profile(LONGITUDINAL)), t, steps_3211(t, 0.5, width=1.0, amp=0.02)[:, None],
                       noise=NOISE, seed=3, bias={"q": 0.004})
    res = FEM(p, process_noise={}, estimate_bias=False, max_iter=30).fit(run).result_
    i = p.free_names.index("b_q")
    assert all(np.isinf(s) for run_std in res.info["zero_shift_std"] for s in run_std.values())
    assert np.isfinite(res.std[i]) and res.std[i] > 0
    assert "b_q" not in res.info.get("not_determined", {})
    assert abs(res.theta[i] - 0.004) < 4 * res.std[i]


def test_ml_initial_state_and_zero_shift_stds_are_nan_where_the_variance_is_not_positive():
    """Every standard error ML reports (parameters, initial states, zero shifts) is NaN, never 0,
    where its variance is not positive; held entries stay inf."""
    from identify.estimators import ml

    class Cov:
        def diag(self):
            return np.array([4.0, 0.0, -1e-9, 1.0])

    std = ml._std(Cov(), np.array([True, True, True, False]))
    assert std[0] == 2.0 and np.isnan(std[1]) and np.isnan(std[2]) and std[3] == np.inf
