"""Pseudo-inputs a profile describes are rebuilt from any run, once, without parsing names."""
import numpy as np
import pytest

from identify import ProfileError, Run, parse_profile
from identify.model import pseudo_inputs as pi

TOML = """
name = "p"
states = { q = "rad/s" }
inputs = { eta = "rad", one = "1", t = "s", mystery = "nonlinear", wobble = "1" }
outputs = ["q"]
[free]
M_q = -1.0
[meta]
delays = { eta = 0.04 }
[meta.pseudo_inputs]
one = { constant = 1.0 }
t = { time = 1 }
mystery = { product = ["q", "eta"], abs = [true, false] }
wobble = { sinusoid = "q", frequency = 2.0, quadrature = true }
"""


def _run():
    t = 10.0 + np.arange(500) * 0.02
    return Run(t, {"eta": np.sign(np.sin(t)), "q": np.cos(2 * np.pi * 2.0 * t + 0.3) + 0.1 * t})


def test_channels_rebuilt_from_the_descriptions_not_the_names():
    p = parse_profile(TOML)
    run = _run()
    (r,) = pi.prepare(p, [run])
    np.testing.assert_allclose(r["one"], 1.0)
    np.testing.assert_allclose(r["t"], run.time - run.time[0])
    eta = r["eta"]  # delayed by 0.04 s = 2 samples
    np.testing.assert_allclose(eta[2:], run["eta"][:-2])
    np.testing.assert_allclose(r["mystery"], np.abs(run["q"]) * eta)  # the run's own channels, delayed input
    # quadrature of the measured output's own 2 Hz component: sin(2 pi f t + phase of q at f)
    tt = run.time - run.time[0]
    assert np.corrcoef(r["wobble"], np.sin(2 * np.pi * 2.0 * tt + 0.3 + 2 * np.pi * 2.0 * 10.0))[0, 1] > 0.99


def test_prepare_is_idempotent_and_leaves_recorded_channels():
    p = parse_profile(TOML)
    once = pi.prepare(p, [_run()])
    twice = pi.prepare(p, once)
    np.testing.assert_array_equal(once[0]["eta"], twice[0]["eta"])
    plain = parse_profile(TOML.split("[meta]")[0].replace(', one = "1", t = "s", mystery = "nonlinear", '
                                                          'wobble = "1"', ""))
    assert pi.prepare(plain, [_run()])[0].channels.keys() == _run().channels.keys()


def test_a_list_of_names_is_one_clear_error():
    legacy = parse_profile(TOML.split("[meta]")[0] + '[meta]\npseudo_inputs = ["one", "t"]\n')
    with pytest.raises(ProfileError, match="re-run refine"):
        pi.prepare(legacy, [_run()])
