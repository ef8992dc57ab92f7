"""Baseline signals, their spectra and the signal file forms."""
import numpy as np
import pytest
from scipy.optimize import brentq

from identify import read_run
from signaldesign.phases import relative_peak_factor
from signaldesign.baselines import (doublet, m3211, make_signal, multisine, multistep, orthogonal_multisines,
                                    prts, step_sequence)
from signaldesign.signal import SignalError, load_signals, save_signals, signals_to_run
from signaldesign.spectrum import energy, energy_spectrum, half_power_band, in_band_fraction


def _doublet_band_analytic(width):
    """Doublet |U|^2 ~ sin(x)^4 / x^2 with x = w h / 2: peak where tan x = 2x, half power by root finding."""
    f = lambda x: np.sin(x) ** 4 / x ** 2  # noqa: E731
    x_peak = brentq(lambda x: np.tan(x) - 2 * x, 0.5, 1.5)
    half = f(x_peak) / 2
    x_lo = brentq(lambda x: f(x) - half, 1e-6, x_peak)
    x_hi = brentq(lambda x: f(x) - half, x_peak, np.pi - 1e-9)
    return 2 * x_lo / width, 2 * x_hi / width, 2 * x_peak / width


@pytest.mark.parametrize("width", [0.5, 1.0, 2.0])
def test_doublet_half_power_band_matches_the_analytic_value(width):
    lo, hi, peak = half_power_band(doublet(width, 0.02))
    a_lo, a_hi, a_peak = _doublet_band_analytic(width)
    assert lo == pytest.approx(a_lo, rel=1e-8)
    assert hi == pytest.approx(a_hi, rel=1e-8)
    assert peak == pytest.approx(a_peak, rel=1e-6)
    # the textbook figures: the doublet's band is about 1.14/h .. 3.65/h rad/s
    assert lo * width == pytest.approx(1.1443, abs=1e-3) and hi * width == pytest.approx(3.6533, abs=1e-3)


def _fft_spectrum(signal, omega, fs=2000.0, pad=2 ** 21):
    """|U(w)|^2 from a finely sampled signal's FFT: independent of the closed form."""
    t = (np.arange(int(round(signal.end_time * fs))) + 0.5) / fs
    U = np.fft.rfft(signal(t), n=pad) / fs
    w = 2 * np.pi * np.fft.rfftfreq(pad, 1 / fs)
    return np.interp(omega, w, np.abs(U) ** 2)


def test_3211_half_power_band_matches_the_analytic_spectrum():
    h, A = 0.6, 0.02
    s = m3211(h, A)
    lo, hi, peak = half_power_band(s)

    # closed form written out by hand: pulses +3h, -2h, +h, -h
    def P(w):
        x = np.exp(-1j * w * h)
        U = A * (1 - x) / (1j * w) * (1 + x + x ** 2 - x ** 3 - x ** 4 + x ** 5 - x ** 6)
        return np.abs(U) ** 2

    assert P(lo) == pytest.approx(P(peak) / 2, rel=1e-7)
    assert P(hi) == pytest.approx(P(peak) / 2, rel=1e-7)
    w = np.linspace(0.05, 12, 400)
    assert np.all(P(w) <= P(peak) * (1 + 1e-9))
    np.testing.assert_allclose(energy_spectrum(s, w), P(w), rtol=1e-9)
    np.testing.assert_allclose(_fft_spectrum(s, w), P(w), rtol=2e-3, atol=1e-6 * P(peak))
    assert 0.2 < lo * h < 0.4 and 2.5 < hi * h < 3.5  # wider than a doublet of the same pulse width


def test_spectrum_scales_with_width_and_parseval_holds():
    a, b = m3211(0.5), m3211(1.0)
    np.testing.assert_allclose(np.array(half_power_band(a)), 2 * np.array(half_power_band(b)), rtol=1e-7)
    for s in (doublet(0.7, 0.03), m3211(0.4), prts(7.0), multisine(7.0, (0.5, 4.0))):
        assert in_band_fraction(s, (0.0, 100 * 2 * np.pi / s.dt), points=100001) == pytest.approx(1.0, abs=3e-3)
    assert energy(doublet(0.7, 0.03)) == pytest.approx(2 * 0.7 * 0.03 ** 2)


def test_multistep_doublet_and_sequences():
    assert m3211(0.5).levels.tolist() == [1, 1, 1, -1, -1, 1, -1]
    assert doublet(1.0).levels.tolist() == [1, -1]
    s = multistep((2, 1, 1), 0.3, first=-1)
    assert s.levels.tolist() == [-1, -1, 1, -1] and s.duration == pytest.approx(1.2)
    assert make_signal("2121", width=0.4).levels.tolist() == [1, 1, -1, 1, 1, -1]
    assert step_sequence([1, 0, -1], 0.5).duration == pytest.approx(1.5)
    with pytest.raises(SignalError, match="width"):
        make_signal("3211")
    with pytest.raises(SignalError, match="pulse width must be positive"):
        doublet(0.0)
    with pytest.raises(SignalError, match="unknown signal kind"):
        make_signal("sawtooth", width=1)


