"""Output-error maximum likelihood (identify.estimators.ml.ML) on data simulated from a known truth."""
import math

import numpy as np
import pytest

from identify import (EstimationError, LinearModel, RunError, parse_profile,
                      simulate, simulate_run)
from identify import ML
from identify.estimators.output_error import OutputError, auto_segment


def steps_3211(t, t0, width=0.7, amp=0.03):
    """A 3211 (widths 3-2-1-1, alternating sign) starting at t0 s."""
    u, a = np.zeros_like(t), t0
    for k, sign in zip((3, 2, 1, 1), (1, -1, 1, -1)):
        u[(t >= a) & (t < a + k * width)] = sign * amp
        a += k * width
    return u


def grid(T, dt):
    return np.arange(int(round(T / dt)) + 1) * dt


def two_axis_inputs(t, t_lat):
    u = np.zeros((len(t), 2))
    u[:, 0] = steps_3211(t, 0.5)
    u[:, 1] = steps_3211(t, t_lat)
    return u


def perturbed(profile, factor):
    """The profile with every free value multiplied by ``factor`` (array or scalar)."""
    theta = np.array(list(profile.free.values())) * factor
    return profile.with_values(dict(zip(profile.free_names, theta)))


def alternating(p, size):
    return 1 + size * np.where(np.arange(p) % 2, 1.0, -1.0)


def noise_5pc(model, t, u):
    clean = simulate_run(model, t, u)
    return {y: 0.05 * float(np.std(clean[y])) for y in model.profile.outputs}


# -- the Jacobian behind the normal equations -------------------------------------------------------
def test_normal_equations_match_finite_difference_jacobian(s61, rng):
    dt = 0.1
    t = grid(8, dt)
    runs = [simulate_run(s61, t, two_axis_inputs(t, 3.0), noise_fraction=0.05, seed=1),
            simulate_run(s61, t[:61], two_axis_inputs(t[:61], 1.0), noise_fraction=0.05, seed=2)]
    p = s61.profile
    prob = OutputError(p, [r.matrix(p.input_names) for r in runs], [r.matrix(list(p.outputs)) for r in runs],
                       dt, segment=3.0)
    assert prob.layout.n_segments == 3 + 2
    beta = prob.initial_beta(s61.theta * 1.1) + rng.normal(0, 1e-3, prob.n_beta)
    Wh = np.diag(rng.uniform(0.5, 2.0, p.outputs.__len__()))
    M, g = prob.normal_equations(prob.evaluate(beta), Wh)
    J = np.empty((len(prob.residual_vector(beta, Wh)), prob.n_beta))
    for i in range(prob.n_beta):
        h = 1e-6 * max(1.0, abs(beta[i]))
        step = np.zeros(prob.n_beta)
        step[i] = h
        J[:, i] = -(prob.residual_vector(beta + step, Wh) - prob.residual_vector(beta - step, Wh)) / (2 * h)
    scale = np.sqrt(np.outer(np.diag(J.T @ J), np.diag(J.T @ J)))
    np.testing.assert_allclose(M / scale, (J.T @ J) / scale, atol=1e-6)
    np.testing.assert_allclose(g, J.T @ prob.residual_vector(beta, Wh), rtol=1e-5,
                               atol=1e-6 * np.abs(g).max())


# -- matched structure, noise-free: six significant digits -----------------------------------------
def test_noise_free_s61_8state_recovers_every_parameter_to_six_digits(s61):
    dt = 0.04
    t = grid(20, dt)
    x0 = np.array([0.001, -0.002, 0.3, -0.2, 0.01, -0.005, 0.02, 0.01])
    bias = {"u": 0.05, "q": 0.001, "phi": -0.003}
    run = simulate_run(s61, t, two_axis_inputs(t, 8.0), x0=x0, bias=bias)
    iters = []
    ml = ML(perturbed(s61.profile, alternating(len(s61.theta), 0.2)),
            progress=lambda k, cost, theta: iters.append(k)).fit(run)
    res = ml.result_
    rel = np.abs(res.theta / s61.theta - 1)
    assert rel.max() <= 5e-7, dict(zip(res.names, rel))
    assert res.info["converged"] and res.info["form"] == "multiple shooting"
    assert iters == list(range(1, res.info["iterations"] + 1))
    for y in s61.profile.outputs:
        assert res.info["zero_shifts"][0][y] == pytest.approx(bias.get(y, 0.0), abs=1e-9)
    np.testing.assert_allclose(list(res.info["initial_states"][0].values()), x0, atol=1e-9)
    # the modelled outputs reproduce the measured ones (noise-free)
    assert max(v["rms"] for v in res.fit.values()) < 1e-9


