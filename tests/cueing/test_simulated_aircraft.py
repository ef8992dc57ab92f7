"""The simulated aircraft is the model: every declared effect flown (delays, pseudo-inputs), by
the test point after the flight and the live source alike; --truth / --perturb fly another aircraft."""
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from cueing.response import SimulatedAircraft, simulate_profile
from identify import ML, LinearModel, load_profile, parse_profile, read_run
from signaldesign.baselines import m3211

ROOT = Path(__file__).resolve().parents[2]
S61 = (ROOT / "profiles" / "s61_hover_4dof.toml").read_text()


def _delayed(tmp_path, extra=""):
    path = tmp_path / "delayed.toml"
    path.write_text(S61.replace("[meta]\n", f"[meta]\ndelays = {{ theta_s = 0.08 }}\n{extra}"))
    return path


def _fly(tmp_path, *options):
    env = dict(os.environ, PYTHONPATH=str(ROOT), SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy",
               OPENBLAS_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "cueing", "fly", "--signal", str(ROOT / "examples" / "sig.json"), "--source", "pilot",
           "--headless", "--fast", "--noise", "0.02", "--seed", "3", "--out", str(tmp_path / "run.csv"), *options]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return read_run(tmp_path / "run.csv"), proc.stdout


def _noise_ratios(profile, run) -> dict:
    """Each output's ML residual RMS over the simulation's measurement noise (2 % of its std)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # theta_c is not flown: its derivatives held, said
        result = ML(profile).fit([run]).result_
    return {y: result.fit[y]["rms"] / (0.02 * np.std(run[y])) for y in result.fit}


def test_declared_delay_is_flown_ml_with_it_fits_at_noise_level(tmp_path):
    delayed = _delayed(tmp_path)
    run, _ = _fly(tmp_path, "--simulate", str(delayed))
    with_delay, without = _noise_ratios(str(delayed), run), _noise_ratios("s61_hover_4dof", run)
    assert max(with_delay.values()) < 1.15, with_delay  # white noise of the injected level is all that is left
    assert max(without.values()) > 2.0, without  # the undeclared delay leaves structure


def test_live_source_steps_the_same_aircraft(tmp_path):
    """Frame by frame, with a delay and pseudo-inputs (a constant and a state product fed back),
    the live source reaches the test point's states."""
    extra = 'pseudo_inputs = { one = { constant = 1.0 }, qq = { product = ["q", "theta_s"] } }\n'
    text = _delayed(tmp_path, extra).read_text()
    text = text.replace('inputs = { theta_s = "rad", theta_c = "rad" }',
                        'inputs = { theta_s = "rad", theta_c = "rad", one = "-", qq = "-" }')
    text = text.replace("[fixed]\n", "[fixed]\nM_one = 0.001\nM_qq = -2.0\n")
    model = LinearModel(parse_profile(text))
    sig = m3211(0.8, 0.01, "theta_s", 1.0)
    t = np.arange(0, 8, 1 / 60)
    aircraft = SimulatedAircraft(model, [sig], 60.0, noise_fraction=0.0)
    live = np.array([aircraft.read(tk, [sig(tk)]) for tk in t])
    u = np.zeros((t.size, model.n_inputs))
    u[:, 0] = sig(t)
    run = simulate_profile(model, t, u, derivatives=False)
    after = run.matrix(model.profile.state_names)
    assert "one" not in run.channels and np.array_equal(run["theta_s"], u[:, 0])  # flown input, undelayed
    # the same aircraft to 0.1 % (0.08 s is 4.8 frames: the live source holds the delayed stick
    # exactly, the whole run interpolates it between samples; the state product is held over
    # sub-intervals there, over samples here); without the declared effects it differs by > 5 %
    assert np.abs(live - after).max() < 1e-3 * np.abs(after).max()
    plain = simulate_profile(LinearModel(load_profile("s61_hover_4dof")), t, u[:, :2], derivatives=False)
    assert np.abs(plain.matrix(model.profile.state_names) - after).max() > 0.05 * np.abs(after).max()


def test_perturb_flies_another_aircraft_and_says_which(tmp_path):
    run, out = _fly(tmp_path, "--simulate", "s61_hover_4dof", "--perturb", "0.2")
    truth = load_profile(tmp_path / "run.truth.toml")
    apriori = load_profile("s61_hover_4dof")
    ratio = np.array([truth.free[n] / apriori.free[n] for n in apriori.free])
    assert "run.truth.toml" in out and np.all(np.abs(ratio - 1) <= 0.2 + 1e-12) and np.ptp(ratio) > 0.1
    with_truth, with_apriori = _noise_ratios(str(tmp_path / "run.truth.toml"), run), _noise_ratios("s61_hover_4dof", run)
    assert max(with_truth.values()) < 1.15 and max(with_apriori.values()) < 1.15  # ML re-estimates; both fit
    fitted = ML("s61_hover_4dof")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fitted.fit([run]).result_
    i = res.names.index("M_theta_s")  # flown on theta_s: its control derivative is the truth's, not the a priori
    assert abs(res.theta[i] - truth.free["M_theta_s"]) < 3 * res.std[i]


def test_implausible_amplitude_is_said_before_flying(tmp_path):
    from signaldesign.signal import save_signals
    save_signals(m3211(0.5, 1.38, "theta_c", 1.0), tmp_path / "big.json")
    env = dict(os.environ, PYTHONPATH=str(ROOT), SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy")
    proc = subprocess.run([sys.executable, "-m", "cueing", "fly", "--signal", str(tmp_path / "big.json"), "--source",
                           "pilot", "--headless", "--fast", "--simulate", "bo105_70kt", "--record", "6",
                           "--out", str(tmp_path / "big.csv")], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0 and "amplitude 79.1 deg on theta_c is implausible" in proc.stderr
