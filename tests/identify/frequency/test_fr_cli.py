"""--method fr, VERIFY, identify hq and identify loes from the command line on simulated S 61 runs."""
import json

import numpy as np
import pytest
from scipy.signal import chirp

from identify import LinearModel, load_profile, perturbed_model, simulate_run
from identify.estimators.frequency.response_fit import FR
from identify.estimators.frequency.verify import verify
from signaldesign.baselines import m3211

from tests.helpers import one_error_line, run_cli

DT = 0.02
DEG = np.pi / 180
NOISE = {"u": 0.05, "v": 0.05, "p": 0.05 * DEG, "q": 0.05 * DEG, "theta": 0.05 * DEG, "phi": 0.05 * DEG}


def sweep_run(truth, t, axis: int, seed: int):
    """A 0.2 deg logarithmic sweep, 0.1-2 Hz, on input ``axis`` of the S 61 4-DOF (the other held)."""
    U = np.zeros((len(t), 2))
    U[:, axis] = np.deg2rad(0.2) * chirp(t, 0.1, t[-1], 2.0, method="logarithmic", phi=-90)
    return simulate_run(truth, t, U, noise=NOISE, seed=seed)


@pytest.fixture(scope="module")
def flights():
    """A 'real' S 61 (the a priori 30 % off), a sweep and a 3211 per axis, and a held-out run of
    3211s of other widths on both axes."""
    p = load_profile("s61_hover_4dof")
    truth = perturbed_model(LinearModel(p), 0.3, np.random.default_rng(4))
    t = np.arange(0, 20, DT)
    sweeps = []
    for j in range(2):
        sweeps.append(sweep_run(truth, t, j, seed=j))
        U = np.zeros((len(t), 2))
        U[:, j] = m3211(1.0, np.deg2rad(0.3), p.input_names[j], delay=1.0)(t)
        sweeps.append(simulate_run(truth, t, U, noise=NOISE, seed=20 + j))
    U = np.column_stack([m3211(1.0, np.deg2rad(0.2), "theta_s", delay=1.0)(t),
                         m3211(0.7, np.deg2rad(0.2), "theta_c", delay=9.0)(t)])
    held_out = simulate_run(truth, t, U, noise=NOISE, seed=9)
    return p, truth, sweeps, held_out


def test_fr_model_verifies_on_a_held_out_run(flights):
    p, truth, sweeps, held_out = flights
    # 17 derivatives held 30 % off: the model's time-domain residual is misfit (up to 150x the noise
    # power in the fitted band), not noise, so the residual bootstrap's premise fails; CIFER's gates on
    # J's bound (n_draws=0) are what this test of pruning and VERIFY is about
    fit = FR(p, prune=True, n_draws=0).fit(sweeps).result_
    assert fit.info["frequency_domain"] and fit.converged
    assert all(not a["over_guidelines"] for a in fit.accuracy().values())
    v = verify(fit.model, held_out)
    assert v.j_rms <= 2.0 and v.tic <= 0.3 and v.passes  # Tischler's guidelines
    apriori = verify(LinearModel(p), held_out)
    assert apriori.j_rms > 2 * v.j_rms  # and the check can tell: the a priori predicts far worse
    assert verify(truth, held_out).j_rms < v.j_rms  # the truth better still (17 derivatives held)
    assert len(v.predictions[0].x0) == 6 and len(v.predictions[0].zero_shifts) == 6


def test_cli_fr_verify_hq_loes(flights, tmp_path, capsys):
    from identify.cli import main  # in-process: the subprocess start-up would cost most of the test

    p, truth, sweeps, held_out = flights
    paths = [r.to_csv(tmp_path / f"run{k}.csv") for k, r in enumerate(sweeps[::2])]  # the sweeps only
    val = held_out.to_csv(tmp_path / "val.csv")
    assert main(["estimate", *map(str, paths), "--profile", "s61_hover_4dof", "--method", "fr", "--prune",
                 "--n-draws", "4", "--verify", str(val), "--out", str(tmp_path / "fr")]) == 0
    out = capsys.readouterr().out
    assert "FR identification" in out and "VERIFY" in out and "J_rms" in out
    assert "fixed at a priori" in out and "lowest resolved frequency" in out
    info = json.loads((tmp_path / "fr" / "result.json").read_text())["info"]
    assert info["verify"]["passes"] and info["J_mean"] < 100
    assert info["n_draws"] == 4 and info["standard_errors"].startswith("residual bootstrap, ")  # --n-draws recorded
    assert (tmp_path / "fr" / "verify.png").stat().st_size > 10_000
    assert main(["hq", *map(str, paths), "--profile", "s61_hover_4dof", "--out", str(tmp_path / "hq")]) == 0
    assert "ADS-33 level" in capsys.readouterr().out and (tmp_path / "hq" / "hq_pitch.png").exists()
    assert "| pitch |" in (tmp_path / "hq" / "hq.md").read_text()
    assert main(["loes", *map(str, paths), "--profile", "s61_hover_4dof", "--pair", "p/theta_c", "--num", "0",
                 "--den", "1", "--tau-max", "0.2", "--out", str(tmp_path / "lo")]) == 0
    assert "J = " in capsys.readouterr().out and (tmp_path / "lo" / "loes.png").exists()
    proc = run_cli("identify", "loes", *paths, "--profile", "s61_hover_4dof", "--pair", "r/theta_c", "--out",
                   tmp_path / "x")
    one_error_line(proc, "--pair r/theta_c")
    proc = run_cli("identify", "estimate", *paths, "--profile", "s61_hover_4dof", "--method", "fr", "--n-draws", "2",
                   "--out", tmp_path / "y")
    assert proc.returncode != 0 and "0 or at least 3" in proc.stderr
    proc = run_cli("identify", "estimate", *paths, "--profile", "s61_hover_4dof", "--method", "ml", "--n-draws", "5",
                   "--out", tmp_path / "z")
    one_error_line(proc, "--n-draws does not apply to ml")