# -- noisy data: Monte Carlo spread against the Cramer-Rao bounds ------------------------------------
def test_monte_carlo_spread_matches_cramer_rao_and_is_unbiased(s61):
    """S 61 8-state model (unstable, so multiple shooting), one 10 s run at 20 Hz with a 3211 on
    each cyclic, 5 % noise on every output, 100 seeded noise realisations; initial states, zero
    shifts and the noise covariance (relaxation) are estimated in every fit."""
    n_mc, dt = 100, 0.05
    t = grid(10, dt)
    u = two_axis_inputs(t, 5.0)
    noise = noise_5pc(s61, t, u)
    start = perturbed(s61.profile, alternating(len(s61.theta), 0.1))
    est, std = [], []
    for k in range(n_mc):
        res = ML(start).fit(simulate_run(s61, t, u, noise=noise, seed=1000 + k)).result_
        assert res.info["converged"]
        est.append(res.theta)
        std.append(res.std)
    est, std = np.array(est), np.array(std)
    spread = est.std(axis=0, ddof=1)
    ratio = spread / std.mean(axis=0)
    assert np.all(np.abs(ratio - 1) <= 0.25), dict(zip(s61.names, ratio.round(3)))
    z = (est.mean(axis=0) - s61.theta) / (spread / np.sqrt(n_mc))
    assert np.all(np.abs(z) < 3), dict(zip(s61.names, z.round(2)))


# -- unstable model, 20 s runs, a priori values 30 % off --------------------------------------------
def test_unstable_s61_converges_from_30_percent_perturbed_apriori(s61):
    dt = 0.05
    t = grid(20, dt)
    u = two_axis_inputs(t, 8.0)
    run = simulate_run(s61, t, u, noise=noise_5pc(s61, t, u), bias={"u": 0.1, "q": 0.002}, seed=7)
    assert s61.unstable
    segment = auto_segment(s61, 20.0)
    reference = ML(s61.profile, segment=segment).fit(run).result_
    for seed in range(3):
        signs = np.random.default_rng(seed).choice([-1.0, 1.0], len(s61.theta))
        start = perturbed(s61.profile, 1 + 0.3 * signs)
        auto = ML(start).fit(run).result_  # segments chosen from the perturbed model's own modes
        assert auto.info["form"] == "multiple shooting" and auto.info["converged"]
        assert np.all(np.abs(auto.theta - s61.theta) < 4 * auto.std), seed
        same = ML(start, segment=segment).fit(run).result_
        assert same.info["converged"]
        # the same optimum as when started from the truth
        assert np.all(np.abs(same.theta - reference.theta) < 1e-3 * reference.std), seed


# -- multi-run -------------------------------------------------------------------------------------
def test_two_runs_give_lower_parameter_error_than_either_alone(s61):
    """Two 10 s runs, 3211 on longitudinal and on lateral cyclic. A run alone cannot move the
    derivatives of the other cyclic (no sensitivity: they stay at their a priori value, reported
    as not excited); the average relative error is over all 18 derivatives."""
    dt = 0.05
    t = grid(10, dt)
    u_lon, u_lat = np.zeros((len(t), 2)), np.zeros((len(t), 2))
    u_lon[:, 0], u_lat[:, 1] = steps_3211(t, 1.0), steps_3211(t, 1.0)
    noise = noise_5pc(s61, t, u_lon + u_lat)
    start = perturbed(s61.profile, alternating(len(s61.theta), 0.2))

    def error(runs):
        res = ML(start).fit(runs).result_
        assert res.info["converged"]
        return np.mean(np.abs(res.theta / s61.theta - 1)), res

    for k in range(3):
        lon = simulate_run(s61, t, u_lon, noise=noise, seed=10 + k)
        lat = simulate_run(s61, t, u_lat, noise=noise, seed=20 + k)
        e_lon, r_lon = error([lon])
        e_lat, _ = error([lat])
        e_both, r_both = error([lon, lat])
        assert e_both < min(e_lon, e_lat), (e_both, e_lon, e_lat)
        assert set(r_lon.info["not_excited"]) == {"theta_R_theta_c", "phi_R_theta_c"}
        assert np.all(np.isinf(r_lon.std[[r_lon.names.index(n) for n in r_lon.info["not_excited"]]]))
        assert r_both.info["not_excited"] == [] and len(r_both.info["zero_shifts"]) == 2


