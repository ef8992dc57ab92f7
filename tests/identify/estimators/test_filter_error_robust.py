"""Filter error that says what it did: the process-noise model in one line, a refusal instead of
silent output error, a degenerate fit said (not printed as precision), the innovations' whiteness
and the bounds it chooses, a failed start or restart reported and the best fit kept (never a
traceback)."""
import math
import warnings

import numpy as np
import pytest

from identify import LinearModel, Run, discretize, parse_profile
from identify.errors import EstimationError
from identify.estimators.filter_error import FEM, FilterProblem
from tests.identify.estimators.test_filter_error import LATERAL, _pulses

# HFB-320-like longitudinal motion (alpha, q, V, theta), process noise on alpha and q as real
# flight data were declared (a restart there once raised LinAlgError from the information matrix)
HFB = """
name = "HFB-320-like longitudinal (alpha, q, V, theta)"
states = { alpha = "rad", q = "rad/s", V = "m/s", theta = "rad" }
inputs = { delta_e = "rad" }
outputs = ["alpha", "q", "V", "theta"]
[free]
alpha_alpha = -1.25
alpha_V = -0.0022
alpha_delta_e = -0.11
M_alpha = -7.8
M_q = -1.9
M_V = 0.0012
M_delta_e = -9.5
V_alpha = 4.6
V_V = -0.021
[fixed]
alpha_q = 1.0
V_theta = -9.81
theta_q = 1.0
[process_noise]
alpha = 0.01
q = 0.05
"""


def _ar1(rng, n, dt, tau, sigma, width=1):
    a = math.exp(-dt / tau)
    out, e = np.zeros((n, width)), rng.standard_normal((n, width)) * sigma * math.sqrt(1 - a * a)
    for k in range(1, n):
        out[k] = a * out[k - 1] + e[k]
    return out


def _hfb_run(seed: int) -> Run:
    """60 s at 10 Hz, elevator pulses; a first-order gust on alpha (1 s) entering through the
    derivatives (a relative wind: a model FEM's white noise does not share); white sensor noise."""
    p = parse_profile(HFB)
    m = LinearModel(p)
    rng = np.random.default_rng(seed)
    dt, t = 0.1, np.arange(0, 60, 0.1)
    u = np.zeros_like(t)
    for a, b, v in [(1, 2, 0.03), (2, 3, -0.03), (3, 4, 0.03), (10, 11, -0.02), (11, 12, 0.02)]:
        u[(t >= a) & (t < b)] = v
    gust = _ar1(rng, len(t), dt, 1.0, 0.01)[:, 0]
    Phi, Gam = discretize(m.A, np.column_stack([m.B, -m.A[:, 0]]), dt)
    x, X = np.zeros(4), np.zeros((len(t), 4))
    for k in range(len(t)):
        X[k] = x
        x = Phi @ x + Gam @ np.array([u[k], gust[k]])
    Y = X + np.array([0.002, 0.002, 0.1, 0.001]) * rng.standard_normal(X.shape)
    return Run(t, {"delta_e": u, **dict(zip(p.outputs, Y.T))}, source=f"<hfb {seed}>")


def _textbook_run(seed: int) -> Run:
    """The textbook layout (states p, r; outputs p_dot, r_dot, a_y, p, r; 321 samples at 0.05 s):
    turbulence as a coloured forcing of the roll and yaw equations (0.7 s), in the measured
    derivatives too, and little sensor noise: the filter can follow the measured states exactly."""
    p = parse_profile(LATERAL)
    m = LinearModel(p)
    rng = np.random.default_rng(seed)
    dt, n = 0.05, 321
    t = np.arange(n) * dt
    v = _ar1(rng, n, dt, 1.0, 1.5)[:, 0]
    u = np.column_stack([_pulses(t, (1.0, (1.2, 0.8, 0.4, 0.4), 0.05)), _pulses(t, (8.0, (1.0, 1.0), 0.05)), v])
    w = _ar1(rng, n, dt, 0.7, 1.0, 2) * np.array([0.6, 0.25])
    Phi, Gam = discretize(m.A, np.hstack([m.B, np.eye(2)]), dt)
    x, Y = np.zeros(2), np.zeros((n, 5))
    for k in range(n):
        Y[k] = m.C @ x + m.D @ u[k]
        Y[k, :2] = m.A @ x + m.B @ u[k] + w[k]  # the measured derivatives: the turbulence's forcing in them
        x = Phi @ x + Gam @ np.r_[u[k], w[k]]
    Y += np.array([0.01, 0.005, 0.02, 0.001, 0.001]) * rng.standard_normal(Y.shape)
    return Run(t, {**dict(zip(p.input_names, u.T)), **dict(zip(p.outputs, Y.T))}, source=f"<textbook {seed}>")


def test_without_process_noise_nor_velocity_state_fem_refuses_in_one_line():
    p = parse_profile(LATERAL.split("[process_noise]")[0] + "[initial_state]" + LATERAL.split("[initial_state]")[1])
    with pytest.raises(EstimationError) as exc:
        FEM(p).fit([_textbook_run(0)])
    text = str(exc.value)
    assert "\n" not in text and "[process_noise]" in text and "--turbulence" in text
    # output error on purpose is still there, and said
    r = FEM(p, process_noise={}).fit([_textbook_run(0)]).result_
    assert r.info["process_noise_model"] == "process noise: none (output error)"


