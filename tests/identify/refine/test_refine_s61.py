"""The S 61 case of the paper: data from the 8-state model with rotor tip-path-plane states, declared
model the 4-DOF rigid body. The refinement must find the unmodelled rotor dynamics as a lag or
delay on a cyclic input and reduce the error on the fit and on the validation run."""
import numpy as np

from identify import LinearModel, load_profile, simulate_run
from identify.refine import Refine

DT, T = 0.05, 10.0


def _cyclics(seed: int, n: int) -> np.ndarray:
    """Random three-level steps of 0.5 s on both cyclics (theta_s, theta_c), 0.01 rad."""
    rng = np.random.default_rng(seed)
    k = int(0.5 / DT)
    u = np.repeat(rng.choice([-1.0, 0.0, 1.0], size=(n // k + 1, 2)), k, axis=0)[:n] * 0.01
    u[:k] = 0.0
    return u


def test_s61_rotor_dynamics_found_as_lag_or_delay(s61):
    t = np.arange(int(T / DT) + 1) * DT
    runs = [simulate_run(s61, t, _cyclics(s, len(t)), noise_fraction=0.02, seed=s) for s in (1, 2, 3)]
    declared = load_profile("s61_hover_4dof")
    r = Refine(declared, kinds=("derivative", "delay", "lag"), max_steps=1).fit(runs[:2], validate=runs[2:])
    assert r.steps_, [s.to_dict() for s in r.rejected_]
    step = r.steps_[0]
    assert step.effect in ("lag", "delay") and step.target in ("theta_s", "theta_c"), step.to_dict()
    # the rotor's flapping time constant in the truth is 0.1 s (k = 10 1/s)
    value = next(iter(step.parameters.values()))["value"]
    tau = 1 / value if step.effect == "lag" else value
    assert 0.05 < tau < 0.2, step.parameters
    for where in ("fit", "validation"):
        assert r.error_after_[where]["overall"] < 0.9 * r.error_before_[where]["overall"], \
            (where, r.error_before_[where], r.error_after_[where])