# -- generality: ties, output-equation parameters, pseudo-inputs, lag states -----------------------
GENERAL = """
name = "pitch/roll with a cyclic lag, a drift pseudo-input (time) and a rate-gyro scale factor"
states = { u = "m/s", v = "m/s", p = "rad/s", q = "rad/s", theta = "rad", phi = "rad", lag = "rad" }
inputs = { theta_s = "rad", theta_c = "rad", t = "s" }
outputs = ["u", "v", "p", "q", "theta", "phi"]
[ties]
k_lag = { lag_lag = -1.0, lag_theta_s = 1.0 }
k_q = { "q:q" = 1.0 }
[free]
X_u = -0.0442307
X_q = 0.981
Y_v = -0.0709015
Y_p = -0.981
L_v = -0.045675
L_p = -1.65
M_u = 0.009139
M_q = -0.47
X_theta_s = -9.81
Y_theta_c = 9.81
L_theta_c = 14.5
M_lag = 3.7
k_lag = 8.0
M_t = 0.0005
k_q = 0.05
[fixed]
X_theta = -9.81
Y_phi = 9.81
theta_q = 1.0
phi_p = 1.0
"""


def test_general_profile_with_ties_output_scale_pseudo_input_and_lag_state():
    truth = LinearModel(parse_profile(GENERAL))
    assert truth.unstable
    dt = 0.05
    t = grid(16, dt)
    # (a constant pseudo-input would be indistinguishable from zero shifts and initial states)
    u = np.column_stack([steps_3211(t, 0.5), steps_3211(t, 6.0), t])
    run = simulate_run(truth, t, u, x0=[0.2, -0.1, 0, 0, 0.01, 0, 0.005], bias={"p": 0.002})
    res = ML(perturbed(truth.profile, alternating(len(truth.theta), 0.15))).fit(run).result_
    rel = np.abs(res.theta / truth.theta - 1)
    assert rel.max() <= 5e-7, dict(zip(res.names, rel))
    assert res.info["zero_shifts"][0]["p"] == pytest.approx(0.002, abs=1e-9)


def test_stable_model_uses_plain_output_error():
    text = """
name = "short period"
states = { w = "m/s", q = "rad/s" }
inputs = { eta = "rad" }
outputs = ["w", "q", "a_z"]
[output_defs]
a_z = { w_dot = 1.0 }
[free]
Z_w = -0.8
Z_q = 50.0
M_w = -0.05
M_q = -1.5
Z_eta = -5.0
M_eta = -8.0
"""
    truth = LinearModel(parse_profile(text))
    assert not truth.unstable and math.isinf(auto_segment(truth, 60.0))
    t = grid(12, 0.02)
    u = steps_3211(t, 0.5, width=0.4)[:, None]
    run = simulate_run(truth, t, u, noise=noise_5pc(truth, t, u), seed=3)
    res = ML(perturbed(truth.profile, 1.2)).fit(run).result_
    assert res.info["form"] == "plain" and res.info["n_segments"] == 1 and res.info["converged"]
    assert np.all(np.abs(res.theta - truth.theta) < 4 * res.std)
    # relaxation estimates the measurement noise itself
    for y, s in noise_5pc(truth, t, u).items():
        assert res.info["noise_std"][y] == pytest.approx(s, rel=0.1)
    # without initial state and zero shifts the known (zero) start is used, and fits as well
    fixed = ML(perturbed(truth.profile, 1.2), estimate_x0=False, estimate_bias=False).fit(run).result_
    assert np.all(np.abs(fixed.theta - truth.theta) < 4 * fixed.std)
    assert fixed.info["zero_shift_std"] is None and fixed.info["zero_shifts"] == [{"w": 0.0, "q": 0.0, "a_z": 0.0}]
    assert fixed.info["initial_states"][0] == {"w": run["w"][0], "q": run["q"][0]}


