"""The state-space frequency-response fit (DERIVID) on exact responses: recovery, delays, gates."""
import numpy as np
import pytest

from identify import LinearModel, load_profile
from identify.estimators.frequency.statespace import ResponseData, fit_frequency_responses, response_and_jacobian


@pytest.fixture(scope="module")
def s61():
    return load_profile("s61_hover_4dof")


def exact_data(model, omega, tau=None, coherence=1.0):
    p = model.profile
    H = response_and_jacobian(model, omega, list(range(len(p.outputs))), list(range(len(p.input_names))), tau)
    return ResponseData(omega, H, np.full(H.shape, coherence), np.ones(H.shape, bool), p.input_names,
                        list(p.outputs))


def test_noise_free_responses_give_the_derivatives_and_delays(s61):
    truth = LinearModel(s61)
    data = exact_data(truth, 2 * np.pi * np.geomspace(0.05, 3, 60), tau=np.array([0.05, 0.08]))
    start = truth.theta * np.random.default_rng(1).uniform(0.7, 1.3, truth.theta.size)
    fit = fit_frequency_responses(s61, data, theta0=start, delays=("theta_s", "theta_c"))
    assert fit.converged
    assert np.max(np.abs(fit.theta / truth.theta - 1)) < 1e-4
    assert fit.tau == pytest.approx({"theta_s": 0.05, "theta_c": 0.08}, rel=1e-4)
    assert fit.J_mean < 1e-6 and len(fit.J) == 12 and not fit.left_out


def test_only_resolved_coherent_points_count_and_short_pairs_are_left_out(s61):
    truth = LinearModel(s61)
    omega = 2 * np.pi * np.geomspace(0.05, 3, 40)
    data = exact_data(truth, omega)
    data.H = data.H.copy()
    data.H[:10] *= 5.0  # garbage where nothing is resolved: must not count
    data.resolved[:10] = False
    data.coherence[:, 0, 1] = 0.3  # u/theta_c incoherent everywhere
    start = truth.theta * 1.2
    fit = fit_frequency_responses(s61, data, theta0=start)
    assert np.max(np.abs(fit.theta / truth.theta - 1)) < 1e-4
    assert "u/theta_c" in fit.left_out and "u/theta_c" not in fit.J
    assert all(n == 30 for n in fit.n_points.values())


def test_pruning_fixes_what_the_data_cannot_determine_and_says_why(s61):
    # only the pitch and roll rates to 0.5..3 Hz: the speed derivatives are not determined
    truth = LinearModel(s61)
    p = s61
    omega = 2 * np.pi * np.geomspace(0.5, 3, 30)
    full = exact_data(truth, omega)
    keep = [p.outputs.index(y) for y in ("p", "q")]
    rng = np.random.default_rng(2)
    noisy = full.H[:, keep] * (1 + 0.02 * (rng.standard_normal(full.H[:, keep].shape)
                                           + 1j * rng.standard_normal(full.H[:, keep].shape)))
    data = ResponseData(omega, noisy, np.full(noisy.shape, 0.95), np.ones(noisy.shape, bool),
                        p.input_names, ["p", "q"])
    free = fit_frequency_responses(p, data)
    bad = [n for n, a in free.accuracy().items() if a["over_gates"]]
    assert bad  # some derivatives cannot be had from p, q above 0.5 Hz
    pruned = fit_frequency_responses(p, data, prune=True)
    assert pruned.pruned and all(r for _, r, _ in pruned.pruned)
    assert all(not a["over_gates"] for a in pruned.accuracy().values())
    assert set(n for n, _, _ in pruned.pruned) <= set(p.free)
    assert all(n in pruned.profile.fixed for n, _, _ in pruned.pruned)
