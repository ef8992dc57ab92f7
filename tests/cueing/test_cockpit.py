"""The cockpit a designed signal needs: the whole design record with a quiet lead-in, switch timing
that an ordinary pilot's lag does not defeat, an explained information score, both mouse axes, a
flagged low frame rate, a resizable window, units on the scale, Escape as a non-zero exit.

Off-screen (SDL dummy drivers) and on fake clocks; the real-clock timing is in benchmarks/.
"""
import json

import numpy as np
import pygame
import pytest

from cueing import display as disp
from cueing.cli import EXIT_ABORTED, main
from cueing.clock import FakeClock
from cueing.errors import CueingError
from cueing.flightlog import read_frame_log
from cueing.runner import Runner, Schedule, Screen
from cueing.scoring import MAX_LAG, PracticeScore, score_run, switch_timing, tracking_lag
from cueing.session import fly
from cueing.sources import MouseSource, PilotSource, ScriptedSource
from identify import LinearModel, Run, load_profile, read_run
from signaldesign import Signal, save_signals
from signaldesign.design import SequenceDesign
from tests.cueing.test_cueing import needle_columns

AMP = 0.02
RATE = 60.0


@pytest.fixture(scope="module")
def s61_4dof():
    return LinearModel(load_profile("s61_hover_4dof"))


@pytest.fixture(scope="module")
def design(s61_4dof):
    """A 7 s optimised sequence designed for a 20 s record (0.35 s steps: shorter than a pilot's lag)."""
    d = SequenceDesign("theta_s", duration=7.0, record=20.0, amplitude=AMP, dt=0.05, grid=0.35, min_pulse=0.35,
                       max_changes=8, n_iter=300, restarts=1).fit(s61_4dof)
    return d.signals_[0]


def test_a_7_s_design_is_flown_over_its_20_s_record_after_a_quiet_lead_in(design, tmp_path):
    assert design.record == 20.0 and design.end_time == pytest.approx(7.0)
    sig = save_signals(design, tmp_path / "design.json")
    out = tmp_path / "run.csv"
    assert main(["fly", "--signal", str(sig), "--source", "pilot", "--seed", "4", "--headless", "--fast",
                 "--countdown", "0", "--lead-in", "2", "--simulate", "s61_hover_4dof", "--out", str(out)]) == 0
    run = read_run(out, require=["theta_s", "theta_s_cmd", "q"])
    assert run.time[0] == 0.0 and run.time[-1] == pytest.approx(22.0, abs=1 / RATE)  # lead-in + record
    quiet = run.time < 2.0
    assert np.all(run["theta_s_cmd"][quiet] == 0.0)  # nothing commanded during the lead-in
    started = run.time[np.flatnonzero(run["theta_s_cmd"])[0]]
    assert started == pytest.approx(2.0, abs=1 / RATE)
    after = run.time > 2.0 + design.end_time
    assert np.all(run["theta_s_cmd"][after] == 0.0) and np.ptp(run.time[after]) > 12.9  # the response goes on
    assert run.meta["lead_in"].startswith("2 s") and run.meta["record"].startswith("20 s")
    # the log carries the signal as flown (delayed by the lead-in): recover gives the same run
    assert main(["recover", str(tmp_path / "run.frames.csv"), "--out", str(tmp_path / "again.csv")]) == 0
    again = read_run(tmp_path / "again.csv")
    np.testing.assert_array_equal(again["theta_s_cmd"], run["theta_s_cmd"])


def test_default_pilot_gets_finite_switch_timings_on_short_steps(design, s61_4dof, tmp_path):
    for seed in range(3):
        flight = fly([design], PilotSource(seed=seed), tmp_path / f"p{seed}.csv", fast=True, countdown=0.0,
                     lead_in=2.0, model=s61_4dof, audio=False)
        sc = flight.score
        assert np.isfinite(sc.timing_mean) and sc.missed <= sc.switches // 4, (sc.missed, sc.switches)
        assert 0.2 < sc.timing_mean < 1.0 and 0.2 < sc.lag < 1.0  # reaction delay, lag, integration
        text = "\n".join(sc.lines())
        assert "nan" not in text.lower()


