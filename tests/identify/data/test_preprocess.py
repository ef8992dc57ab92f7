import numpy as np
import pytest
from scipy.signal import butter, sosfilt

from identify import Run, RunError, read_run
from identify.data.preprocess import (add_derivatives, central_difference, cg_correction, differentiator_taps, lowpass,
                                 processing_steps, replay, slice_run, smooth, smooth_derivative)

DT = 0.011  # the paper's sample interval


def _sine_fit(t, x, f, others=(1.0, 20.0)):
    """Amplitude and phase (rad) of the f-Hz component of x, fitted by least squares together
    with the ``others`` frequencies (so they do not leak into it)."""
    freqs = [f] + [g for g in others if g != f]
    M = np.column_stack([fn(2 * np.pi * g * t) for g in freqs for fn in (np.sin, np.cos)] + [np.ones_like(t)])
    a, b = np.linalg.lstsq(M, x, rcond=None)[0][:2]
    return np.hypot(a, b), np.arctan2(b, a)


def test_smoothing_removes_vibration_and_keeps_low_frequency_in_phase():
    t = np.arange(0, 20, DT)
    slow, vib = np.sin(2 * np.pi * 1.0 * t), 0.5 * np.sin(2 * np.pi * 20.0 * t)
    out = lowpass(slow + vib, DT, 6.25)
    mid = slice(200, -200)
    amp1, ph1 = _sine_fit(t[mid], out[mid], 1.0)
    amp20, _ = _sine_fit(t[mid], out[mid], 20.0)
    assert amp20 < 1e-3 * 0.5  # 20 Hz vibration down by more than 60 dB
    assert amp1 == pytest.approx(1.0, abs=2e-3)
    assert abs(ph1) < np.radians(0.05)  # zero phase
    # the same filter run forwards only lags: the test can tell the difference
    causal = sosfilt(butter(4, 6.25, fs=1 / DT, output="sos"), slow + vib)
    assert abs(_sine_fit(t[mid], causal[mid], 1.0)[1]) > np.radians(5)


def test_differentiator_has_90_degree_phase_and_unit_slope_in_band():
    taps = differentiator_taps(DT, 6.25)
    K = (len(taps) - 1) // 2
    np.testing.assert_allclose(taps, -taps[::-1], atol=0)  # antisymmetric: purely imaginary response
    k = np.arange(-K, K + 1)
    for f in (0.1, 0.5, 1.0, 2.0, 3.0):
        H = np.sum(taps * np.exp(2j * np.pi * f * DT * k))
        assert abs(H.real) < 1e-9 * abs(H)
        assert H.imag / (2 * np.pi * f) == pytest.approx(1.0, abs=3e-3)
    H20 = np.sum(taps * np.exp(2j * np.pi * 20.0 * DT * k))
    assert abs(H20) < 1e-3 * 2 * np.pi * 20  # vibration is not amplified


def test_smoothed_differentiation_beats_central_differences_on_noisy_data(rng):
    t = np.arange(0, 20, DT)
    x = np.sin(2 * np.pi * 0.3 * t) + 0.4 * np.sin(2 * np.pi * 1.1 * t + 1.0)
    xdot = 2 * np.pi * (0.3 * np.cos(2 * np.pi * 0.3 * t) + 0.4 * 1.1 * np.cos(2 * np.pi * 1.1 * t + 1.0))
    noisy = x + 0.01 * rng.standard_normal(len(t))
    err_smooth = smooth_derivative(noisy, DT, 6.25) - xdot
    err_central = central_difference(noisy, DT) - xdot
    rms = lambda e: np.sqrt(np.mean(e ** 2))  # noqa: E731
    print(f"derivative RMS error: smoothed {rms(err_smooth):.4f}, central differences {rms(err_central):.4f}")
    assert rms(err_smooth) < 0.25 * rms(err_central)
    assert rms(err_smooth[100:-100]) < 0.05 * np.std(xdot)
    # noise-free: accurate inside; near the ends (half the filter length) within a few per cent
    err = np.abs(smooth_derivative(x, DT, 6.25) - xdot)
    K = (len(differentiator_taps(DT, 6.25)) - 1) // 2
    assert err[K:-K].max() < 0.005 * np.abs(xdot).max()
    assert err.max() < 0.1 * np.abs(xdot).max()


