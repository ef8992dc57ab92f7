import dataclasses

import control
import numpy as np
import pytest

from identify import (LinearModel, SimulationError, discretize, load_profile, output_sensitivities, simulate,
                      simulate_run)


def _inputs(n, m, dt, rng):
    """Piecewise-constant inputs with random steps (a held, flown-like signal)."""
    u = np.repeat(rng.uniform(-0.02, 0.02, size=(n // 20 + 1, m)), 20, axis=0)[:n]
    u[:50] = 0.0
    return u


def test_zoh_simulation_matches_python_control(s61, rng):
    dt, n = 0.01, 2001
    t = np.arange(n) * dt
    u = _inputs(n, s61.n_inputs, dt, rng)
    x0 = rng.normal(0, 0.01, s61.n_states)
    ours = simulate(s61, u, dt, x0)
    sysd = control.c2d(s61.to_ss(), dt, method="zoh")
    ref = control.forced_response(sysd, T=t, U=u.T, X0=x0, return_x=True)
    scale = np.abs(ref.outputs).max()
    np.testing.assert_allclose(ours.y, ref.outputs.T, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(ours.x, ref.states.T, rtol=0, atol=1e-9 * np.abs(ref.states).max())


def test_free_response_matches_continuous_solution(s61, rng):
    """With no input both are the exact exponential solution, continuous time included."""
    dt, n = 0.02, 1001
    t = np.arange(n) * dt
    x0 = rng.normal(0, 0.01, s61.n_states)
    ours = simulate(s61, np.zeros((n, s61.n_inputs)), dt, x0)
    ref = control.forced_response(s61.to_ss(), T=t, U=np.zeros((s61.n_inputs, n)), X0=x0)
    np.testing.assert_allclose(ours.y, ref.outputs.T, rtol=0, atol=1e-9 * np.abs(ref.outputs).max())


def test_diverging_unstable_model_raises_clear_error(s61):
    p = s61.profile
    fast = LinearModel(p, s61.theta * np.where(np.array(p.free_names) == "theta_R_u", 40.0, 1.0))
    with pytest.raises(SimulationError) as err:
        simulate(fast, np.full((20001, 2), 0.05), 0.01)
    msg = str(err.value)
    assert "diverged" in msg and "state '" in msg and "t = " in msg and "\n" not in msg


def test_sensitivities_match_finite_differences(s61, rng):
    dt, n = 0.02, 501
    u = _inputs(n, s61.n_inputs, dt, rng)
    x0 = rng.normal(0, 0.005, s61.n_states)
    sens = output_sensitivities(s61, u, dt, x0, initial_state=True)
    h = 1e-6
    for i in range(len(s61.names)):
        step = np.zeros_like(s61.theta)
        step[i] = h * max(1.0, abs(s61.theta[i]))
        yp = simulate(s61.with_theta(s61.theta + step), u, dt, x0).y
        ym = simulate(s61.with_theta(s61.theta - step), u, dt, x0).y
        fd = (yp - ym) / (2 * step[i])
        np.testing.assert_allclose(sens.dy[:, :, i], fd, atol=1e-6 * max(1.0, np.abs(fd).max()),
                                   err_msg=s61.names[i])
    for j in range(s61.n_states):
        e = np.zeros(s61.n_states)
        e[j] = 1e-4
        fd = (simulate(s61, u, dt, x0 + e).y - simulate(s61, u, dt, x0 - e).y) / 2e-4
        np.testing.assert_allclose(sens.dy_x0[:, :, j], fd, atol=1e-7 * max(1.0, np.abs(fd).max()))
    np.testing.assert_allclose(sens.y, simulate(s61, u, dt, x0).y)


def test_derivative_outputs_have_sensitivities_through_C_and_D(rng):
    p = dataclasses.replace(load_profile("s61_hover_4dof"), limits={})  # its limits name the outputs dropped
    text = p.to_toml().replace('outputs = ["u", "v", "p", "q", "theta", "phi"]',
                               'outputs = ["q", "q_dot", "a_x"]\n[output_defs]\na_x = { u_dot = 1.0, theta = 9.81 }')
    from identify import parse_profile
    m = LinearModel(parse_profile(text))
    u = _inputs(301, 2, 0.02, rng)
    sens = output_sensitivities(m, u, 0.02)
    i = m.names.index("M_theta_s")
    h = 1e-6
    fd = (simulate(m.with_theta(m.theta + h * np.eye(len(m.theta))[i]), u, 0.02).y
          - simulate(m.with_theta(m.theta - h * np.eye(len(m.theta))[i]), u, 0.02).y) / (2 * h)
    np.testing.assert_allclose(sens.dy[:, :, i], fd, atol=1e-6)
    assert np.abs(sens.dy[:, 1, i]).max() > 0.01  # q_dot feels M_theta_s directly through D


def test_simulated_run_noise_bias_and_channels(s61):
    dt, n = 0.01, 2001
    t = np.arange(n) * dt
    u = np.zeros((n, 2))
    u[100:300, 0] = 0.01
    clean = simulate_run(s61, t, u, seed=3)
    noisy = simulate_run(s61, t, u, seed=3, noise={"q": 0.002}, bias={"p": 0.01})
    assert {"theta_s", "theta_c", "q", "q_dot", "theta_R_dot"} <= set(clean.channels)
    np.testing.assert_array_equal(clean["theta_s"], noisy["theta_s"])
    assert np.std(noisy["q"] - clean["q"]) == pytest.approx(0.002, rel=0.1)
    assert np.mean(noisy["p"] - clean["p"]) == pytest.approx(0.01, rel=1e-9)
    gust = simulate_run(s61, t, u, seed=3, process_noise=0.05)
    assert not np.allclose(gust["q"], clean["q"])
    # the recorded derivatives include the disturbance, white with the asked standard deviation
    x = np.column_stack([gust[s] for s in s61.profile.state_names])
    xdot = np.column_stack([gust[s + "_dot"] for s in s61.profile.state_names])
    w = xdot - x @ s61.A.T - u @ s61.B.T
    np.testing.assert_allclose(w.std(axis=0), 0.05, rtol=0.1)
    assert abs(np.corrcoef(w[:-1, 2], w[1:, 2])[0, 1]) < 0.1


def test_discretize_is_exact_for_a_scalar():
    Phi, Gamma = discretize(np.array([[-2.0]]), np.array([[3.0]]), 0.1)
    assert Phi[0, 0] == pytest.approx(np.exp(-0.2), rel=1e-14)
    assert Gamma[0, 0] == pytest.approx(1.5 * (1 - np.exp(-0.2)), rel=1e-13)


def test_simulated_run_without_derivative_sensors(s61):
    t = np.arange(201) * 0.02
    run = simulate_run(s61, t, np.zeros((201, 2)), derivatives=False)
    assert "q" in run.channels and not any(c.endswith("_dot") for c in run.channels)


def test_input_delay_and_perturbed_truth(s61):
    """A truth with a control-system delay: the run records the stick as given, the aircraft
    responds to it later (zero before the record); a whole-sample delay is an exact shift, any other
    interpolates."""
    from identify import delay_inputs, perturbed_model
    t = np.arange(801) * 0.02
    u = np.column_stack([np.where((t > 1) & (t < 2), 0.01, 0.0), 0.005 * np.sin(2 * t)])
    delayed = delay_inputs(t, u, 0.1, before=0.0)
    np.testing.assert_array_equal(delayed, np.vstack([np.zeros((5, 2)), u[:-5]]))
    np.testing.assert_allclose(delay_inputs(t, u[:, 1], 0.013), np.interp(t - 0.013, t, u[:, 1], left=u[0, 1]))
    run = simulate_run(s61, t, u, input_delay=0.1, seed=3, noise_fraction=0.01)
    ref = simulate_run(s61, t, delayed, seed=3, noise_fraction=0.01)
    np.testing.assert_array_equal(run.matrix(s61.profile.input_names), u)
    for y in s61.profile.outputs:
        np.testing.assert_array_equal(run[y], ref[y])
    assert "input_delay" in run.meta
    with pytest.raises(SimulationError, match="no input"):
        simulate_run(s61, t, u, input_delay={"pedal": 0.1})
    truth = perturbed_model(s61, 0.15, np.random.default_rng(1))
    ratio = truth.theta / s61.theta
    assert np.all((ratio >= 0.85) & (ratio <= 1.15)) and np.ptp(ratio) > 0.1
