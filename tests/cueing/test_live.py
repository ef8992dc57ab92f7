"""The live estimate in the cockpit: recursive frequency-domain equation error while the simulated
pilot flies, checked against ML on the same run after the flight."""
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from cueing.live import fly_live, parse_targets, read_live_log
from cueing.sources import PilotSource
from identify import LinearModel, load_profile
from signaldesign import save_signals
from signaldesign.baselines import m3211

from tests.helpers import ROOT, one_error_line, run_cli

PROFILE = "s61_hover_4dof"
RATE = 60.0  # the cockpit default; its frame times are not exact decimals (see the last test)


def signals():
    """Both cyclics, staggered 3211s: the pilot flies both needles."""
    return [m3211(0.6, 0.01, "theta_s", delay=1.0), m3211(0.5, 0.01, "theta_c", delay=6.0)]


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    out = tmp_path_factory.mktemp("live") / "run.csv"
    apriori = LinearModel(load_profile(PROFILE))
    # the aircraft differs from the a priori model: the live estimate must find it, not echo it
    truth = apriori.with_theta(apriori.theta * np.random.default_rng(5).uniform(0.85, 1.15, apriori.theta.size))
    flight, live, ml = fly_live(signals(), PilotSource(skill=0.6, seed=2), out, PROFILE, simulate=truth,
                                seed=4, fast=True, display="headless", audio=False, countdown=1.0, tail=6.0,
                                rate=RATE, screenshot_dir=out.parent / "shots", screenshot_every=4.0)
    return out, flight, live, ml, truth


def test_live_estimate_agrees_with_post_flight_ml(flown):
    out, flight, live, ml, truth = flown
    assert ml is not None and live.latest is not None and not live.latest.errors
    idx = [live.names.index(n) for n in live.targets]
    ml_theta = dict(zip(ml.names, ml.theta))
    diff = (live.latest.theta[idx] - np.array([ml_theta[n] for n in live.targets])) / live.latest.std[idx]
    assert list(live.targets) == ["L_p", "L_theta_c", "M_q", "M_theta_s"]  # the primary derivatives
    assert np.all(np.abs(diff) < 2), dict(zip(live.targets, diff.round(2)))
    # the secondary (coupling) derivatives too, more loosely: the two estimators weight the data
    # differently, so their difference is about one live standard error (2 is exceeded 1 in 20)
    rest = [live.names.index(n) for n in live.names if n[0] in "LM" and n not in live.targets]
    diff_rest = (live.latest.theta[rest] - ml.theta[rest]) / live.latest.std[rest]
    assert np.all(np.abs(diff_rest) < 3), dict(zip([live.names[i] for i in rest], diff_rest.round(2)))
    # and both found the aircraft flown, not the a priori model
    moved = np.abs(truth.theta - LinearModel(load_profile(PROFILE)).theta)[idx] > 3 * live.latest.std[idx]
    assert moved.sum() >= 3
    z_truth = (live.latest.theta[idx] - truth.theta[idx]) / live.latest.std[idx]
    assert np.all(np.abs(z_truth) < 3), dict(zip(live.targets, z_truth.round(2)))


def test_complete_lights_and_history_is_logged(flown):
    out, flight, live, ml, truth = flown
    assert live.complete_at_ is not None and 0 < live.complete_at_ < flight.run.duration
    meta, cols = read_live_log(live.log_path)
    assert meta["end"] == "completed"
    assert len(cols["time"]) == len(flight.run)  # one row per flown frame
    solved = np.isfinite(cols["M_q"])
    assert 10 <= solved.sum() <= flight.run.duration + 1  # about one re-solve a second
    assert cols["complete"][solved][-1] == 1 and cols["complete"][solved][0] == 0
    assert np.allclose(cols["M_q_std"][solved][-1], live.latest.std[live.names.index("M_q")])
    # the run file holds the response the live estimator saw
    assert np.allclose(flight.run["q"], np.interp(flight.run.time, cols["time"], cols["q"]))
    report = out.with_name("run.live.md").read_text()
    assert "| M_q | 20 |" in report and "test point complete at" in report and "live I %" in report
    # Tischler & Remple's insensitivity (others known) is never above the Cramér-Rao bound
    assert np.all(live.latest.insensitivity <= live.latest.std * (1 + 1e-9))


def test_panel_is_drawn_beside_the_needles(flown):
    import pygame
    out, flight, live, ml, truth = flown
    shot = pygame.image.load(str(out.parent / "shots" / "end.png"))
    w, h = shot.get_size()
    # the "complete" box is green in the panel's bottom
    x, y = w - 135, h - 34
    r, g, b, *_ = shot.get_at((x, y))
    assert g > 150 and r < 120, (r, g, b)


