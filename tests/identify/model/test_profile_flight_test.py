"""Profile tables flight-test models need: process noise, known x0, zero shifts, biases, input hold."""
import numpy as np
import pytest

from identify import ML, LinearModel, load_profile, parse_profile, simulate, simulate_run
from identify.errors import EstimationError, ProfileError

BASE = """
name = "roll"
states = { p = "rad/s", phi = "rad" }
inputs = { da = "rad" }
outputs = ["p", "phi", "p_dot"]
[free]
L_p = -2.0
L_da = 10.0
[fixed]
phi_p = 1.0
"""
LINEAR = BASE.replace('outputs = ["p", "phi", "p_dot"]', 'outputs = ["p", "phi", "p_dot"]\ninput_hold = "linear"')


def test_tables_parse_round_trip_and_defaults():
    p = parse_profile(LINEAR + "[process_noise]\np = 0.1\n[initial_state]\nphi = 0.0\n[zero_shifts]\np = false\n"
                      "phi = { value = 0.01, fixed = true }\np_dot = 0.2\n[biases]\nL = 0.05\n")
    assert p.input_hold == "linear" and p.process_noise_states() == {"p": 0.1}
    assert p.zero_shift("p") == (0.0, False) and p.zero_shift("phi") == (0.01, False)
    assert p.zero_shift("p_dot") == (0.2, True)
    assert p.free["L_one"] == 0.05 and p.meta["pseudo_inputs"]["one"] == {"constant": 1.0}
    assert parse_profile(p.to_toml()) == p
    plain = parse_profile(BASE)
    assert plain.process_noise_states() == {} and plain.zero_shift("p") == (0.0, True)
    assert load_profile("navion_cruise_long").process_noise_states() == {"u": None, "w": None}


@pytest.mark.parametrize("extra, message", [
    ("[process_noise]\nx = 1.0\n", "not a state"),
    ("[initial_state]\nq = 0.0\n", "not a state"),
    ("[zero_shifts]\nq = false\n", "not an output"),
    ("[zero_shifts]\np = true\n", "expected a start value"),
])
def test_bad_tables_are_one_line_errors(extra, message):
    with pytest.raises(ProfileError, match=message):
        parse_profile(BASE + extra)
    with pytest.raises(ProfileError, match="input_hold"):
        parse_profile(LINEAR.replace('"linear"', '"cubic"'))


def test_linear_hold_is_exact_for_a_ramp():
    """A ramp input interpolated linearly: the discrete model matches a 100x finer held simulation."""
    model = LinearModel(parse_profile(BASE))
    dt, t = 0.1, np.arange(0, 3, 0.1)
    fine_t = np.arange(0, 2.9 + 1e-9, 0.001)
    lin = simulate(model, 0.1 * t[:, None], dt, hold="linear").x
    fine = simulate(model, 0.1 * (fine_t + 0.0005)[:, None], 0.001).x[::100]
    held = simulate(model, 0.1 * t[:, None], dt).x
    np.testing.assert_allclose(lin, fine[:len(lin)], atol=2e-6)
    assert np.abs(held - fine[:len(held)]).max() > 100 * np.abs(lin - fine[:len(lin)]).max()


def test_ml_holds_known_x0_and_absent_zero_shifts_and_refuses_linear_hold():
    p = parse_profile(BASE + "[initial_state]\nphi = 0.02\n[zero_shifts]\np = false\n")
    t = np.arange(0, 5, 0.02)
    u = np.where((t > 1) & (t < 2), 0.02, 0.0)
    run = simulate_run(LinearModel(p), t, u, x0=[0.0, 0.02], noise={"p": 0.001, "phi": 0.001, "p_dot": 0.01}, seed=1)
    res = ML(p, coloured=False).fit(run).result_
    assert res.info["initial_states"][0]["phi"] == 0.02 and res.info["segments"][0]["x0_std"]["phi"] == np.inf
    assert res.info["zero_shifts"][0]["p"] == 0.0 and res.info["zero_shift_std"][0]["p"] == np.inf
    assert np.isfinite(res.info["zero_shift_std"][0]["phi"])
    with pytest.raises(EstimationError, match="fem only"):
        ML(parse_profile(LINEAR)).fit(run)
