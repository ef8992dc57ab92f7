"""LS and IV on data simulated from a known truth (the S 61 hover model unless said otherwise)."""
import numpy as np
import pytest

from identify import (IV, LS, EstimationError, LinearModel, Run, RunError, load_profile, parse_profile,
                      simulate_run)
from identify.estimators.equation_error import equation_groups
from identify.data.preprocess import lowpass

DT = 0.01


def steps(t, pattern, unit, start, amplitude):
    """A step sequence: ``pattern`` levels (e.g. 3211 as [1, 1, 1, -1, -1, 1, -1]) of ``unit`` s."""
    k = np.floor((t - start) / unit + 1e-9).astype(int)
    inside = (k >= 0) & (k < len(pattern))
    return amplitude * np.where(inside, np.asarray(pattern, float)[np.clip(k, 0, len(pattern) - 1)], 0.0)


P3211 = [1, 1, 1, -1, -1, 1, -1]


def inputs(t, lon=0.02, lat=0.02, lat_start=9.0):
    return np.column_stack([steps(t, P3211, 0.5, 1.0, lon), steps(t, P3211, 0.5, lat_start, lat)])


@pytest.fixture(scope="module")
def s61_run_20s(s61):
    t = np.arange(2001) * DT
    return simulate_run(s61, t, inputs(t), seed=0)


def relative_error(theta, truth):
    return np.abs(theta - truth) / np.abs(truth)


@pytest.mark.parametrize("method", [LS, IV])
def test_noise_free_20s_run_recovers_every_s61_parameter_to_six_digits(s61, s61_run_20s, method):
    """Done when: matched structure, exact state derivatives as channels, one 20 s run."""
    apriori = s61.profile.with_values({k: 1.3 * v for k, v in s61.profile.free.items()})
    options = {"start": "apriori"} if method is IV else {}
    est = method(apriori, **options).fit(s61_run_20s)
    err = relative_error(est.theta_, s61.theta)
    worst = int(np.argmax(err))
    print(f"{method.__name__}: worst relative error {err[worst]:.2e} ({s61.names[worst]})")
    assert len(est.theta_) == 18
    assert err.max() < 5e-7  # six significant digits or more
    res = est.result_
    assert all(src == f"channel {s}_dot" for s, src in res.info["derivatives"][0].items())
    assert max(v["theil"] for v in res.fit.values()) < 1e-6  # the identified model reproduces the run
    assert len(res.time) == 1 and res.measured[0].shape == res.modelled[0].shape == (2001, 8)


def test_derivatives_from_an_output_definition_and_from_smoothed_differentiation(s61):
    """a_x = u_dot + g theta gives u_dot exactly; states with no derivative get differentiated."""
    text = s61.profile.to_toml().replace(
        'outputs = ["theta_R", "phi_R", "u", "v", "p", "q", "theta", "phi"]',
        'outputs = ["theta_R", "phi_R", "u", "v", "p", "q", "theta", "phi", "a_x"]\n'
        '[output_defs]\na_x = { u_dot = 1.0, theta = 9.81 }')
    profile = parse_profile(text)
    truth = LinearModel(profile)
    t = np.arange(2001) * DT
    run = simulate_run(truth, t, inputs(t), seed=0)
    run = Run(run.time, {k: v for k, v in run.channels.items() if k not in ("u_dot", "q_dot")}, run.meta)
    est = LS(profile).fit(run)
    sources = est.result_.info["derivatives"][0]
    assert sources["u"] == "output a_x"
    assert sources["q"].startswith("smoothed differentiation of q")
    err = relative_error(est.theta_, truth.theta)
    x_eq = [i for i, n in enumerate(truth.names) if n.startswith("X_")]
    m_eq = [i for i, n in enumerate(truth.names) if n.startswith("M_")]
    assert err[x_eq].max() < 1e-9  # exact derivative from a_x
    assert err[m_eq].max() < 0.02  # smoothed differentiation: small error only


def test_ties_across_equations_are_solved_jointly():
    profile = parse_profile("""
name = "tied"
states = { u = "m/s", q = "rad/s", theta = "rad" }
inputs = { theta_s = "rad" }
outputs = ["u", "q", "theta"]
[free]
X_u = -0.05
M_q = -1.2
k = 2.0
[fixed]
X_theta = -9.81
theta_q = 1.0
[ties]
k = { X_theta_s = 1.0, M_theta_s = 0.5, M_u = 0.01 }
""")
    truth = LinearModel(profile)
    groups = equation_groups(truth)
    assert [g.equations for g in groups] == [[0, 1]]  # X and M joined by k; theta has no free parameter
    t = np.arange(1001) * DT
    run = simulate_run(truth, t, steps(t, P3211, 0.7, 0.5, 0.05)[:, None], seed=1)
    apriori = profile.with_values({"X_u": -0.1, "M_q": -2.0, "k": 1.0})
    for method in (LS, IV):
        est = method(apriori).fit(run)
        np.testing.assert_allclose(est.theta_, truth.theta, rtol=1e-9)