def test_live_and_ml_agree_when_frames_are_off_the_run_grid(tmp_path):
    """On a real clock the frames fall between the run file's grid instants. The live estimator
    uses the frame times; ML sees the run file, whose stick once changed at the next grid instant
    (up to a frame late): ML's L_p came out 5.5 of its standard errors off the truth and 7 live
    standard errors from the live estimate. Each sample now holds the frames' mean stick."""
    from cueing.clock import FakeClock, jitter
    apriori = LinearModel(load_profile(PROFILE))
    truth = apriori.with_theta(apriori.theta * np.random.default_rng(5).uniform(0.85, 1.15, apriori.theta.size))
    flight, live, ml = fly_live(signals(), PilotSource(skill=0.6, seed=2), tmp_path / "run.csv", PROFILE,
                                simulate=truth, seed=4, display="headless", audio=False, countdown=1.0, tail=6.0,
                                rate=RATE, clock=FakeClock(lateness=jitter(0.004, 1)))
    t = flight.log.time[flight.log.time >= 0]
    assert np.median(np.abs(t * RATE - np.round(t * RATE))) > 0.1  # frames a tenth of a frame or more off the grid
    idx = [live.names.index(n) for n in live.targets]
    ml_of = dict(zip(ml.names, zip(ml.theta, ml.std)))
    m_theta, m_std = np.array([ml_of[n] for n in live.targets]).T
    true = np.array([truth.theta[truth.profile.free_names.index(n)] for n in live.targets])
    assert np.all(np.abs(m_theta - true) < 3 * m_std), dict(zip(live.targets, ((m_theta - true) / m_std).round(2)))
    diff = (live.latest.theta[idx] - m_theta) / live.latest.std[idx]
    assert np.all(np.abs(diff) < 2), dict(zip(live.targets, diff.round(2)))


def test_targets_spec():
    p = load_profile(PROFILE)
    assert parse_targets("M_q:10,L_p", p) == {"M_q": 10.0, "L_p": 20.0}
    assert all(n[0] in "LMN" for n in parse_targets(None, p))
    with pytest.raises(Exception, match="not a free parameter"):
        parse_targets("M_x", p)


def test_cli_live_fly(tmp_path):
    sig = save_signals(signals(), tmp_path / "sig.json")
    out = tmp_path / "run.csv"
    proc = run_cli("cueing", "fly", "--signal", sig, "--source", "pilot", "--fast", "--headless", "--no-audio",
                   "--live", PROFILE, "--simulate", PROFILE, "--targets", "M_q:10,L_p:10,M_theta_s",
                   "--countdown", "0.5", "--tail", "4", "--seed", "3", "--rate", "60", "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "| M_q | 10 |" in proc.stdout and "live work per frame" in proc.stdout
    assert out.with_name("run.live.csv").exists() and "q" in out.read_text().splitlines()[0] + out.read_text()


def test_cli_live_without_a_response_is_one_error_line(tmp_path):
    sig = save_signals(signals(), tmp_path / "sig.json")
    proc = run_cli("cueing", "fly", "--signal", sig, "--source", "pilot", "--fast", "--headless", "--no-audio",
                   "--live", PROFILE, "--out", tmp_path / "run.csv")
    one_error_line(proc, "--simulate", "--live-response")
    proc = run_cli("cueing", "fly", "--signal", sig, "--source", "pilot", "--fast", "--headless", "--no-audio",
                   "--live", PROFILE, "--simulate", PROFILE, "--targets", "M_x:5", "--out", tmp_path / "run.csv")
    one_error_line(proc, "M_x")
    proc = run_cli("cueing", "fly", "--signal", sig, "--source", "pilot", "--fast", "--headless", "--no-audio",
                   "--live", PROFILE, "--live-response", "no_such_module:f", "--out", tmp_path / "run.csv")
    one_error_line(proc, "no_such_module")


# an "external simulator" for the --live-response path: measured states as a function of (t, stick)
_EXTERNAL = {}


def external_states(t, stick):
    from cueing.response import SimulatedAircraft
    if "aircraft" not in _EXTERNAL:
        _EXTERNAL["aircraft"] = SimulatedAircraft(LinearModel(load_profile(PROFILE)), signals(), RATE, 0.02, seed=9)
    return _EXTERNAL["aircraft"].read(t, stick)


def test_external_response_feeds_the_live_estimate(tmp_path):
    from cueing.response import ExternalResponse
    _EXTERNAL.clear()
    response = ExternalResponse("external:tests.cueing.test_live:external_states")
    flight, live, ml = fly_live(signals(), PilotSource(skill=0.6, seed=3), tmp_path / "run.csv", PROFILE,
                                response=response, fast=True, audio=False, countdown=0.5, tail=5.0, rate=RATE)
    assert "external" in read_live_log(live.log_path)[0]["response"]
    assert live.complete_at_ is not None and ml is not None
    assert "q" in flight.run.channels and flight.run["q"].std() > 0


def three_states(t, stick):
    return [0.0, 0.0, 0.0]


def test_external_response_of_the_wrong_size_is_named(tmp_path):
    from cueing.errors import CueingError
    from cueing.response import ExternalResponse
    with pytest.raises(CueingError, match="gave 3 states.*6"):
        fly_live(signals(), PilotSource(skill=0.6, seed=3), tmp_path / "run.csv", PROFILE,
                 response=ExternalResponse("tests.cueing.test_live:three_states"), fast=True, audio=False,
                 countdown=0.5, tail=1.0, rate=RATE)
    assert "# end: aborted" in (tmp_path / "run.live.csv").read_text()


def test_run_file_inputs_are_each_frames_own(flown):
    """At 60 Hz the frame log's microsecond time stamps fall just after the run file's grid instants;
    each grid instant must still take its own frame's stick (once it took the previous frame's for
    two samples in three, so ML saw the inputs a frame late)."""
    out, flight, live, ml, truth = flown
    _, cols = read_live_log(live.log_path)
    for name in ("theta_s", "theta_c"):
        np.testing.assert_allclose(flight.run[name], cols[name], rtol=0, atol=1e-12)


def test_the_estimate_runs_without_pygame(tmp_path):
    """The live estimate and its response sources are not the cockpit: they load and estimate
    with pygame unimportable (only the panel and the runner draw)."""
    code = textwrap.dedent(f"""
        import sys
        class Blocker:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] == "pygame":
                    raise ImportError("pygame blocked")
        sys.meta_path.insert(0, Blocker())
        import numpy as np
        from cueing.live.estimate import LiveIdentification
        from cueing.live.log import read_live_log
        from cueing.response import SimulatedAircraft
        from identify import LinearModel, load_profile
        from signaldesign.baselines import m3211
        signals = [m3211(0.6, 0.01, "theta_s", delay=1.0), m3211(0.5, 0.01, "theta_c", delay=6.0)]
        aircraft = SimulatedAircraft(LinearModel(load_profile({PROFILE!r})), signals, 60.0, seed=1)
        live = LiveIdentification(load_profile({PROFILE!r}), signals, aircraft, sys.argv[1])
        for k in range(660):  # 11 s at 60 Hz, the stick flown exactly
            t = k / 60
            live.update(k, t, t, np.array([s(t) for s in signals]), False)
        live.close()
        assert "pygame" not in sys.modules
        print(len(live.history_.t), int(np.isfinite(read_live_log(sys.argv[1])[1]["M_q"]).sum()))
    """)
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "run.live.csv")], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rounds, logged = map(int, proc.stdout.split())
    assert rounds >= 8 and logged == rounds  # about one re-solve a second, each logged