def test_switch_timing_is_the_delay_even_when_it_exceeds_a_step():
    sig = Signal("steps", "theta_s", 0.3, [1, -1, 1, 1, -1, 0, 1, -1], AMP, delay=1.0)
    t = np.arange(0, 8, 1 / RATE)
    for delay in (0.1, 0.4, 0.7):
        timing = switch_timing(t, sig(t - delay), sig)
        np.testing.assert_allclose(timing, delay, atol=1.01 / RATE)
        assert tracking_lag(sig(t), sig(t - delay), 1 / RATE) == pytest.approx(delay, abs=0.5 / RATE)
    # a switch the pilot never follows stays missed, it does not borrow a later switch's crossing
    flown = sig(t - 0.4)
    flown[(t > 1.3) & (t < 2.5)] = AMP  # ignores the 1.3 s switch to -1 and the 1.6 s one back to +1
    timing = switch_timing(t, flown, sig)
    assert np.isnan(timing[1]) and np.isnan(timing[2]) and np.isfinite(timing[3:]).all()
    slow = Signal("doublet", "theta_s", 3.0, [1, -1], AMP, delay=0.5)
    assert np.all(np.isnan(switch_timing(t, slow(t - MAX_LAG - 0.2), slow)))  # beyond a human's lag: missed
    assert np.isnan(tracking_lag(sig(t), np.zeros_like(t), 1 / RATE))  # a stick never moved has no lag


def test_all_switches_missed_reads_as_such_not_nan():
    sig = Signal("steps", "theta_s", 1.0, [1, 1, 0, -1], AMP, delay=0.5)
    t = np.arange(0, 6, 1 / RATE)
    sc = score_run(Run(t, {"theta_s_cmd": sig(t), "theta_s": 0.4 * sig(t)}), [sig])  # never gets halfway
    assert sc.missed == sc.switches == 4 and np.isnan(sc.timing_mean)
    text = "\n".join(sc.lines())
    assert "none of 4 followed" in text and "nan" not in text.lower() and sc.lag == pytest.approx(0, abs=0.02)


def test_scores_agree_overshoot_is_peak_response_not_information(s61_4dof):
    """Flown 1.2x the design: raw D-efficiency 1.44 (information grows with the response squared),
    peak response 1.2x, information retained at the designed peak response 1.0, level error +20 %:
    every figure tells the same story."""
    sig = Signal("3211", "theta_s", 1.0, [1, 1, 1, -1, -1, 1, -1], AMP, delay=0.5)
    t = np.arange(0, 12, 0.05)
    sc = score_run(Run(t, {"theta_s_cmd": sig(t), "theta_s": 1.2 * sig(t)}), [sig], s61_4dof)
    assert sc.d_efficiency == pytest.approx(1.2 ** 2, rel=1e-3)
    assert sc.peak_ratio == pytest.approx(1.2, rel=1e-6) and sc.information_retained == pytest.approx(1.0, rel=1e-3)
    assert sc.level_error_pos == pytest.approx(0.2, abs=1e-9) and sc.level_error_neg == pytest.approx(0.2, abs=1e-9)
    d = sc.to_dict()
    assert d["information_retained"] == sc.information_retained and d["d_efficiency"] == sc.d_efficiency
    text = "\n".join(sc.lines())
    assert "100.0 % (at the designed peak response)" in text and "120.0 % of the designed" in text
    assert "144.0 %" in text and "20 % beyond the designed peak response" in text


