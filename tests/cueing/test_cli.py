"""cueing command line: crash safety under SIGKILL, error lines, a simulated test point that ML
identifies, practice and history."""
import os
import signal as sig
import subprocess
import sys
import time

import numpy as np
import pytest

from cueing.cli import main
from cueing.flightlog import read_frame_log
from identify import ML, LinearModel, load_profile, read_run
from signaldesign import Signal, save_signals
from tests.helpers import ROOT, one_error_line, run_cli

AMP = 0.02


@pytest.fixture
def sig_file(tmp_path):
    return save_signals(Signal("3211", "theta_s", 1.0, [1, 1, 1, -1, -1, 1, -1], AMP, delay=0.5),
                        tmp_path / "sig.json")


@pytest.fixture
def two_axis_file(tmp_path):
    return save_signals([Signal("3211", "theta_s", 1.0, [1, 1, 1, -1, -1, 1, -1], AMP, delay=0.5),
                         Signal("3211", "theta_c", 1.0, [-1, -1, -1, 1, 1, -1, 1], AMP, delay=2.0)],
                        tmp_path / "two.json")


def _flying(sig_file, tmp_path):
    """``cueing fly`` (off-screen display, simulated pilot) in a process, once its frame log holds
    frames and 1.5 s more have passed: (process, frame log path, run file path)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy")
    out = tmp_path / "run.csv"
    log_path = tmp_path / "run.frames.csv"
    proc = subprocess.Popen([sys.executable, "-m", "cueing", "fly", "--signal", str(sig_file), "--source", "pilot",
                             "--headless", "--countdown", "0.5", "--out", str(out)], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 60
    while time.time() < deadline and not (log_path.is_file() and log_path.stat().st_size > 2000):
        time.sleep(0.02)
    if not log_path.is_file():
        proc.kill()
        pytest.fail("the frame log never appeared")
    time.sleep(1.5)
    return proc, log_path, out


def test_sigterm_ends_the_run_marked_terminated(sig_file, tmp_path):
    """The off-screen display starts SDL, which takes SIGTERM if nobody holds it and turns it into
    a quit event: the run then ended as 'window closed'. It must say what happened and exit 143."""
    proc, log_path, out = _flying(sig_file, tmp_path)
    try:
        proc.send_signal(sig.SIGTERM)
        proc.wait(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 128 + sig.SIGTERM
    assert "terminated (signal 15)" in proc.stderr.read().decode()
    log = read_frame_log(log_path)
    assert log.aborted and log.status == "aborted (terminated: SIGTERM)"
    assert log.time[-1] > 1.0 and not out.exists()


def test_sigkill_leaves_a_readable_log_missing_at_most_0_2_s(sig_file, tmp_path):
    proc, log_path, out = _flying(sig_file, tmp_path)
    try:
        killed_at = time.time()
        proc.send_signal(sig.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == -sig.SIGKILL
    log = read_frame_log(log_path)
    assert log.aborted and "killed" in log.status
    last = float(log.meta["clock_epoch_unix"]) + log.time[-1]  # unix time of the last logged frame
    # (a frame may still start between reading the clock and the signal landing: hence -0.05)
    assert -0.05 <= killed_at - last <= 0.2, killed_at - last
    assert log.time[-1] > 1.0 and not out.exists()
    # the partial log still becomes a run file, marked aborted
    print(f"killed {killed_at - last:.4f} s after the last logged frame, {log.time[-1]:.2f} s into the run")
    assert main(["recover", str(log_path), "--out", str(tmp_path / "partial.csv")]) == 0
    run = read_run(tmp_path / "partial.csv", require=["theta_s", "theta_s_cmd"])
    assert run.meta["status"].startswith("aborted") and run.duration > 1.0


def test_no_joystick_gives_one_line_and_status_2(sig_file, tmp_path):
    one_error_line(run_cli("cueing", "fly", "--signal", sig_file, "--source", "joystick", "--headless",
                           "--out", tmp_path / "x.csv"), "no joystick")
    assert not (tmp_path / "x.frames.csv").exists()


@pytest.mark.parametrize("args, needle", [
    (["--signal", "{tmp}/missing.json"], "missing.json"),
    (["--signal", "{sig}", "--source", "wand"], "unknown source 'wand'"),
    (["--signal", "{sig}", "--source", "replay:{tmp}/none.csv"], "no such run file"),
    (["--signal", "{sig}", "--source", "pilot", "--skill", "1.5"], "--skill"),
    (["--signal", "{sig}", "--rate", "0"], "--rate"),
    (["--signal", "{sig}", "--source", "joystick", "--axes", "one"], "--axes"),
    (["--signal", "{sig}", "--source", "pilot", "--noise", "-1"], "--noise"),
    (["--signal", "{sig}", "--source", "pilot", "--screenshot-every", "-1"], "--screenshot-every"),
    (["--signal", "{sig}", "--source", "external:math:pi"], "not a function"),
    (["--signal", "{sig}", "--source", "external:os.path:join", "--fast", "--countdown", "0"], "external source"),
])
def test_bad_input_gives_one_line_and_status_2(args, needle, sig_file, tmp_path, capsys):
    argv = ["fly", "--headless", "--out", str(tmp_path / "x.csv")] + [
        a.format(tmp=tmp_path, sig=sig_file) for a in args]
    assert main(argv) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(err) == 1 and needle in err[0] and err[0].startswith("cueing: error:"), err


def test_option_errors_are_one_line(sig_file, tmp_path, capsys):
    assert main(["fly", "--signal", str(sig_file), "--source", "mouse", "--fast", "--headless",
                 "--out", str(tmp_path / "x.csv")]) == 2
    rudder = save_signals(Signal("doublet", "delta_r", 1.0, [1, -1], AMP), tmp_path / "rudder.json")
    assert main(["fly", "--signal", str(rudder), "--source", "pilot", "--fast", "--headless", "--countdown", "0",
                 "--simulate", "s61_hover_4dof", "--out", str(tmp_path / "x.csv")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(err) == 2 and "--fast" in err[0] and "has no input delta_r" in err[1]


def test_simulated_test_point_loads_in_identify_and_ml_converges(two_axis_file, tmp_path):
    out = tmp_path / "tp.csv"
    proc = run_cli("cueing", "fly", "--signal", two_axis_file, "--source", "pilot", "--seed", "3", "--headless",
                   "--fast", "--countdown", "0", "--tail", "3", "--simulate", "s61_hover_4dof",
                   "--noise", "0.02", "--out", out)
    assert proc.returncode == 0, proc.stderr
    truth = LinearModel(load_profile("s61_hover_4dof"))
    run = read_run(out, require=truth.profile.channels + ["theta_s_cmd", "theta_c_cmd"])
    assert run.meta["status"] == "completed" and "pilot model" in run.meta["source"]
    # flown, not designed: the pilot's input differs from the command
    assert np.sqrt(np.mean((run["theta_s"] - run["theta_s_cmd"]) ** 2)) > 0.1 * AMP
    # start 30 % off the truth in every free derivative
    start = truth.profile.with_values({n: 1.3 * v for n, v in truth.parameters().items()
                                       if n in truth.names}, name="perturbed")
    ml = ML(start).fit(run)
    info = ml.result_.info
    assert info["converged"], info["stop"]
    err = np.abs(ml.theta_ - truth.theta)
    well = ml.std_ < 0.1 * np.abs(truth.theta)  # the parameters this test point determines well
    assert well.sum() >= 10
    assert np.all(err[well] < 4 * ml.std_[well]), dict(zip(np.array(truth.names)[well], (err / ml.std_)[well]))


def test_practice_improves_and_history_shows_the_learning_curve(sig_file, tmp_path, capsys):
    hist = tmp_path / "hist"
    code = main(["practice", "--signal", str(sig_file), "--source", "pilot", "--pilot", "Rix", "--attempts", "4",
                 "--skill", "0", "--learn", "0.6", "--seed", "11", "--headless", "--fast", "--countdown", "0",
                 "--profile", "s61_hover_4dof", "--history-dir", str(hist), "--out-dir", str(tmp_path / "p")])
    assert code == 0
    records = [r for r in map(__import__("json").loads, (hist / "Rix.jsonl").read_text().splitlines())]
    assert len(records) == 4 and all(r["status"] == "completed" for r in records)
    rms = [r["rms"] for r in records]
    timing = [r["timing_mean"] for r in records]
    assert rms[-1] < rms[0] and timing[-1] < timing[0]
    assert all(0 < r["d_efficiency"] < 2 for r in records)
    assert len(list((tmp_path / "p").glob("Rix_attempt??.csv"))) == 4
    capsys.readouterr()
    assert main(["history", "Rix", "--history-dir", str(hist), "--plot", str(tmp_path / "c.png")]) == 0
    printed = capsys.readouterr().out
    assert printed.count("\n") >= 5 and (tmp_path / "c.png").stat().st_size > 1000
    assert main(["history", "Nobody", "--history-dir", str(hist)]) == 2
