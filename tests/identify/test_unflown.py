"""Controls that were not flown: a cyclics-only BO 105 test (collective and tail rotor never
moved) identifies; the parameters of the unflown controls are held at their a priori values and
said so, the rest estimated within their standard errors."""
import warnings

import numpy as np
import pytest

from identify import FDEE, ML, LinearModel, load_profile, perturbed_model, simulate_run
from identify.model.subset import fix, free, input_parameters, unflown_parameters, with_outputs
from identify.errors import ProfileError
from signaldesign.baselines import m3211

UNFLOWN = ("theta_0", "theta_TR")


@pytest.fixture(scope="module")
def cyclics_only():
    p = load_profile("bo105_70kt")
    m = LinearModel(p)
    truth = perturbed_model(m, 0.1, np.random.default_rng(5))
    t = np.arange(0, 12, 0.02)
    runs = []
    for k, (name, width) in enumerate((("theta_s", 0.7), ("theta_c", 0.5))):  # one run per axis
        u = np.zeros((t.size, m.n_inputs))
        u[:, p.input_names.index(name)] = m3211(width, 0.01, name, 1.0)(t)
        runs.append(simulate_run(truth, t, u, noise_fraction=0.03, seed=k))
    return p, truth, runs


@pytest.mark.parametrize("estimator", [ML, FDEE])
def test_cyclics_only_bo105_identifies(cyclics_only, estimator):
    p, truth, runs = cyclics_only
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = estimator(p).fit(runs).result_
    lines = [str(w.message) for w in caught if "held at their a priori values" in str(w.message)]
    assert len(lines) == 1 and all(u in lines[0] for u in UNFLOWN)
    held = [n for u in UNFLOWN for n in input_parameters(p)[u]]
    assert sorted(n for v in result.info["held"].values() for n in v) == sorted(held)
    for i, n in enumerate(result.names):
        if n in held:
            assert result.theta[i] == p.free[n] and np.isinf(result.std[i])
    est = np.array([n not in held for n in result.names])
    z = np.abs(result.theta - truth.theta)[est] / result.std[est]
    assert np.isfinite(z).all() and z.max() < 4.0, z.max()  # 4 std: ~30 parameters, none should be off
    assert "held (std inf)" in result.summary()


def test_fix_free_outputs_and_unflown_detection(cyclics_only):
    p, _, runs = cyclics_only
    assert set(unflown_parameters(p, runs)) == set(UNFLOWN)
    assert unflown_parameters(p, runs + [runs[0].with_channels({"theta_0": runs[0]["theta_s"]})]) == \
        {"theta_TR": input_parameters(p)["theta_TR"]}
    held = fix(p, "M_q,L_p")
    assert "M_q" in held.fixed and "M_q" not in held.free and held.fixed["M_q"] == p.free["M_q"]
    assert free(held, ["M_q"]).free["M_q"] == p.free["M_q"]
    with pytest.raises(ProfileError, match="cannot fix M_qq"):
        fix(p, "M_qq")
    with pytest.raises(ProfileError, match=r"cannot free M_q \(already free\)"):
        free(p, "M_q")
    narrowed = with_outputs(p, "p,q,r")
    assert narrowed.outputs == ("p", "q", "r") and set(narrowed.limits) <= {"p", "q", "r"}
    with pytest.raises(ProfileError, match="output\\(s\\) nz not in the profile"):
        with_outputs(p, "p,nz")


def delayed_cyclics_only():
    """The cyclics-only BO 105 with an undeclared 0.08 s delay on theta_s: two fit runs (one per
    cyclic) and two validation runs that move both."""
    from signaldesign.baselines import doublet
    p = load_profile("bo105_70kt")
    m = LinearModel(p)
    truth = perturbed_model(m, 0.1, np.random.default_rng(5))
    t = np.arange(0, 10, 0.04)

    def run(signals, seed):
        u = np.zeros((t.size, m.n_inputs))
        for s in signals:
            u[:, p.input_names.index(s.input)] += s(t)
        return simulate_run(truth, t, u, noise_fraction=0.03, seed=seed, input_delay={"theta_s": 0.08})
    runs = [run([m3211(0.7, 0.01, "theta_s", 1.0)], 0), run([m3211(0.5, 0.01, "theta_c", 1.0)], 1)]
    validate = [run([doublet(1.0, 0.01, "theta_s", 1.0), doublet(0.7, 0.01, "theta_c", 5.0)], 2 + k) for k in range(2)]
    return p, runs, validate


def test_cyclics_only_bo105_refines():
    """refine on the cyclics-only test: the collective and tail-rotor parameters held (said once),
    the undeclared 0.08 s delay on theta_s found; the final model keeps the held ones free, at
    their a priori values, for a test that flies those controls."""
    from identify.refine import Refine
    p, runs, validate = delayed_cyclics_only()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        refine = Refine(p, kinds=("delay", "derivative")).fit(runs, validate=validate)
    assert sum("REFINE:" in str(w.message) and "no run moves theta_0, theta_TR" in str(w.message) for w in caught) == 1
    (step,) = refine.steps_
    tau = step.parameters["tau_theta_s"]
    assert step.effect == "delay" and abs(tau["value"] - 0.08) < 3 * tau["std"] + 1e-3, tau
    held = [n for u in UNFLOWN for n in input_parameters(p)[u]]
    assert all(refine.profile_.free[n] == p.free[n] for n in held)
    assert all(np.isinf(refine.result_.std[refine.result_.names.index(n)]) for n in held)


def test_delay_bound_with_fdee_carries_its_derivative_errors():
    """refine with FDEE: the delay's curvature bound alone (0.0016 s) put this draw's 0.0855 s 3.4
    standard errors from the truth; FDEE's own errors in the derivatives move the best-fitting
    delay (12 draws scattered 0.0071 s), and the standard error now carries them."""
    from identify.refine import Refine
    p, runs, validate = delayed_cyclics_only()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        refine = Refine(p, estimator=FDEE(p), kinds=("delay", "derivative")).fit(runs, validate=validate)
    (step,) = refine.steps_
    tau = step.parameters["tau_theta_s"]
    assert step.effect == "delay" and tau["std"] > 2 * tau["std_profile"], tau
    assert abs(tau["value"] - 0.08) < 2 * tau["std"], tau