def test_fem_says_which_process_noise_model_it_fitted_and_plots_both_kinds_of_modelled(tmp_path):
    r = FEM(parse_profile(HFB)).fit([_hfb_run(0)]).result_
    line = r.info["process_noise_model"]
    assert line.startswith("process noise: white, on the equations of alpha") and "[process_noise]" in line
    assert sum(line in s for s in r.summary().splitlines()) == 1
    # the one-step predictions follow the data closer than the open-loop simulation (nothing fed back)
    sim, pred, z = r.simulated[0], r.modelled[0], r.measured[0]
    assert sim.shape == pred.shape and np.mean((z - sim) ** 2) > np.mean((z - pred) ** 2)
    from identify.estimators.plots import plot_time_histories
    assert plot_time_histories(r, tmp_path / "th.png").stat().st_size > 0
    r.save(tmp_path / "out")
    from identify.estimators.result import IdentificationResult
    back = IdentificationResult.from_json(tmp_path / "out" / "result.json")
    np.testing.assert_array_equal(back.simulated[0], sim)
    assert back.info["whiteness"]["outputs"].keys() == r.info["whiteness"]["outputs"].keys()


def test_a_failed_restart_is_reported_and_the_best_converged_fit_kept(monkeypatch):
    # the restart's first information matrix cannot be formed (as on real HFB-320 data: "Matrix is
    # not positive definite"): the fit keeps the converged starts, says the restart failed
    p, run = parse_profile(HFB), _hfb_run(0)
    real, calls = FilterProblem.information, {"n": 0}

    def failing_in_restart(self, ev):
        import inspect
        if any(f.frame.f_locals.get("name") == "restart" for f in inspect.stack()[1:8]):
            raise np.linalg.LinAlgError("Matrix is not positive definite")
        calls["n"] += 1
        return real(self, ev)

    monkeypatch.setattr(FilterProblem, "information", failing_in_restart)
    r = FEM(p).fit([run]).result_
    starts = r.info["r_start"]
    assert starts is not None and "restart" in starts["failed"], starts  # the case takes the restart path
    assert "not positive definite" in starts["failed"]["restart"] and "restart failed" in r.info["r_start_choice"]
    assert r.converged and starts["kept"] in ("gain_held", "wide_f") and np.all(np.isfinite(r.std))


def test_an_information_matrix_that_cannot_be_formed_gives_nan_bounds_with_the_reason(monkeypatch):
    from identify.estimators.filter_error import estimator
    p, run = parse_profile(HFB), _hfb_run(1)

    def broken(prob, ev, *args):
        from identify.estimators.filter_error.bounds import fit_bounds
        return fit_bounds(prob, None, *args)  # as if the sensitivities failed

    monkeypatch.setattr(estimator, "fit_bounds", broken)
    r = FEM(p).fit([run]).result_
    assert np.all(np.isnan(r.std)) and all("no bound" in r.info["not_determined"][n] for n in r.names)
    assert sum("not determined: " in s for s in r.summary().splitlines()) <= 2  # grouped, not one line each


def test_the_textbook_style_degenerate_fit_is_said_not_printed_as_precision():
    # R of p and r on their floor (the filter copies both states): the derivatives' Cramér-Rao bounds
    # were 5-13 times too narrow on this case (measured on seeds 0-2)
    r = FEM(parse_profile(LATERAL)).fit([_textbook_run(0)]).result_
    why = r.info["degenerate"]
    assert why and "copies every state" in why, r.info["measurement_noise"]
    assert np.all(np.isnan(r.std)) and all("not meaningful" in r.info["not_determined"][n] for n in r.names)
    assert sum("degenerate fit" in s for s in r.summary().splitlines()) == 2  # the warning and the grouped line
    assert "poorly determined" not in r.summary()  # not the inputs' fault: no advice to fly other inputs


def test_whiteness_of_the_innovations_is_recorded_and_chooses_the_bounds():
    p = parse_profile(HFB)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = FEM(p).fit([_hfb_run(2)]).result_
    white = r.info["whiteness"]
    assert set(white["outputs"]) == set(p.outputs) and all("Q" in v and "p_value" in v for v in white["outputs"].values())
    if white["coloured"]:  # default: the coloured-innovation bounds, said
        assert r.info["std_coloured"] is not None and "coloured on" in r.info["bounds_choice"]
    else:
        assert r.info["std_coloured"] is None and "white on every output" in r.info["bounds_choice"]
    forced = FEM(p, coloured=False).fit([_hfb_run(2)]).result_
    assert forced.info["std_coloured"] is None and forced.info["whiteness"] == white


def test_the_textbook_formulation_is_not_degenerate_on_the_same_data():
    # R as the innovation covariance (relaxed) with C K <= 1, the gain from the continuous Riccati
    # equation in S (Jategaonkar's formulation): no R floor, the filter never copies the data unsaid
    from identify.estimators.registry import build
    p, run = parse_profile(LATERAL), _textbook_run(1)
    default = FEM(p).fit([run]).result_
    r = build("fem", p, formulation="innovation").fit([run]).result_
    assert default.info["degenerate"] and r.info["degenerate"] is None and r.info["formulation"] == "innovation"
    assert r.converged and np.all(r.info["diag_CK"] <= 1 + 1e-9) and np.all(np.isfinite(r.std) & (r.std > 0))
    implied = [v["variance"] for v in r.info["measurement_noise"].values()]
    assert np.all(np.array(implied) >= -1e-12) and "implied" in r.info["not_determined"]["R of p"]
    # its bounds measure something: wider than the degenerate fit's Cramér-Rao ones (median 2.2x measured)
    assert np.median(r.std / np.asarray(default.info["std_white"])) > 1.5
    with pytest.raises(EstimationError, match="formulation must be one of"):
        FEM(p, formulation="textbook").fit([run])
