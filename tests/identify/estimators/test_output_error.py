"""The segmented output-error engine shared by ML and IV's instruments."""
import numpy as np

from identify.estimators.output_error import restarts, simulate_segments
from identify.model.simulate import discretize, propagate


def test_engine_simulates_restarted_segments_together(s61):
    """simulate_segments (IV's instruments) runs all segments in one recursion; each segment equals
    its own simulation from its start state, including the shorter last one."""
    rng = np.random.default_rng(4)
    N, dt = 503, 0.01
    Phi, Gamma = discretize(s61.A, s61.B, dt)
    forcing = rng.standard_normal((N, s61.n_inputs)) @ Gamma.T
    lay = restarts(N, dt, 1.0)
    assert list(lay.length) == [100] * 5 + [3]
    starts = rng.standard_normal((lay.n_segments, s61.n_states))
    x = simulate_segments(Phi, forcing, starts, lay)
    for s, (a, n_s) in enumerate(zip(lay.start, lay.length)):
        np.testing.assert_allclose(x[a:a + n_s], propagate(Phi, forcing[a:a + n_s], starts[s]), rtol=1e-12, atol=1e-12)
    assert restarts(N, dt, None).n_segments == 1