def test_target_on_an_input_the_signal_does_not_move_says_why(tmp_path):
    from cueing.errors import CueingError
    from cueing.live.estimate import LiveIdentification
    from signaldesign.baselines import m3211
    lon_only = [m3211(0.6, 0.01, "theta_s", 1.0)]
    with pytest.raises(CueingError, match=r"L_theta_c: not excited by this signal, which moves only theta_s "
                                          r"\(L_theta_c acts on theta_c\)"):
        LiveIdentification(load_profile(PROFILE), lon_only, None, tmp_path / "x.live.csv", "M_q,L_theta_c")


def test_live_writes_the_same_run_file_as_a_flight_without_it(tmp_path):
    """One cyclic flown: the run file still holds every input of the profile (the other at trim),
    every state and its derivative, as without --live; so ML after the flight, identify estimate
    and identify freq read it (issue #21)."""
    from cueing.session import fly
    from identify import read_run

    one = [m3211(0.6, 0.01, "theta_s", delay=1.0)]
    options = dict(fast=True, display="headless", audio=False, countdown=0.5, tail=4.0, rate=RATE)
    plain = fly(one, PilotSource(skill=0.6, seed=2), tmp_path / "plain.csv", simulate=PROFILE, seed=4, **options)
    flight, live, ml = fly_live(one, PilotSource(skill=0.6, seed=2), tmp_path / "live.csv", PROFILE,
                                simulate=PROFILE, seed=4, **options)
    live_run, plain_run = read_run(tmp_path / "live.csv"), read_run(plain.path)
    assert set(live_run.channels) >= set(plain_run.channels) - {"theta_s_cmd"}, \
        set(plain_run.channels) - set(live_run.channels)
    assert np.all(live_run["theta_c"] == 0) and "theta_c" in live_run.meta["unflown_inputs"]
    assert {"q_dot", "p_dot", "u_dot", "v_dot"} <= set(live_run.channels)
    assert ml is not None  # the live-vs-ML check ran (it failed: "missing channel(s) theta_c")
    from identify.cli import main
    # ML holds the derivatives of the cyclic not flown (infinite std error), as for the plain file
    assert main(["estimate", str(tmp_path / "live.csv"), "--profile", PROFILE, "--method", "ml",
                 "--out", str(tmp_path / "est")]) == 0
