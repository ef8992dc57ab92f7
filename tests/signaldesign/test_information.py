import numpy as np
import pytest

from signaldesign.information import cramer_rao_std, d_efficiency, fisher_information, log_det


def test_information_grows_with_amplitude_squared(s61):
    dt = 0.05
    u = np.zeros((201, 2))
    u[10:50, 0], u[50:90, 0] = 0.01, -0.01
    u[20:60, 1] = 0.01
    M1 = fisher_information(s61, u, dt)
    M2 = fisher_information(s61, 2 * u, dt)
    np.testing.assert_allclose(M2, 4 * M1, rtol=1e-9)
    assert d_efficiency(M2, M1) == pytest.approx(4.0, rel=1e-9)
    assert np.all(np.isfinite(cramer_rao_std(M1)))


def test_unexcited_parameters_make_the_information_singular(s61):
    u = np.zeros((201, 2))
    u[10:50, 0] = 0.01  # lateral cyclic never moves: phi_R_theta_c cannot be seen
    M = fisher_information(s61, u, 0.05)
    i = s61.names.index("phi_R_theta_c")
    assert M[i, i] == 0.0 and log_det(M) == -np.inf
