"""FR's bias correction (the response estimate's own error) and the residual bootstrap's surrogates."""
from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import chirp, lfilter

from identify import LinearModel, load_profile, simulate_run
from identify.estimators.frequency.bootstrap import incoherent_part, surrogate_noise
from identify.estimators.frequency.response_fit import FR

DT = 0.02


@pytest.fixture(scope="module")
def clean_runs():
    """Noise-free 20-s sweeps of the unstable S 61 hover model, 0.1-2 Hz on each cyclic."""
    p = load_profile("s61_hover_4dof")
    t = np.arange(0, 20, DT)
    runs = []
    for j in range(2):
        U = np.zeros((len(t), 2))
        U[:, j] = np.deg2rad(0.2) * chirp(t, 0.1, t[-1], 2.0, method="logarithmic", phi=-90)
        runs.append(simulate_run(LinearModel(p), t, U))
    return p, runs


def test_the_estimates_own_error_is_corrected_on_noise_free_short_runs(clean_runs):
    p, runs = clean_runs
    free = ["L_p", "L_theta_c", "M_theta_s"]  # what these sweeps determine (the benchmark's set)
    start = replace(p, free={k: 1.2 * p.free[k] for k in free},
                    fixed={**p.fixed, **{k: v for k, v in p.free.items() if k not in free}})
    want = np.array([p.free[k] for k in free])
    raw = FR(start, n_draws=0, bias_passes=0).fit(runs).result_
    fixed = FR(start, n_draws=0).fit(runs).result_
    # without the correction the short records' leakage and transients leave percent-level errors
    assert np.max(np.abs(raw.theta / want - 1)) > 5e-3
    assert np.max(np.abs(fixed.theta / want - 1)) < 1e-3
    assert any("response estimate's own error" in line for line in fixed.info["report_lines"])


def test_surrogates_keep_the_spectra_and_drop_what_the_inputs_explain():
    rng = np.random.default_rng(1)
    N = 2000
    u = rng.standard_normal((N, 1))
    noise = 0.3 * rng.standard_normal((N, 2))
    noise[:, 1] += 0.5 * noise[:, 0]  # correlated outputs
    s = surrogate_noise(noise, np.random.default_rng(2))
    A, S = np.fft.rfft(noise - noise.mean(0), axis=0), np.fft.rfft(s, axis=0)
    assert np.allclose(np.abs(A), np.abs(S)) and not np.allclose(noise, s)
    assert np.allclose(A[:, 0].conj() * A[:, 1], S[:, 0].conj() * S[:, 1])  # cross-spectrum kept
    # a residual that is mostly a response to the input: only the noise's power is left
    residual = np.column_stack([lfilter([1.0], [1, -0.9], u[:, 0])] * 2) + noise
    left = np.sum(np.abs(incoherent_part(residual, u)) ** 2, axis=0)
    assert np.allclose(left / np.sum(np.abs(A) ** 2, axis=0), 1, atol=0.15)