def test_level_error_is_not_the_lag(s61_4dof):
    """A pilot exactly on the levels but 0.4 s late: level errors about 0, the lag 0.4 s."""
    sig = Signal("3211", "theta_s", 1.0, [1, 1, 1, -1, -1, 1, -1], AMP, delay=0.5)
    t = np.arange(0, 12, 0.01)
    sc = score_run(Run(t, {"theta_s_cmd": sig(t), "theta_s": sig(t - 0.4)}), [sig], s61_4dof)
    assert sc.lag == pytest.approx(0.4, abs=0.02)
    assert abs(sc.level_error_pos) < 0.02 and abs(sc.level_error_neg) < 0.02


def press_escape_after_1_s(t_signal):
    """An external stick that, 1 s into the run, presses Escape (posted as a pygame event)."""
    if t_signal > 1.0 and not getattr(press_escape_after_1_s, "pressed", False):
        press_escape_after_1_s.pressed = True
        pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE))
    return 0.0


def test_escape_exits_non_zero_and_keeps_the_data_marked_aborted(tmp_path, capsys):
    sig = save_signals(Signal("3211", "theta_s", 1.0, [1, 1, 1, -1, -1, 1, -1], AMP), tmp_path / "s.json")
    press_escape_after_1_s.pressed = False
    out = tmp_path / "esc.csv"
    code = main(["fly", "--signal", str(sig), "--source", f"external:{__name__}:press_escape_after_1_s",
                 "--headless", "--fast", "--countdown", "0", "--lead-in", "0", "--out", str(out)])
    assert code == EXIT_ABORTED != 0
    err = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(err) == 1 and "aborted (pilot pressed Escape)" in err[0]
    log = read_frame_log(tmp_path / "esc.frames.csv")
    assert log.aborted and log.status == "aborted (pilot pressed Escape)"
    run = read_run(out)
    assert run.meta["status"] == log.status and run.time[-1] == pytest.approx(1.0, abs=2 / RATE)


def test_mouse_flies_two_axes_and_refuses_three(tmp_path):
    sigs = [Signal("doublet", "theta_s", 1.0, [1, -1], AMP, delay=0.5),
            Signal("doublet", "theta_c", 1.0, [-1, 1], AMP, delay=0.5)]
    pos = {}
    mouse = MouseSource(position=lambda: pos["xy"], focused=lambda: True)

    def lateness(k):  # the pointer moves along a diagonal, one pixel per frame
        pos["xy"] = (200 + k, 400 - k)
        return 0.0

    pos["xy"] = (200, 400)
    r = Runner(sigs, mouse, tmp_path / "m.frames.csv", clock=FakeClock(lateness=lateness), audio=False,
               schedule=Schedule(countdown=0.0), screen=Screen(display="headless"))
    log = r.fly()
    k = np.arange(log.time.size)
    np.testing.assert_allclose(log.columns["theta_s"][1:], [r.display.value_of_x(200 + i - 1) for i in k[1:]])
    np.testing.assert_allclose(log.columns["theta_c"][1:], [r.display.value_of_y(400 - i + 1) for i in k[1:]])
    assert np.ptp(log.columns["theta_c"]) > AMP  # the second axis is flown, not a silent zero
    assert "y: second axis" in log.meta["source"]
    with pytest.raises(CueingError, match="at most 2 axes"):
        MouseSource(position=lambda: (0, 0)).start(sigs + [Signal("doublet", "theta_p", 1.0, [1, -1], AMP)])


def test_low_frame_rate_is_shown_logged_and_scored(tmp_path):
    sig = Signal("doublet", "theta_s", 1.0, [1, -1], AMP, delay=0.5)
    slow = fly([sig], ScriptedSource(lambda t: 0.0), tmp_path / "slow.csv", clock=FakeClock(lateness=lambda k: 0.03),
               countdown=0.0, display="headless", audio=False, screenshot_dir=tmp_path / "shots",
               screenshot_every=0.5)
    stats = slow.log.frame_stats()
    assert stats["rate_achieved"] < 0.5 * RATE  # ~20 Hz, not 60
    assert any("frame rate low" in what for _, what in slow.log.events)
    assert "frame rate low" in slow.run.meta["frame_rate_warning"]
    assert slow.score.frame_rate_low and slow.score.lines()[-1].startswith("! frame rate low")
    late_shot = pygame.image.load(str(tmp_path / "shots" / "frame_00030.png"))
    warn = needle_columns(late_shot, disp.WARN_COLOR, (0, 40))
    assert warn.size > 20 and warn.min() > 400  # red text at the top right
    normal = fly([sig], ScriptedSource(lambda t: 0.0), tmp_path / "ok.csv", fast=True, countdown=0.0, audio=False)
    assert not normal.score.frame_rate_low and "frame_rate_warning" not in normal.run.meta


