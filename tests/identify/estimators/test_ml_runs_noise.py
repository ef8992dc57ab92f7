"""ML's coloured bounds when the runs' residuals differ in size (each run its own autocorrelation)."""
import warnings

import numpy as np

from identify import ML, LinearModel, load_profile, simulate_run
from signaldesign.baselines import step_sequence

E_LEVELS = (1, 0, 1, 1, -1, 0, 0, -1, 1, 0, -1, -1, 0)


def _runs(truth, seed):
    # noise 3 % of each channel's std in *its* run: the axis not flown has far less noise in the
    # run that does not move it, as residuals that scale with the response would have
    t = np.arange(141) * 0.05
    runs = []
    for k, axis in enumerate(truth.profile.input_names):
        u = np.zeros((len(t), truth.n_inputs))
        u[:, k] = step_sequence(E_LEVELS, 0.5, np.deg2rad(0.5), axis, 0.5)(t)
        runs.append(simulate_run(truth, t, u, noise_fraction=0.03, seed=1000 * seed + k))
    return runs


def test_bounds_follow_the_spread_when_the_runs_noise_differs():
    prof = load_profile("s61_hover_4dof")
    truth = LinearModel(prof)
    est, std = [], []
    for i in range(30):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = ML(prof).fit(_runs(truth, i)).result_
        est.append(r.theta)
        std.append(r.std)
    ratio = np.std(np.array(est), axis=0) / np.median(np.array(std), axis=0)
    assert np.sqrt(np.mean(np.log(ratio) ** 2)) < 0.3
