"""Residual diagnostics: each check must pass white noise and flag the structure it is for."""
import numpy as np
from scipy import signal, stats

from identify.refine import diagnostics as dg


def test_whiteness_passes_noise_and_flags_coloured_residual(rng):
    white = [rng.standard_normal((800, 2)) for _ in range(2)]
    assert np.all(dg.whiteness(white)["p_value"] > 0.01)
    coloured = [signal.lfilter([1.0], [1.0, -0.6], e, axis=0) for e in white]
    assert np.all(dg.whiteness(coloured)["p_value"] < 1e-6)


def test_mean_trend_finds_drift_not_noise(rng):
    t = np.arange(1000) * 0.02
    e = rng.standard_normal((1000, 2))
    e[:, 1] += 0.1 * t
    mt = dg.mean_trend([e], [t])
    assert abs(mt["t_trend"][0]) < 4 and mt["t_trend"][1] > 10
    assert abs(mt["trend"][1] - 0.1) < 5 * abs(mt["trend"][1] / mt["t_trend"][1])


def test_spectral_peak_locates_line_and_fisher_test_is_calibrated(rng):
    dt, n = 0.02, 1000
    t = np.arange(n) * dt
    e = rng.standard_normal((n, 1)) + 0.5 * np.sin(2 * np.pi * 4.0 * t)[:, None]
    sp = dg.spectral_peak([e], dt)
    assert abs(sp["frequency"][0] - 4.0) <= 1 / (n * dt) and sp["p_value"][0] < 1e-6
    assert abs(dg.dominant_frequency([e[:, 0]], dt, 0.5) - 4.0) < 0.01
    p = np.array([dg.spectral_peak([rng.standard_normal((400, 1))], dt)["p_value"][0] for _ in range(300)])
    assert np.mean(p < 0.05) <= 0.08  # conservative by construction, never liberal


def _regression(rng, n=600, c=0.0):
    base = rng.standard_normal((n, 1, 3))
    cand = rng.standard_normal((n, 1, 1))
    e = rng.standard_normal((n, 1)) + c * cand[:, :, 0]
    nuis = np.ones((n, 1, 1))
    return e, base, nuis, cand


def test_score_statistic_is_chi_square_under_the_null(rng):
    stats_ = []
    for _ in range(400):
        e, base, nuis, cand = _regression(rng)
        # residual of the fitted base model, as after an estimation
        X = np.concatenate([base, nuis], axis=2)[:, 0, :]
        e = e - X @ np.linalg.lstsq(X, e, rcond=None)[0]
        stats_.append(dg.score_test([e], [base], [nuis], [cand])["statistic"])
    stats_ = np.array(stats_)
    assert abs(stats_.mean() - 1.0) < 0.2
    assert np.mean(stats_ > stats.chi2.isf(0.05, 1)) < 0.09


def test_score_test_detects_candidate_and_linear_estimate(rng):
    e, base, nuis, cand = _regression(rng, c=0.3)
    out = dg.score_test([e], [base], [nuis], [cand])
    assert out["statistic"] > 30 and out["dof"] == 1
    sb = dg.ScoreBase.build([e], dg.block_design([base], [nuis]))
    assert abs(sb.linear_estimate(cand.reshape(-1, 1)) - 0.3) < 0.15


def test_candidate_in_span_of_model_is_not_testable(rng):
    e, base, nuis, _ = _regression(rng)
    inside = base[:, :, :1] * 2.0 + nuis
    assert dg.score_test([e], [base], [nuis], [inside])["dof"] == 0


def test_sidak_threshold_grows_with_number_of_tests():
    assert dg.sidak_threshold(0.01, 1, 1) < dg.sidak_threshold(0.01, 100, 1) < dg.sidak_threshold(0.01, 100, 2)
    assert abs(dg.sidak_threshold(0.05, 1, 1) - stats.chi2.isf(0.05, 1)) < 1e-9