def test_prts_is_a_maximal_ternary_sequence():
    for order in (2, 3, 4):
        s = prts(7.0, order)
        L = 3 ** order - 1
        assert s.levels.size == L and s.duration == pytest.approx(7.0)
        # an m-sequence over GF(3) holds 3^(n-1) of each non-zero symbol and one zero fewer
        assert np.sum(s.levels == 1) == np.sum(s.levels == -1) == 3 ** (order - 1)
        x = s.levels
        # two-level periodic autocorrelation of the +/-1/0 mapping: zero at every non-zero lag
        # except the half period, where the sequence is its own negative
        ac = np.array([x @ np.roll(x, k) for k in range(L)])
        assert ac[0] == 2 * 3 ** (order - 1)
        assert ac[L // 2] == -ac[0]
        assert np.all(ac[[k for k in range(1, L) if k != L // 2]] == 0)


def test_multisines_are_in_band_and_orthogonal():
    s = multisine(10.0, (0.5, 4.0), 0.05, dt=0.02)
    w0 = 2 * np.pi / 10
    h = np.array(s.params["harmonics"])
    assert np.all(h * w0 >= 0.5) and np.all(h * w0 <= 4.0) and h.size == 6
    assert np.abs(s.levels).max() == pytest.approx(1.0)
    a, b = orthogonal_multisines(["theta_s", "theta_c"], 10.0, (0.5, 4.0), 0.02, dt=0.01)
    assert set(a.params["harmonics"]).isdisjoint(b.params["harmonics"])
    assert abs(a.levels @ b.levels) < 1e-2 * np.linalg.norm(a.levels) * np.linalg.norm(b.levels)
    with pytest.raises(SignalError, match="no harmonic"):
        multisine(2.0, (0.1, 0.5))


def test_signal_json_and_run_csv_round_trip(tmp_path):
    sigs = [m3211(0.6, 0.02, "theta_s"), prts(5.2, 3, 0.01, "theta_c")]
    path = save_signals(sigs, tmp_path / "sig.json")
    back = load_signals(path)
    assert [s.kind for s in back] == ["3211", "prts"]
    np.testing.assert_array_equal(back[0].levels, sigs[0].levels)
    assert back[1].dt == pytest.approx(sigs[1].dt) and back[1].amplitude == 0.01
    run = signals_to_run(back, 0.01, 8.0)
    run.to_csv(tmp_path / "sig.csv")
    again = read_run(tmp_path / "sig.csv")
    np.testing.assert_allclose(again["theta_s"], sigs[0](again.time))
    assert again["theta_s"][0] == 0.02 and again["theta_s"][-1] == 0.0


def test_a_signal_with_a_nan_delay_is_rejected():
    import pytest

    from signaldesign.signal import Signal, SignalError
    with pytest.raises(SignalError, match="delay"):
        Signal("doublet", "theta_s", 1.0, [1, -1], delay=float("nan"))


@pytest.mark.parametrize("low", [0.5, 0.63, 1.0])
def test_optimised_multisines_have_a_small_relative_peak_factor(low):
    """Two orthogonal multisines over a decade of band in 10 s: each input's relative peak factor
    (max - min) / (2 sqrt(2) rms) at most 1.15 and below Schroeder's phases' (Morelli's target)."""
    band = (low, 10 * low)
    opt = orthogonal_multisines(["theta_s", "theta_c"], 10.0, band, dt=0.05)
    sch = orthogonal_multisines(["theta_s", "theta_c"], 10.0, band, dt=0.05, phases="schroeder")
    for o, s in zip(opt, sch):
        assert o.params["harmonics"] == s.params["harmonics"] and len(o.params["harmonics"]) >= 3
        rpf = relative_peak_factor(o.levels)
        assert rpf == pytest.approx(o.params["relative_peak_factor"])
        assert rpf <= 1.15 and rpf < relative_peak_factor(s.levels) - 0.05
        # the same power in every harmonic: the phases changed, the spectrum did not
        spec = np.abs(np.fft.rfft(o.levels))[o.params["harmonics"]]
        assert np.ptp(spec) < 1e-6 * spec.max()
    assert abs(opt[0].levels @ opt[1].levels) < 1e-9 * np.linalg.norm(opt[0].levels) * np.linalg.norm(opt[1].levels)
    with pytest.raises(SignalError, match="phases"):
        multisine(10.0, band, phases="random")
