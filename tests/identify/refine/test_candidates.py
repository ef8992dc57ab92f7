"""Candidate effects as profile + run transformations."""
import numpy as np

from identify import LinearModel, parse_profile, simulate, simulate_run
from identify.refine.candidates import (Context, Delay, Derivative, Lag, Nonlinear, Periodic, bias, catalogue,
                                        delay_run, drift, prepare_runs, scale)
from identify.refine.diagnostics import dominant_frequency
from tests.identify.refine.test_refine import PROFILE, excitation

DT, N = 0.02, 1001


def _run(seed=1):
    return simulate_run(LinearModel(PROFILE), np.arange(N) * DT, excitation(seed), noise_fraction=0.01, seed=seed)


def _outputs(p, run):
    m = LinearModel(p)
    return simulate(m, run.matrix(p.input_names), run.dt).y


def test_linear_candidates_at_null_value_leave_the_model_unchanged():
    run = _run()
    y0 = _outputs(PROFILE, run)
    for c in (Derivative("M_u"), Derivative("X_eta"), bias("q"), drift("theta"), scale("q"),
              Nonlinear("M", "q_absq", ("q",), "absq"), Periodic("q", 4.0)):
        p, (r,) = c.apply(PROFILE, [run])
        assert set(c.params) <= set(p.free), c.name
        np.testing.assert_allclose(_outputs(p, r), y0, atol=1e-12, err_msg=c.name)
        back = parse_profile(p.to_toml())  # round-trips as plain TOML
        assert (back.states, back.inputs, back.outputs, back.free, back.fixed, back.ties, back.meta) == \
            (p.states, p.inputs, p.outputs, p.free, p.fixed, p.ties, p.meta), c.name


def test_candidate_entries_act_where_named():
    run = _run()
    p, (r,) = scale("q").apply(PROFILE, [run], {"sf_q": 0.1})
    y0, y = _outputs(PROFILE, run), _outputs(p, r)
    np.testing.assert_allclose(y[:, 1], 1.1 * y0[:, 1], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(y[:, [0, 2]], y0[:, [0, 2]])
    p, (r,) = drift("theta").apply(PROFILE, [run], {"drift_theta": 0.01})
    np.testing.assert_allclose(_outputs(p, r)[:, 2] - y0[:, 2], 0.01 * (run.time - run.time[0]), atol=1e-12)


def test_lag_moves_input_derivatives_onto_lag_state_and_fast_lag_is_the_original():
    p = Lag("eta", k=2000.0).profile(PROFILE)
    assert "eta_lag" in p.states and "M_eta_lag" in p.free and "M_eta" not in p.free
    assert p.ties["k_eta_lag"] == {"eta_lag_eta_lag": -1.0, "eta_lag_eta": 1.0}
    run = _run()
    y0 = _outputs(PROFILE, run)
    y = simulate(LinearModel(p), run.matrix(p.input_names), run.dt).y
    assert np.max(np.abs(y - y0)) < 0.01 * np.max(np.abs(y0))
    slow = simulate(LinearModel(Lag("eta", k=5.0).profile(PROFILE)), run.matrix(["eta"]), run.dt).y
    assert np.max(np.abs(slow - y0)) > 0.1 * np.max(np.abs(y0))


def test_delay_shifts_the_input_by_whole_samples_exactly():
    run = _run()
    late = delay_run(run, "eta", 5 * DT)
    np.testing.assert_allclose(late["eta"][5:], run["eta"][:-5], atol=1e-12)
    p, (r,) = Delay("eta").apply(PROFILE, [run], {"tau_eta": 0.1})
    assert p.meta["delays"] == {"eta": 0.1}
    np.testing.assert_allclose(prepare_runs(p, [run])[0]["eta"], r["eta"])


def test_prepare_runs_rebuilds_pseudo_inputs_of_a_refined_profile():
    run = _run()
    p, _ = bias("q").apply(PROFILE, [run])
    for c in (drift("u"), Nonlinear("M", "q_absq", ("q",), "absq"), Nonlinear("M", "u_x_q", ("u", "q"), "prod"),
              Periodic("q", 3.0)):
        p, _ = c.apply(p, [run])
    p = parse_profile(p.to_toml())  # as read back from final_profile.toml
    (r,) = prepare_runs(p, [run])
    np.testing.assert_allclose(r["one"], 1.0)
    np.testing.assert_allclose(r["t"], run.time - run.time[0])
    np.testing.assert_allclose(r["q_absq"], run["q"] * np.abs(run["q"]))
    np.testing.assert_allclose(r["u_x_q"], run["u"] * run["q"])
    np.testing.assert_allclose(r["cos_q"] ** 2 + r["sin_q"] ** 2, 1.0)
    assert abs(dominant_frequency([r["cos_q"]], DT, 0.5) - 3.0) < 0.01
    for name in p.inputs:
        assert name in r.channels


def test_catalogue_lists_every_structurally_zero_entry_once():
    run = _run()
    ctx = Context([run], [np.zeros((len(run), 3))], DT)
    cands = catalogue(PROFILE, ctx, kinds=("derivative",))
    names = sorted(c.target for c in cands)
    # the dynamic equations X and M only (theta_dot = q is kinematics, all fixed): A: X_q, M_u; B: X_eta
    assert names == sorted(["X_q", "M_u", "X_eta"])
    kinds = {c.kind for c in catalogue(PROFILE, ctx)}
    assert kinds == {"derivative", "delay", "sensor_lag", "bias", "drift", "scale", "nonlinear", "periodic"}
    p = Derivative("M_u").profile(PROFILE)
    assert "M_u" not in [c.target for c in catalogue(p, ctx, kinds=("derivative",))]


def test_a_scale_factor_beyond_any_calibration_error_is_implausible():
    sf = scale("q")
    assert sf.implausible({"sf_q": {"value": 0.15, "std": 0.02}}) == ""
    reason = sf.implausible({"sf_q": {"value": -0.5, "std": 0.007}})
    assert "-50 %" in reason and "'q'" in reason
    assert Derivative("M_u").implausible({"M_u": {"value": 40.0, "std": 1.0}}) == ""
