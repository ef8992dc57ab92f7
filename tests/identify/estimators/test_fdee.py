"""Frequency-domain equation error (FDEE): batch on the unstable S 61 4-DOF, and the recursive
version reaching the batch estimate sample by sample."""
import numpy as np
import pytest

from identify import LinearModel, load_profile, simulate_run
from signaldesign.baselines import m3211

DT = 0.02


def s61_runs(model, process_noise=0.0, seed=0):
    """Two 20-s runs of staggered 3211s on both cyclics of the (unstable) S 61 4-DOF, 3 % noise,
    no derivative channels."""
    t = np.arange(0, 20, DT)
    runs = []
    for k in range(2):
        U = np.column_stack([m3211(0.6, 0.01, "theta_s", delay=1.0 + k)(t),
                             m3211(0.5, 0.01, "theta_c", delay=4.0 + k)(t)])
        runs.append(simulate_run(model, t, U, noise_fraction=0.03, process_noise=process_noise,
                                 seed=seed + k, derivatives=False))
    return runs


@pytest.fixture(scope="module")
def s61_4dof():
    return LinearModel(load_profile("s61_hover_4dof"))


@pytest.mark.parametrize("process_noise", [0.0, 0.02])
def test_fdee_within_three_standard_errors_on_the_unstable_s61(s61_4dof, process_noise):
    from identify.estimators.frequency.equation_error import FDEE
    assert s61_4dof.unstable
    est = FDEE(s61_4dof.profile).fit(s61_runs(s61_4dof, process_noise, seed=7))
    z = (est.theta_ - s61_4dof.theta) / est.std_
    assert np.all(np.abs(z) < 3), dict(zip(est.result_.names, z.round(2)))
    assert est.result_.method == "fdee" and "FDEE identification" in est.summary()
    assert "coloured" in est.result_.info["standard_errors"]


def test_fdee_needs_every_state(s61_4dof):
    from identify import RunError
    from identify.estimators.frequency.equation_error import FDEE
    run = s61_runs(s61_4dof)[0]
    run.channels.pop("phi")
    with pytest.raises(RunError, match="phi"):
        FDEE(s61_4dof.profile).fit(run)


def test_fdee_unexcited_parameter_is_named(s61_4dof):
    """A run with the lateral cyclic held still cannot give its derivatives: held at their a
    priori values and said, not guessed."""
    from identify.estimators.frequency.equation_error import FDEE
    t = np.arange(0, 20, DT)
    U = np.column_stack([m3211(0.6, 0.01, "theta_s", delay=1.0)(t), np.zeros_like(t)])
    run = simulate_run(s61_4dof, t, U, noise_fraction=0.03, seed=1)
    with pytest.warns(UserWarning, match="no run moves theta_c"):
        result = FDEE(s61_4dof.profile).fit(run).result_
    assert "L_theta_c" in result.info["held"]["theta_c"] and np.isinf(result.std[result.names.index("L_theta_c")])


def test_streamed_estimate_equals_the_batch_one(s61_4dof):
    """Sample by sample (partial_fit, as in the cockpit), the streamed estimate reaches exactly the
    batch estimate; so does the record streamed in uneven blocks with a repeated frame."""
    from identify.estimators.frequency.equation_error import FDEE
    run = s61_runs(s61_4dof)[0]
    x, u = run.matrix(s61_4dof.profile.state_names), run.matrix(s61_4dof.profile.input_names)
    live = FDEE(s61_4dof.profile, band=(0.05, 1.5), n_freq=40)
    for k in range(len(run)):
        live.partial_fit(run.time[k], x[k], u[k])
    blocks = FDEE(s61_4dof.profile, band=(0.05, 1.5), n_freq=40)
    for k0, k1 in [(0, 1), (1, 300), (299, 300), (300, 5000)]:  # (299, 300): a repeated frame
        blocks.partial_fit(run.time[k0:k1], x[k0:k1], u[k0:k1])
    batch = FDEE(s61_4dof.profile, band=(0.05, 1.5), n_freq=40).fit(run).result_
    assert live.n_samples == blocks.n_samples == len(run)
    for est in (live.solve(), blocks.solve()):
        assert not est.errors
        assert np.allclose(est.theta, batch.theta, rtol=1e-8, atol=1e-10)
        assert np.allclose(est.std, batch.std, rtol=1e-6)
        assert np.allclose(est.insensitivity, batch.insensitivity, rtol=1e-6)


def test_fdee_takes_no_state_derivative(s61_4dof, monkeypatch):
    """FDEE's preparation reads the measured states only: nothing is differentiated."""
    from identify.estimators import equation_error
    from identify.estimators.frequency.equation_error import FDEE

    def refuse(*args, **kwargs):
        raise AssertionError("FDEE differentiated a state")
    monkeypatch.setattr(equation_error, "state_derivatives", refuse)
    res = FDEE(s61_4dof.profile).fit(s61_runs(s61_4dof)).result_
    assert res.info["derivatives"].startswith("not used")


def test_fdee_reports_cramer_rao_and_insensitivity_and_flags_an_unexcited_derivative():
    """Tischler & Remple's accuracy view of a frequency-domain fit: with the lateral stick moved
    1 % as much as the longitudinal one, its pitch derivative M_theta_c hardly changes the fit
    (insensitivity over 10 %) and is flagged; the well-excited derivatives are not."""
    from identify import parse_profile
    from identify.estimators.frequency.equation_error import FDEE
    from tests.identify.estimators.test_frequency_response import STABLE
    truth = LinearModel(parse_profile(STABLE))
    t = np.arange(0, 20, DT)
    runs = [simulate_run(truth, t, np.column_stack([m3211(w, 0.02, "theta_s", delay=1.0)(t),
                                                    m3211(0.7, 0.0002, "theta_c", delay=9.0)(t)]),
                         noise_fraction=0.05, seed=10 + k) for k, w in enumerate((0.5, 0.8, 1.2))]
    result = FDEE(truth.profile).fit(runs).result_
    acc = result.accuracy()
    assert acc["M_theta_c"]["insensitivity_pct"] > 10 and any("insensitive" in f for f in acc["M_theta_c"]["over_guidelines"])
    for name in ("M_theta_s", "L_theta_s", "M_q", "L_p"):
        assert acc[name]["over_guidelines"] == [], (name, acc[name])
    # the insensitivity (others known) never exceeds the Cramér-Rao bound (others estimated too)
    assert np.all(result.insensitivity <= result.std * (1 + 1e-9))
    text = result.summary()
    assert "insensitive (I > 10 %)" in text and "over a guideline: " in text and "M_theta_c" in text.split("over a guideline")[1]
    assert result.to_dict()["info"]["accuracy"]["M_theta_c"]["over_guidelines"]