def test_equation_error_needs_every_state_measured(s61, s61_run_20s):
    run = Run(s61_run_20s.time, {k: v for k, v in s61_run_20s.channels.items() if k not in ("theta_R", "phi_R")},
              source="flight7.csv")
    with pytest.raises(RunError) as err:
        LS(s61.profile).fit(run)
    msg = str(err.value)
    assert "flight7.csv" in msg and "theta_R, phi_R" in msg and "every state" in msg and "\n" not in msg


def test_bad_data_and_unidentifiable_parameters_raise_one_line(s61, s61_run_20s):
    ch = dict(s61_run_20s.channels)
    ch["q"] = ch["q"].copy()
    ch["q"][500] = np.nan
    with pytest.raises(EstimationError, match=r"channel 'q': non-finite value at t = 5 s"):
        LS(s61.profile).fit(Run(s61_run_20s.time, ch))
    # lateral cyclic never moved: its derivatives are held at the a priori values, and said so
    t = np.arange(1001) * DT
    run = simulate_run(s61, t, inputs(t, lat=0.0), seed=0)
    with pytest.warns(UserWarning, match="held at their a priori values: no run moves theta_c"):
        result = LS(s61.profile).fit(run).result_
    held = result.info["held"]["theta_c"]
    assert held and all(n.endswith("_theta_c") for n in held)
    for n in held:
        i = result.names.index(n)
        assert result.theta[i] == s61.profile.free[n] and np.isinf(result.std[i])
    assert np.isfinite(result.std[[i for i, n in enumerate(result.names) if n not in held]]).all()


def test_output_only_parameter_is_refused(s61):
    text = s61.profile.to_toml().replace("[free]\n", "[free]\nk_q = 0.0\n") + '\n[ties]\nk_q = { "q:q" = 1.0 }\n'
    profile = parse_profile(text)
    t = np.arange(501) * DT
    run = simulate_run(LinearModel(profile), t, inputs(t, lat_start=1.5), seed=0)
    with pytest.raises(EstimationError, match="k_q act only on the output equation"):
        LS(profile).fit(run)


def _coloured_noise_runs(s61, seeds, rel=0.05, cutoff=2.0):
    """Exact states; state-derivative channels with low-pass (coloured) noise: LS is unbiased and
    its residuals are exactly that coloured noise."""
    t = np.arange(2001) * DT
    clean = simulate_run(s61, t, inputs(t), seed=0)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        ch = dict(clean.channels)
        for s in s61.profile.state_names:
            e = lowpass(rng.standard_normal(len(t)), DT, cutoff)
            ch[s + "_dot"] = ch[s + "_dot"] + rel * np.std(ch[s + "_dot"]) * e / np.std(e)
        yield Run(t, ch, source=f"seed {seed}")


def test_standard_errors_with_coloured_residuals_match_the_spread_over_seeds(s61):
    theta, std, white = [], [], []
    for run in _coloured_noise_runs(s61, range(12)):
        est = LS(s61.profile).fit(run)
        theta.append(est.theta_)
        std.append(est.std_)
        white.append(est.result_.info["std_white"])
    spread = np.std(theta, axis=0, ddof=1)
    ratio_coloured = spread / np.mean(std, axis=0)
    ratio_white = spread / np.mean(white, axis=0)
    gm = lambda r: float(np.exp(np.mean(np.log(r))))  # noqa: E731
    print(f"spread / CR std: coloured-corrected {gm(ratio_coloured):.2f} "
          f"(range {ratio_coloured.min():.2f}..{ratio_coloured.max():.2f}), white {gm(ratio_white):.2f}")
    # 12 seeds: the spread itself is uncertain by about +-20 %
    assert 0.6 < gm(ratio_coloured) < 1.6
    assert ratio_coloured.min() > 0.3 and ratio_coloured.max() < 3.0
    assert gm(ratio_white) > 2.5  # the uncorrected bound is far too optimistic: the test can tell


def test_two_runs_together_beat_either_alone(s61):
    """A 10 s longitudinal-cyclic run and a 10 s lateral-cyclic run (each with a small pulse on the
    other axis so that it is identifiable alone), noisy, evaluated singly and together."""
    t = np.arange(1001) * DT
    u_lon = np.column_stack([steps(t, P3211, 0.5, 1.0, 0.02), steps(t, [1, -1], 0.5, 6.0, 0.004)])
    u_lat = np.column_stack([steps(t, [1, -1], 0.5, 6.0, 0.004), steps(t, P3211, 0.5, 1.0, 0.02)])
    errors = {"lon": [], "lat": [], "both": []}
    for seed in range(3):
        lon = simulate_run(s61, t, u_lon, seed=10 + seed, noise_fraction=0.03)
        lat = simulate_run(s61, t, u_lat, seed=20 + seed, noise_fraction=0.03)
        for key, runs in (("lon", [lon]), ("lat", [lat]), ("both", [lon, lat])):
            est = LS(s61.profile).fit(runs)
            errors[key].append(np.sqrt(np.mean(relative_error(est.theta_, s61.theta) ** 2)))
    mean = {k: float(np.mean(v)) for k, v in errors.items()}
    print("RMS relative parameter error: " + ", ".join(f"{k} {v:.4f}" for k, v in mean.items()))
    assert mean["both"] < min(mean["lon"], mean["lat"])
    assert len(est.result_.time) == 2 and len(est.result_.info["zero_shifts"]) == 2