# -- the result object -----------------------------------------------------------------------------
def test_result_has_table_fit_metrics_and_per_run_histories(s61):
    t = grid(10, 0.05)
    u = two_axis_inputs(t, 5.0)
    runs = [simulate_run(s61, t, u, noise=noise_5pc(s61, t, u), seed=s) for s in (1, 2)]
    ml = ML(s61.profile).fit(runs)
    res = ml.result_
    text = ml.summary()
    assert "std error" in text and "coloured-residual" in text and all(name in text for name in s61.names)
    assert set(res.fit) == set(s61.profile.outputs) and all(0 < v["theil"] < 0.2 for v in res.fit.values())
    assert len(res.time) == len(res.measured) == len(res.modelled) == 2
    assert res.modelled[1].shape == (len(t), len(s61.profile.outputs))
    np.testing.assert_array_equal(res.measured[0], runs[0].matrix(list(s61.profile.outputs)))
    nll = np.array(res.info["cost"])  # negative log-likelihood: relaxation and steps never raise it
    assert len(nll) == res.info["iterations"] + 1 and len(res.info["log_det_R"]) == len(nll)
    assert np.all(np.diff(nll) <= 1e-9 * np.abs(nll[:-1])) and nll[-1] < nll[0]
    assert res.info["segments"][0]["t_start"] == 0.0 and ml.covariance_.shape == (18, 18)
    np.testing.assert_allclose(np.sqrt(np.diag(ml.covariance_)), res.std)
    assert res.to_dict()["info"]["form"] == "multiple shooting"


# -- bad input: one clear error --------------------------------------------------------------------
def _one_line(exc):
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_diverging_apriori_model_in_plain_form_is_a_clear_error(s61):
    t = grid(40, 0.05)
    run = simulate_run(s61, t, two_axis_inputs(t, 8.0))
    fast = perturbed(s61.profile, np.where(np.array(s61.names) == "theta_R_u", 60.0, 1.0))
    with pytest.raises(EstimationError) as exc:
        ML(fast, segment="plain").fit(run)
    msg = _one_line(exc)
    assert "diverges" in msg and "output 'theta_R'" in msg and "t = " in msg and "segment" in msg
    # multiple shooting copes with the same a priori model
    assert ML(fast).fit(run).result_.info["form"] == "multiple shooting"


def test_bad_runs_and_options_are_clear_errors(s61):
    t = grid(4, 0.05)
    run = simulate_run(s61, t, two_axis_inputs(t, 1.0))
    bad = run.with_channels({"q": np.where(np.arange(len(t)) == 5, np.nan, run["q"])})
    with pytest.raises(EstimationError) as exc:
        ML(s61.profile).fit(bad)
    assert "'q'" in _one_line(exc) and "t = 0.25" in str(exc.value)
    other_rate = simulate_run(s61, grid(4, 0.1), two_axis_inputs(grid(4, 0.1), 1.0))
    with pytest.raises(EstimationError) as exc:
        ML(s61.profile).fit([run, other_rate])
    assert "sample intervals" in _one_line(exc)
    missing = run.with_channels({})
    del missing.channels["theta"]
    with pytest.raises(RunError) as exc:
        ML(s61.profile).fit(missing)
    assert "theta" in _one_line(exc)
    for options, needle in (({"segment": -1.0}, "segment"), ({"noise_cov": np.ones(3)}, "noise_cov"),
                            ({"noise_cov": "guess"}, "noise_cov"), ({"max_iter": 0}, "max_iter")):
        with pytest.raises(EstimationError) as exc:  # options are checked by fit, as in scikit-learn
            ML(s61.profile, **options).fit(run)
        assert needle in _one_line(exc)
    with pytest.raises(EstimationError) as exc:
        ML(s61.profile, segment=1.0, estimate_x0=False).fit(run)
    assert "estimate_x0" in _one_line(exc)


def test_model_error_simulation_consistency(s61):
    """The problem's simulation is the library's ZOH simulation (no separate integrator)."""
    t = grid(6, 0.05)
    u = two_axis_inputs(t, 2.0)
    x0 = np.linspace(-0.01, 0.01, s61.n_states)
    run = simulate_run(s61, t, u, x0=x0)
    p = s61.profile
    prob = OutputError(p, [u], [run.matrix(list(p.outputs))], 0.05, segment=math.inf)
    beta = np.concatenate([s61.theta, x0, np.zeros(len(p.outputs))])
    ev = prob.evaluate(beta, jacobian=False)
    np.testing.assert_allclose(prob.per_run(ev.y)[0], simulate(s61, u, 0.05, x0).y, atol=1e-13)