def test_cg_correction_recovers_cg_accelerations_of_a_rigid_body():
    t = np.arange(0, 10, DT)
    w = np.column_stack([0.3 * np.sin(1.3 * t), 0.2 * np.cos(0.7 * t), 0.25 * np.sin(0.5 * t + 0.3)])
    wdot = np.column_stack([0.39 * np.cos(1.3 * t), -0.14 * np.sin(0.7 * t), 0.125 * np.cos(0.5 * t + 0.3)])
    a_cg = np.column_stack([0.5 * np.sin(0.4 * t), -0.2 * np.cos(0.9 * t), 9.81 + 0.1 * np.sin(t)])
    r = np.array([1.2, -0.4, 0.8])
    a_s = a_cg + np.cross(wdot, r) + np.cross(w, np.cross(w, r))
    run = Run(t, {"a_x": a_s[:, 0], "a_y": a_s[:, 1], "a_z": a_s[:, 2], "p": w[:, 0], "q": w[:, 1], "r": w[:, 2],
                  "p_dot": wdot[:, 0], "q_dot": wdot[:, 1], "r_dot": wdot[:, 2]})
    exact = cg_correction(run, r, rate_derivatives=("p_dot", "q_dot", "r_dot"))
    np.testing.assert_allclose(exact.matrix(["a_x", "a_y", "a_z"]), a_cg, atol=1e-12)
    # angular accelerations from smoothed differentiation of the rates: small error only
    derived = cg_correction(run, r)
    correction = np.abs(a_s - a_cg).max()
    assert np.abs(derived.matrix(["a_x", "a_y", "a_z"]) - a_cg).max() < 0.01 * correction
    assert processing_steps(derived)[-1]["offset"] == r.tolist()


def test_cg_correction_pure_yaw_rate_centripetal():
    """Accelerometer 2 m ahead of the CG, steady yaw rate 0.5 rad/s: it reads -r^2 x = -0.5 m/s^2."""
    t = np.arange(0, 2, 0.01)
    run = Run(t, {"a_x": np.full(t.size, -0.5), "r": np.full(t.size, 0.5)})
    out = cg_correction(run, [2.0, 0.0, 0.0])
    np.testing.assert_allclose(out["a_x"], 0.0, atol=1e-12)
    with pytest.raises(RunError, match="CG offset"):
        cg_correction(run, [1.0, np.nan, 0.0])
    with pytest.raises(RunError, match="needs at least one"):
        cg_correction(Run(t, {"q": t}), [1.0, 0, 0])


def test_every_step_is_recorded_and_replays_to_the_same_data(tmp_path, rng):
    t = np.arange(0, 10, DT)
    raw = Run(t, {"q": np.sin(t) + 0.01 * rng.standard_normal(t.size), "theta_s": np.sign(np.sin(0.5 * t)),
                  "a_x": 0.1 * np.cos(t), "p": 0.05 * np.sin(2 * t)}, {"aircraft": "test"}, "raw.csv")
    done = smooth(raw, 6.25, channels=["q", "a_x", "p"])
    done = add_derivatives(done, ["q"], cutoff_hz=5.0)
    done = cg_correction(done, [0.5, 0.0, 0.1], rates=("p", "q", None))
    done = slice_run(done, 1.0, 8.0)
    steps = processing_steps(done)
    assert [s["step"] for s in steps] == ["smooth", "differentiate", "cg_correction", "slice"]
    assert steps[0]["cutoff_hz"] == 6.25 and steps[0]["channels"] == ["q", "a_x", "p"]
    assert done.meta["aircraft"] == "test"
    # written to the run file and read back, the record still reproduces the processing
    path = done.to_csv(tmp_path / "processed.csv")
    again = replay(raw, processing_steps(read_run(path)))
    for name in done.channels:
        np.testing.assert_allclose(again[name], done[name], rtol=0, atol=1e-12, err_msg=name)
    assert not np.allclose(done["q"], raw.slice(1.0, 8.0)["q"])  # smoothing did something


def test_bad_cutoff_and_missing_channel_give_one_line_errors():
    t = np.arange(0, 1, 0.01)
    run = Run(t, {"q": np.sin(t)}, source="r.csv")
    for bad in (60.0, 0.0, -1.0, float("nan")):
        with pytest.raises(RunError) as err:
            smooth(run, bad)
        assert "r.csv" in str(err.value) and "Nyquist" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(RunError, match="missing channel"):
        smooth(run, 5.0, channels=["p"])
