"""The required frequency band from an a priori model's output sensitivities."""
import numpy as np
import pytest

from identify import LinearModel, load_profile
from signaldesign.band import BandError, frequency_sensitivities, plot_band, required_band


def _transfer(model, omega, j):
    n = model.n_states
    return np.array([model.C @ np.linalg.solve(1j * w * np.eye(n) - model.A, model.B[:, j]) + model.D[:, j]
                     for w in omega])


def test_frequency_sensitivities_are_derivatives_of_the_transfer_function(s61):
    omega = np.array([0.1, 0.36, 0.5, 2.0, 9.0])
    sigma = np.linspace(0.5, 2.0, s61.n_outputs)
    s = frequency_sensitivities(s61, "theta_s", omega, sigma)
    for i in (0, 3, 8, 14):
        eps = 1e-6 * abs(s61.theta[i])
        up, dn = s61.theta.copy(), s61.theta.copy()
        up[i] += eps
        dn[i] -= eps
        dG = (_transfer(s61.with_theta(up), omega, 0) - _transfer(s61.with_theta(dn), omega, 0)) / (2 * eps)
        expected = np.sqrt(np.sum(np.abs(s61.theta[i] * dG / sigma) ** 2, axis=1))
        np.testing.assert_allclose(s[:, i], expected, rtol=1e-5)


def test_s61_band_is_driven_by_its_unstable_modes(s61):
    band = required_band(s61, "theta_s")
    unstable = [m.frequency for m in s61.modes() if not m.stable]
    assert len(unstable) == 2
    for w in unstable:  # 0.36 and 0.50 rad/s
        assert band.low <= w <= band.high
    assert 0.15 < band.low < 0.3 and 0.5 < band.high < 0.7
    assert all(any(abs(m.frequency - w) < 1e-9 for m in band.modes) for w in unstable)
    # the lateral cyclic derivatives cannot be seen through longitudinal cyclic alone
    assert set(band.unexcited) == {"theta_R_theta_c", "phi_R_theta_c"}
    for b in band.parameters:
        assert b.low <= b.peak <= b.high and band.low <= b.low and b.high <= band.high
    text = band.format()
    assert "0.360 rad/s" in text and "UNSTABLE" in text


def test_band_level_widens_the_band(s61):
    narrow, wide = required_band(s61, "theta_s", 0.7), required_band(s61, "theta_s", 0.3)
    assert wide.low < narrow.low and wide.high > narrow.high


def test_band_errors_and_plot(s61, tmp_path):
    with pytest.raises(BandError, match="no input 'theta_x'"):
        required_band(s61, "theta_x")
    with pytest.raises(BandError, match="between 0 and 1"):
        required_band(s61, "theta_s", level=1.5)
    bo = LinearModel(load_profile("bo105_70kt"))
    band = required_band(bo, "theta_c")
    assert "M_theta_s" in band.unexcited and band.low < band.high
    plot_band(band, tmp_path / "band.png")
    assert (tmp_path / "band.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_open_ends_are_the_grid_not_a_band():
    """BO 105 lateral: several sensitivities still rise at the grid's lowest frequency; the band is
    where the others close, and the open ones are named, never reported as 0.01..100 rad/s."""
    from identify import LinearModel, load_profile
    from signaldesign.band import required_band
    band = required_band(LinearModel(load_profile("bo105_70kt")), "theta_c")
    assert band.bounded and band.omega[0] < band.low < band.high < band.omega[-1]
    assert any(p.open_low for p in band.parameters) and "open below 0.01 rad/s" in band.format()
    assert all(f"<{p.low:.3f}" in p.text for p in band.parameters if p.open_low)


def test_implausible_control_amplitude_is_said():
    from identify import load_profile
    from signaldesign.design import implausible_amplitudes
    p = load_profile("bo105_70kt")
    assert implausible_amplitudes(p, ["theta_c"], [np.radians(5.0)]) == []
    (line,) = implausible_amplitudes(p, ["theta_c"], [np.radians(79.0)])
    assert "79.0 deg on theta_c is implausible" in line