def test_iv_removes_most_of_the_ls_bias_from_noisy_states(s61):
    """Noise on the measured states biases LS (errors in variables); IV's simulated instruments
    are not correlated with that noise."""
    t = np.arange(2001) * DT
    u = inputs(t)
    ls, iv, iterations = [], [], []
    for seed in range(3):
        run = simulate_run(s61, t, u, seed=seed, noise_fraction=0.1)
        ls.append(LS(s61.profile).fit(run).theta_)
        est = IV(s61.profile).fit(run)
        iv.append(est.theta_)
        iterations.append(est.result_.info["iterations"])
        assert est.result_.info["converged"]
    bias_ls = np.median(relative_error(np.mean(ls, axis=0), s61.theta))
    bias_iv = np.median(relative_error(np.mean(iv, axis=0), s61.theta))
    print(f"median relative bias: LS {bias_ls:.4f}, IV {bias_iv:.4f}; IV iterations {iterations}")
    assert bias_iv < 0.3 * bias_ls


def test_iv_reports_progress_and_converges_from_a_poor_a_priori_model(s61, s61_run_20s):
    calls = []
    apriori = s61.profile.with_values({k: 0.5 * v for k, v in s61.profile.free.items()})
    est = IV(apriori, start="apriori", progress=lambda it, change, theta: calls.append((it, change))).fit(
        s61_run_20s)
    info = est.result_.info
    assert info["converged"] and len(calls) == info["iterations"] >= 1
    assert calls[-1][1] < 1e-9
    assert relative_error(est.theta_, s61.theta).max() < 5e-7
    with pytest.raises(EstimationError, match="start"):
        IV(s61.profile, start="guess").fit(s61_run_20s)
    with pytest.raises(EstimationError, match="reinit"):
        LS(s61.profile, reinit=-1.0).fit(s61_run_20s)


def test_result_exports_and_the_identified_profile_is_the_next_a_priori_model(s61, s61_run_20s, tmp_path):
    est = LS(s61.profile).fit(s61_run_20s)
    d = est.result_.to_dict()
    assert set(d["parameters"]["M_q"]) >= {"value", "std", "apriori"}
    assert d["parameters"]["M_q"]["value"] == pytest.approx(-0.1, rel=1e-9)
    assert len(d["eigenvalues"]) == 6
    out = est.result_.save(tmp_path)
    again = load_profile(out / "identified_profile.toml")
    np.testing.assert_allclose(list(again.free.values()), est.theta_, rtol=1e-12)


def test_restarted_simulation_bounds_the_drift_of_a_wrong_unstable_model(s61, s61_run_20s):
    from identify.estimators.equation_error import _segment, simulate_states
    # auto: half the 0.36 rad/s pair's 7.3 s time to double, as ML's multiple shooting cuts
    assert _segment(s61, "auto", 20.0) == pytest.approx(0.5 * np.log(2) / 0.0945, rel=0.01)
    assert _segment(s61, "auto", 5.0) is None  # a run shorter than one doubling: no restarts
    wrong = s61.with_theta(1.3 * s61.theta)
    run = s61_run_20s
    x, u = run.matrix(s61.profile.state_names), run.matrix(s61.profile.input_names)
    bias = np.zeros(s61.n_states)
    exact = simulate_states(s61, u, DT, x, bias, 2.0)
    np.testing.assert_allclose(exact, x, atol=1e-9 * np.abs(x).max())  # restarts cost nothing when right
    err = {seg: np.sqrt(np.mean((simulate_states(wrong, u, DT, x, bias, seg) - x) ** 2, axis=0)).max()
           for seg in (None, 2.0)}
    print(f"worst state RMS error of the wrong model: plain {err[None]:.3g}, restarted every 2 s {err[2.0]:.3g}")
    assert err[2.0] < 0.2 * err[None]
    # IV still works with a plain (never restarted) instrument simulation on this stable-enough run
    est = IV(s61.profile, reinit=None, start="apriori").fit(run)
    assert est.result_.info["instrument_segment_s"] is None
    assert relative_error(est.theta_, s61.theta).max() < 5e-7


def test_iv_shortens_the_restart_interval_when_an_estimate_diverges(s61, s61_run_20s):
    """A start far more unstable than the data: instruments restarted every 20 s would diverge
    (a rotor mode growing at 10 1/s), so the interval is halved until they do not, and IV still
    converges."""
    wild = s61.theta.copy()
    wild[s61.names.index("theta_R_theta_R")] *= -1
    profile = s61.with_theta(wild).to_profile()
    est = IV(profile, reinit=20.0, start="apriori").fit(s61_run_20s)
    assert est.result_.info["instrument_segment_s"] < 20.0
    assert relative_error(est.theta_, s61.theta).max() < 5e-7