def test_resized_window_relays_the_display_out(tmp_path):
    sig = Signal("3211", "theta_s", 1.0, [1, 1, 1, -1, -1, 1, -1], AMP, delay=0.5)
    calls = {"n": 0}

    def events():
        calls["n"] += 1
        return [pygame.event.Event(pygame.VIDEORESIZE, size=(1280, 720), w=1280, h=720)] if calls["n"] == 120 else []

    r = Runner([sig], ScriptedSource(lambda t: -0.01), tmp_path / "z.frames.csv", clock=FakeClock(), audio=False,
               events=events, schedule=Schedule(countdown=0.0),
               screen=Screen(display="headless", screenshot_dir=tmp_path / "shots", screenshot_every=1.0))
    log = r.fly()
    assert any("resized to 1280 x 720" in what for _, what in log.events)
    before = pygame.image.load(str(tmp_path / "shots" / "frame_00060.png"))
    after = pygame.image.load(str(tmp_path / "shots" / "frame_00180.png"))
    assert before.get_size() == (800, 480) and after.get_size() == (1280, 720)
    for img, (w, h) in ((before, (800, 480)), (after, (1280, 720))):
        y, L = int(h * 0.62), int(min(h * 0.16, 60 * h / 480))
        xp = needle_columns(img, disp.PILOT_COLOR, (y + 4, y + L))
        expected = disp.MARGIN + (-0.01 / (1.5 * AMP) + 1) / 2 * (w - 2 * disp.MARGIN)
        assert xp.size == disp.NEEDLE_WIDTH and abs(xp.mean() - expected) <= 1.0
        scale = needle_columns(img, disp.SCALE_COLOR, (y - 1, y + 1))
        assert scale.min() == disp.MARGIN and scale.max() == w - disp.MARGIN  # the scale spans the new width


class FilledPanel:
    """A Panel that records what the runner gives it and fills its rectangle with one colour."""

    def __init__(self, width, color):
        self.width, self.color, self.frames, self.rects = width, color, [], []

    def update(self, k, t, t_signal, flown, paused):
        self.frames.append((k, t, float(flown[0])))

    def draw(self, surface, rect):
        self.rects.append(tuple(rect))
        surface.fill(self.color, rect)


@pytest.mark.parametrize("display", ["headless", None])
def test_panels_are_fed_every_frame_and_drawn_right_of_the_needles(tmp_path, display):
    sig = Signal("doublet", "theta_s", 1.0, [1, -1], AMP, delay=0.5)
    panels = [FilledPanel(100, (255, 0, 0)), FilledPanel(60, (0, 0, 255))]
    r = Runner([sig], ScriptedSource(lambda t: 0.5 * AMP), tmp_path / "p.frames.csv", clock=FakeClock(), audio=False,
               schedule=Schedule(countdown=0.5), screen=Screen(display=display, screenshot_dir=tmp_path / "s"),
               panels=panels)
    log = r.fly()
    for panel in panels:  # every frame, the countdown's included, with the frame log's own numbers
        assert [f[0] for f in panel.frames] == list(range(log.time.size))
        np.testing.assert_allclose([f[1] for f in panel.frames], log.time, atol=1e-6)  # logged to 1 µs
        np.testing.assert_allclose([f[2] for f in panel.frames], log.columns["theta_s"])
    if display is None:  # fed without a display, never drawn
        assert not panels[0].rects and not panels[1].rects
        return
    assert set(panels[0].rects) == {(640, 0, 100, 480)} and set(panels[1].rects) == {(740, 0, 60, 480)}
    assert r.needle_surface.get_size() == (640, 480)  # the needles' layout leaves the panels their room
    shot = pygame.image.load(str(r.screenshot("last.png")))
    assert tuple(shot.get_at((700, 240)))[:3] == (255, 0, 0) and tuple(shot.get_at((790, 240)))[:3] == (0, 0, 255)