# -- coloured residuals: Morelli & Klein's correction -----------------------------------------------
def _mc_fits(model, t, u, noise, seeds, tau=None):
    """ML fits of runs with measurement noise of std ``noise`` per output: white, or white passed
    through a first-order low-pass of time constant ``tau`` samples (rescaled to the same std)."""
    from scipy.signal import lfilter

    p = model.profile
    clean = simulate_run(model, t, u)
    start = perturbed(p, alternating(len(model.theta), 0.1))
    est, col, white = [], [], []
    for seed in seeds:
        w = np.random.default_rng(seed).normal(size=(len(t) + 100, len(p.outputs)))
        if tau is not None:
            a = math.exp(-1 / tau)
            w = lfilter([1 - a], [1, -a], w, axis=0)
            w /= math.sqrt((1 - a) / (1 + a))  # unit variance
        w = w[100:]
        channels = dict(clean.channels)
        for j, y in enumerate(p.outputs):
            channels[y] = channels[y] + noise[y] * w[:, j]
        res = ML(start).fit(type(clean)(clean.time, channels, source=f"seed {seed}")).result_
        assert res.info["converged"]
        est.append(res.theta)
        col.append(res.info["std_coloured"])
        white.append(res.info["std_white"])
        assert np.array_equal(res.std, res.info["std_coloured"])  # the default
    return np.array(est), np.array(col), np.array(white)


def test_coloured_correction_agrees_with_cramer_rao_on_white_noise(s61):
    """White noise: the corrected bounds equal M^-1's (measured: mean ratio 0.99, every parameter
    within 6 %; 30 fits of the S 61 8-state model, 10 s at 20 Hz, 3 shooting segments)."""
    t = grid(10, 0.05)
    u = two_axis_inputs(t, 5.0)
    _, col, white = _mc_fits(s61, t, u, noise_5pc(s61, t, u), range(3000, 3030))
    ratio = col.mean(axis=0) / white.mean(axis=0)
    print("white noise: coloured / white bound", dict(zip(s61.names, ratio.round(3))))
    assert np.all(np.abs(ratio - 1) <= 0.15), dict(zip(s61.names, ratio.round(3)))
    # fit by fit the corrected bound scatters a little about the white one
    assert np.median(np.abs(col / white - 1)) <= 0.1


def test_coloured_correction_matches_scatter_on_low_pass_noise():
    """Measurement noise low-passed (first order, time constant 4 samples = 0.2 s), 5 % of each
    output's std; S 61 4-DOF model, one 10 s run at 20 Hz (3 shooting segments), 30 seeds.
    Measured: observed scatter / mean bound is 2.69 (1.88..3.34 over the 20 derivatives) for the
    white Cramér-Rao bound, 1.08 (0.75..1.39) for the coloured-residual one (the per-parameter
    range is mostly the scatter of a 30-sample spread, about +-13 %)."""
    from identify import load_profile

    truth = LinearModel(load_profile("s61_hover_4dof"))
    t = grid(10, 0.05)
    u = two_axis_inputs(t, 5.0)
    est, col, white = _mc_fits(truth, t, u, noise_5pc(truth, t, u), range(2000, 2030), tau=4.0)
    spread = est.std(axis=0, ddof=1)
    r_col, r_white = spread / col.mean(axis=0), spread / white.mean(axis=0)
    print(f"low-pass noise: scatter / bound, coloured {r_col.mean():.3f} ({r_col.min():.2f}..{r_col.max():.2f}), "
          f"white {r_white.mean():.3f} ({r_white.min():.2f}..{r_white.max():.2f})")
    assert abs(r_col.mean() - 1) <= 0.3 and np.all((r_col > 0.6) & (r_col < 1.6)), dict(zip(truth.names, r_col.round(2)))
    assert r_white.mean() > 2 and np.all(r_white > 1.5), dict(zip(truth.names, r_white.round(2)))


def test_coloured_option_false_reports_cramer_rao_bounds(s61):
    t = grid(10, 0.05)
    u = two_axis_inputs(t, 5.0)
    run = simulate_run(s61, t, u, noise=noise_5pc(s61, t, u), seed=7)
    a = ML(s61.profile).fit(run).result_
    b = ML(s61.profile, coloured=False).fit(run).result_
    np.testing.assert_array_equal(a.theta, b.theta)  # the fit is the same
    np.testing.assert_array_equal(b.std, b.info["std_white"])
    np.testing.assert_array_equal(a.std, a.info["std_coloured"])
    np.testing.assert_allclose(a.info["std_white"], b.info["std_white"])
    assert b.info["std_coloured"] is None  # not computed
    assert b.info["standard_errors"].startswith("white") and a.info["noise_autocorrelation"].shape[1] == 8
