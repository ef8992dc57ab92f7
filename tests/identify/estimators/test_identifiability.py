"""Identifiability in the open: correlated and poorly determined parameters, modes whose stability
the runs do not determine (identify.estimators.identifiability, IdentificationResult.identifiability)."""
import json

import numpy as np

from identify import LinearModel, parse_profile, simulate_run
from identify.estimators.identifiability import correlation, mode_uncertainty
from tests.identify.estimators.test_ml import steps_3211
from identify import ML

LONGITUDINAL = """
name = "fixed-wing longitudinal"
states = { u = "m/s", w = "m/s", q = "rad/s", theta = "rad" }
inputs = { de = "rad" }
outputs = ["u", "w", "q", "theta"]
[free]
X_u = -0.04
X_w = 0.04
Z_u = -0.4
Z_w = -2.0
M_u = 0.002
M_w = -0.05
M_q = -2.0
Z_de = -10.0
M_de = -12.0
[fixed]
X_theta = -9.81
Z_q = 50.0
theta_q = 1.0
"""
NOISE = {"u": 0.2, "w": 0.2, "q": 0.003, "theta": 0.003}  # absolute: sensors and light turbulence


def fit(truth, duration, width, seed=1):
    t = np.arange(int(round(duration / 0.05)) + 1) * 0.05
    run = simulate_run(truth, t, steps_3211(t, 0.5, width=width, amp=0.02)[:, None], noise=NOISE, seed=seed)
    start = truth.profile.with_values(dict(zip(truth.names, truth.theta * 1.2)))
    return ML(start).fit(run).result_


def test_a_short_3211_leaves_the_phugoid_undetermined_and_says_so(tmp_path):
    truth = LinearModel(parse_profile(LONGITUDINAL))
    phugoid = min(truth.modes(), key=lambda m: m.frequency)
    assert phugoid.period > 30 and phugoid.stable
    short = fit(truth, 10.0, 0.3)  # a 2.1 s 3211: the short period only
    check = short.identifiability()
    slow = check["modes"][0]
    assert not slow["stability_determined"] and 0 in check["undetermined_modes"]
    assert abs(slow["real"]) < 2 * slow["std_real"]
    assert {"X_u", "M_u"} & set(slow["parameters"])
    assert check["modes"][1]["stability_determined"]  # the short period is well determined
    text = short.summary()
    assert "NOT IDENTIFIABLE" in text and "signaldesign band" in text and "signaldesign design" in text
    short.save(tmp_path)
    saved = json.loads((tmp_path / "result.json").read_text())
    assert saved["identifiability"]["undetermined_modes"] == [0]
    assert saved["eigenvalues"][0]["stability_determined"] is False
    # a long, slow 3211 that excites the phugoid pins it down: nothing is flagged about it
    long = fit(truth, 120.0, 8.0).identifiability()
    assert long["modes"][0]["stability_determined"] and long["undetermined_modes"] == []


def test_correlation_matrix_in_json_and_high_correlations_flagged(tmp_path):
    truth = LinearModel(parse_profile(LONGITUDINAL))
    res = fit(truth, 120.0, 8.0)
    rho = res.correlation
    assert np.allclose(rho, rho.T) and np.allclose(np.diag(rho), 1) and np.all(np.abs(rho) <= 1)
    pairs = res.identifiability()["correlated"]
    assert pairs and all(abs(q["rho"]) > 0.9 for q in pairs)
    i, j = res.names.index(pairs[0]["a"]), res.names.index(pairs[0]["b"])
    assert rho[i, j] == pairs[0]["rho"]
    assert f"{pairs[0]['a']} and {pairs[0]['b']}" in res.summary()
    res.save(tmp_path)
    saved = json.loads((tmp_path / "result.json").read_text())
    assert saved["correlation"]["names"] == res.names
    np.testing.assert_allclose(saved["correlation"]["matrix"], rho)


def test_eigenvalue_sensitivities_match_finite_differences(rng):
    truth = LinearModel(parse_profile(LONGITUDINAL))
    p = len(truth.theta)
    L = rng.normal(size=(p, p)) * 0.01 * np.abs(truth.theta)[:, None]
    cov = L @ L.T
    modes = mode_uncertainty(truth, cov)
    # the real part's variance from finite-difference gradients of the eigenvalues
    def eig_sorted(theta):
        lam = np.linalg.eigvals(truth.with_theta(theta).A)
        lam = lam[lam.imag >= 0]
        return lam[np.argsort(np.abs(lam))]
    grad = np.empty((len(modes), p))
    for i in range(p):
        h = 1e-6 * max(abs(truth.theta[i]), 1e-3)
        step = np.zeros(p)
        step[i] = h
        grad[:, i] = (eig_sorted(truth.theta + step).real - eig_sorted(truth.theta - step).real) / (2 * h)
    expected = np.sqrt(np.einsum("ki,ij,kj->k", grad, cov, grad))
    np.testing.assert_allclose([m["std_real"] for m in modes], expected, rtol=1e-4)


def test_correlation_of_unexcited_parameters_is_zero_not_nan():
    cov = np.array([[4.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    rho = correlation(cov)
    assert np.all(np.isfinite(rho)) and rho[0, 1] == 0.5 and rho[2, 2] == 1 and rho[0, 2] == 0