def test_scale_shows_the_input_unit_rad_as_degrees(design):
    assert disp.display_unit("rad") == (pytest.approx(180 / np.pi), "deg")
    assert disp.display_unit("m") == (1.0, "m") and disp.display_unit(None)[1] == "unit unknown"
    assert disp.signal_units([design]) == {"theta_s": "rad"}  # the design wrote its input's unit
    plain = Signal("doublet", "theta_s", 1.0, [1, -1], AMP)
    assert disp.signal_units([plain]) == {"theta_s": None}
    assert disp.signal_units([plain], load_profile("s61_hover_4dof")) == {"theta_s": "rad"}
    shots = []
    for units in ({"theta_s": "rad"}, {"theta_s": "m"}):
        d = disp.Display([plain], units=units)
        surface = pygame.Surface(d.size)
        d.render(surface, disp.FrameState(1.0, 1.0, np.zeros(1), np.zeros(1)))
        shots.append(pygame.surfarray.array3d(surface)[:, d.y_scale[0] + d.needle_len + 5:, :])
    assert np.any(shots[0] != shots[1])  # tick values (1.15 deg vs 0.02 m) and unit labels differ


@pytest.mark.parametrize("content, needle", [
    (bytes(range(256)) * 4, "binary"),
    (b"# format: pseudostep-frame-log/1\nframe,time\n0,0\n", "header must hold"),
    (b"# format: pseudostep-frame-log/1\nframe,time,t_signal,paused,x_cmd,x\n0,0,0,0,0,abc\n", "not a number"),
    (b"# format: pseudostep-frame-log/1\nframe,time,t_signal,paused,x_cmd,x\n0,1,0,0,0,0\n1,0,0,0,0,0\n",
     "not increasing"),
    (b"# format: pseudostep-frame-log/1\nframe,time,t_signal,paused,x_cmd,x\n0,0,0,0,0\n1,1,0,0,0,0\n",
     "line 3: 6 columns"),
    (b"# format: pseudostep-frame-log/1\n# frame_rate: fast\nframe,time,t_signal,paused,x_cmd,x\n0,0,0,0,0,0\n"
     b"1,1,0,0,0,nan\n", "non-finite"),
])
def test_recover_on_a_malformed_log_is_one_line_status_2(content, needle, tmp_path, capsys):
    bad = tmp_path / "bad.frames.csv"
    bad.write_bytes(content)
    assert main(["recover", str(bad), "--out", str(tmp_path / "x.csv")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(err) == 1 and needle in err[0] and str(bad) in err[0], err
    assert not (tmp_path / "x.csv").exists()


def test_history_and_learning_curve_without_nan(tmp_path):
    from cueing.history import append_attempt, format_history, load_history, plot_learning_curve
    base = {"rms": 0.5, "timing_std": 0.05, "level_error_pos": 0.1, "level_error_neg": -0.1, "asymmetry": 0.2,
            "spectral_fidelity": 0.9, "signal": "design"}
    append_attempt("Kaletka", {**base, "timing_mean": float("nan"), "lag": 0.6, "d_efficiency": 1.13}, tmp_path)
    append_attempt("Kaletka", {**base, "timing_mean": 0.4, "lag": 0.4, "d_efficiency": 0.9}, tmp_path)
    records = load_history("Kaletka", tmp_path)
    table = format_history(records)
    assert "nan" not in table.lower() and "missed" in table and "over 100" in table
    png = plot_learning_curve("Kaletka", records, tmp_path / "c.png")
    assert png.stat().st_size > 1000
    assert json.loads((tmp_path / "Kaletka.jsonl").read_text().splitlines()[1])["lag"] == 0.4


def test_score_lines_flag_warnings_for_the_end_screen():
    sc = PracticeScore(rms=0.1, timing_mean=0.3, timing_std=0.05, timing_max=0.4, switches=4, missed=0,
               level_error_pos=0.0, level_error_neg=0.0, asymmetry=0.0, spectral_fidelity=0.99, lag=0.3,
               frame_rate=59.9, frame_rate_lowest=50.0, frame_rate_target=60.0)
    assert sc.frame_rate_low and sc.lines()[-1].startswith(disp.WARNING_MARK)


@pytest.mark.parametrize("content, needle", [
    (bytes(range(256)) * 4, "binary"),
    (b'{"rms": "fast"}\n', "'rms' is not a number"),
    (b"[1, 2]\n", "not a practice record"),
])
def test_history_of_a_malformed_file_is_one_line_status_2(content, needle, tmp_path, capsys):
    (tmp_path / "Rix.jsonl").write_bytes(content)
    assert main(["history", "Rix", "--history-dir", str(tmp_path), "--plot", str(tmp_path / "c.png")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(err) == 1 and needle in err[0], err


def test_escape_in_the_countdown_exits_non_zero_with_one_line(tmp_path, capsys):
    sig = save_signals(Signal("doublet", "theta_s", 1.0, [1, -1], AMP), tmp_path / "s.json")
    pygame.display.init()
    pygame.event.clear()
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE))  # pressed before the start
    code = main(["practice", "--signal", str(sig), "--source", "pilot", "--pilot", "Rix", "--headless", "--fast",
                 "--countdown", "1", "--history-dir", str(tmp_path / "h"), "--out-dir", str(tmp_path / "p")])
    assert code == EXIT_ABORTED
    err = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(err) == 1 and "before the recording started" in err[0]
    log = (tmp_path / "p" / "Rix_attempt01.frames.csv").read_text()
    assert log.endswith("# end: aborted (pilot pressed Escape)\n")  # the log is kept, marked aborted


def test_record_comes_from_the_signal_or_the_option_and_never_cuts_the_sequence(tmp_path):
    plain = Signal("doublet", "theta_s", 1.0, [1, -1], AMP, delay=0.5)
    assert plain.record == plain.end_time == 2.5  # no design record: the signal itself
    assert Signal("doublet", "theta_s", 1.0, [1, -1], AMP, params={"record": 1.0}).record == 2.0
    assert Signal("doublet", "theta_s", 1.0, [1, -1], AMP, params={"record": "long"}).record == 2.0
    sig = save_signals(plain, tmp_path / "s.json")
    for extra, span in ((["--record", "6"], 6.0 + 1.5), ([], 2.5 + 1.0 + 1.5), (["--record", "1"], 2.5 + 1.0 + 1.5)):
        out = tmp_path / "r.csv"
        assert main(["fly", "--signal", str(sig), "--source", "pilot", "--headless", "--fast", "--countdown", "0",
                     "--lead-in", "1.5", "--out", str(out)] + extra) == 0
        assert read_run(out).time[-1] == pytest.approx(span, abs=1 / RATE), extra


def test_frame_rate_monitor_flags_low_and_recovers_with_hysteresis():
    from cueing.runner import FrameRateMonitor
    m = FrameRateMonitor(60.0)
    t, changes = 0.0, []
    for rate, seconds in ((60, 2), (20, 2), (55, 2), (60, 2)):
        for _ in range(int(rate * seconds)):
            t += 1 / rate
            change = m.add(t)
            changes += [change] if change else []
        if rate == 55:
            assert m.warning is not None  # 92 % of the target: still shown until 95 %
    assert len(changes) == 2 and changes[0].startswith("frame rate low: ") and "recovered" in changes[1]
    assert m.warning is None
