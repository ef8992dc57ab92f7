"""All axes in one run: a simultaneous two-axis run (orthogonal multisines, both cyclics at once)
is taken as it is by the live estimate and by ML, with no per-axis split."""
import numpy as np

from cueing.live.estimate import LiveIdentification
from cueing.response import SimulatedAircraft
from identify import ML, LinearModel, load_profile, simulate_run
from signaldesign.baselines import orthogonal_multisines
from signaldesign.evaluate import Evaluator, record_inputs

PROFILE = "s61_hover_4dof"


def simultaneous():
    return orthogonal_multisines(["theta_s", "theta_c"], 10.0, (0.4, 4.0), 0.01, dt=0.05, delay=1.0)


def test_live_estimate_takes_both_axes_at_once(tmp_path):
    sigs = simultaneous()
    aircraft = SimulatedAircraft(LinearModel(load_profile(PROFILE)), sigs, 60.0, seed=1)
    live = LiveIdentification(load_profile(PROFILE), sigs, aircraft, tmp_path / "run.live.csv")
    for k in range(60 * 14):  # 14 s at 60 Hz, the sticks flown exactly
        t = k / 60
        live.update(k, t, t, np.array([s(t) for s in sigs]), False)
    live.close()
    assert live.latest is not None and not live.latest.errors
    idx = [live.names.index(n) for n in live.targets]
    assert {"M_theta_s", "L_theta_c"} <= set(live.targets)  # both axes' control derivatives
    truth = dict(zip(LinearModel(load_profile(PROFILE)).names, LinearModel(load_profile(PROFILE)).theta))
    z = (live.latest.theta[idx] - np.array([truth[n] for n in live.targets])) / live.latest.std[idx]
    assert np.all(np.isfinite(z)) and np.all(np.abs(z) < 4), dict(zip(live.targets, z.round(2)))


def test_ml_takes_both_axes_at_once():
    model = LinearModel(load_profile(PROFILE))
    sigs = simultaneous()
    ev = Evaluator(model, ["theta_s", "theta_c"], 15.0, 0.05)
    u = record_inputs(model, sigs, 15.0, 0.05)
    assert np.all(np.abs(u).max(axis=0) > 0)  # both inputs move in the same run
    t = np.arange(u.shape[0]) * 0.05
    run = simulate_run(model, t, u, noise=dict(zip(model.profile.outputs, ev.noise_std)), seed=3)
    fit = ML(model.profile, segment="plain", estimate_x0=True, estimate_bias=False,
             noise_cov=ev.noise_std ** 2, coloured=False).fit(run)
    z = (fit.theta_ - model.theta) / fit.result_.std
    assert np.all(np.isfinite(fit.result_.std)) and np.all(np.abs(z) < 4.5), dict(zip(model.names, z.round(2)))
