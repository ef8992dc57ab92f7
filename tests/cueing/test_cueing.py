"""cueing: display pixels, frame log fidelity, pause on joystick loss, scoring, pilot model, history.

Everything off-screen (SDL dummy drivers, set in conftest) and on a fake clock, so it is fast and
deterministic; the real-clock timing lives in benchmarks/cueing_timing.py.
"""
import os
import signal

import numpy as np
import pygame
import pytest

from cueing import display as disp
from cueing.audio import Ticker
from cueing.clock import FakeClock, jitter
from cueing.errors import CueingError
from cueing.flightlog import FrameLogWriter, log_to_run, read_frame_log
from cueing.history import append_attempt, format_history, load_history, plot_learning_curve
from cueing.pilot import PilotModel
from cueing.runner import Runner, Schedule, Screen
from cueing.scoring import score_run, switch_timing
from cueing.sources import (Calibration, JoystickSource, KeyboardSource, MouseSource, PilotSource, ReplaySource,
                            ScriptedSource, make_source)
from identify import Run, read_run
from signaldesign import Signal

RATE = 60.0
AMP = 0.02


@pytest.fixture
def s3211():
    return Signal("3211", "theta_s", 1.0, [1, 1, 1, -1, -1, 1, -1], AMP, delay=0.5)


def expected_x(value, width=800):
    """Needle column from the documented geometry: +/-1.5 amplitudes over the width minus margins."""
    frac = (np.clip(value / (1.5 * AMP), -1, 1) + 1) / 2
    return disp.MARGIN + frac * (width - 2 * disp.MARGIN)


def needle_columns(surface, color, rows):
    px = pygame.surfarray.array3d(surface)  # (w, h, 3)
    band = px[:, rows[0]:rows[1], :]
    hit = np.all(band == np.array(color), axis=2).any(axis=1)
    return np.flatnonzero(hit)


def _sigterm_caught() -> bool:
    """Whether anything (Python or C, such as SDL) catches SIGTERM in this process (Linux)."""
    line = next(l for l in open("/proc/self/status") if l.startswith("SigCgt:"))
    return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads the signal mask from /proc")
def test_a_run_on_a_display_leaves_sigterm_as_it_found_it(s3211, tmp_path):
    """SDL takes SIGTERM when the display starts if nobody holds it and keeps it after the run:
    a later kill of the program, or of design workers it forks, then only queued a quit event."""
    pygame.display.quit()  # SDL starts afresh, as in a new program (an earlier test may have started it)
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        Runner([s3211], ScriptedSource(lambda t: 0.0), tmp_path / "a.frames.csv", clock=FakeClock(), audio=False,
               schedule=Schedule(countdown=0.0, tail=0.1), screen=Screen(display="headless")).fly()
        assert not _sigterm_caught()
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def test_screenshot_shows_both_needles_where_signal_and_input_put_them(s3211, tmp_path):
    # the flown input is a scripted ramp; screenshots are taken mid-run and read back as PNG
    source = ScriptedSource(lambda t: -0.02 + 0.004 * t)
    r = Runner([s3211], source, tmp_path / "a.frames.csv", clock=FakeClock(), audio=False,
               schedule=Schedule(countdown=0.5, tail=0.2),
               screen=Screen(display="headless", screenshot_dir=tmp_path / "shots", screenshot_every=1.3))
    log = r.fly()
    shots = sorted((tmp_path / "shots").glob("frame_*.png"))
    assert len(shots) >= 5
    y, L = r.display.y_scale[0], r.display.needle_len
    checked = 0
    for shot in shots:
        k = int(shot.stem.split("_")[1])
        img = pygame.image.load(str(shot))
        cmd, flown = log.columns["theta_s_cmd"][k], log.columns["theta_s"][k]
        assert cmd == pytest.approx(float(s3211(log.columns["t_signal"][k])))
        xc = needle_columns(img, disp.COMMAND_COLOR, (y - L, y - 3))
        xp = needle_columns(img, disp.PILOT_COLOR, (y + 4, y + L))
        assert xc.size == disp.NEEDLE_WIDTH and xp.size == disp.NEEDLE_WIDTH
        assert abs(xc.mean() - expected_x(cmd)) <= 1.0, (k, xc.mean(), expected_x(cmd))
        assert abs(xp.mean() - expected_x(flown)) <= 1.0, (k, xp.mean(), expected_x(flown))
        checked += cmd != 0
    assert checked >= 2  # some screenshots caught the command needle off centre
    end = pygame.image.load(str(tmp_path / "shots" / "end.png"))
    assert needle_columns(end, (30, 34, 46), (40, 200)).size > 500  # the score box is drawn


def test_countdown_is_shown_before_the_start_only(s3211):
    d = disp.Display([s3211])
    region = (d.size[1] // 5 - 40, d.size[1] // 5 + 40)
    before, after = pygame.Surface(d.size), pygame.Surface(d.size)
    d.render(before, disp.FrameState(-2.5, -2.5, np.zeros(1), np.zeros(1), countdown=2.5))
    d.render(after, disp.FrameState(0.1, 0.1, np.zeros(1), np.zeros(1)))
    assert needle_columns(before, disp.TEXT_COLOR, region).size > 10
    assert needle_columns(after, disp.TEXT_COLOR, region).size == 0


def test_preview_strip_shows_the_coming_switch(s3211):
    d = disp.Display([s3211], preview=2.0)
    surface = pygame.Surface(d.size)
    # 0.3 s before the sequence starts: the needle is at 0, the strip already shows the + level
    d.render(surface, disp.FrameState(0.2, 0.2, np.zeros(1), np.zeros(1)))
    y = d.y_scale[0] - d.needle_len - 4
    xs = needle_columns(surface, disp.PREVIEW_COLOR, (y - 120, y))
    assert abs(xs.max() - expected_x(AMP)) <= 2 and abs(xs.min() - expected_x(0)) <= 2
    plain = pygame.Surface(d.size)
    disp.Display([s3211], preview=0.0).render(plain, disp.FrameState(0.2, 0.2, np.zeros(1), np.zeros(1)))
    assert needle_columns(plain, disp.PREVIEW_COLOR, (y - 120, y)).size == 0


def test_log_equals_what_the_scripted_source_produced(s3211, tmp_path):
    # jittery wake-ups and one 70 ms stall: the command must follow the clock, not the frame count
    base = jitter(0.002, seed=3)
    lateness = lambda k: 0.07 if k == 100 else base(k)  # noqa: E731
    source = ScriptedSource(lambda t: 0.01 * np.sin(3 * t))
    r = Runner([s3211], source, tmp_path / "b.frames.csv", clock=FakeClock(lateness=lateness), audio=False,
               schedule=Schedule(countdown=1.0))
    log = r.fly()
    produced = np.array(source.produced)[:, 0]
    assert log.status == "completed" and not log.aborted
    np.testing.assert_allclose(log.columns["theta_s"], produced, rtol=1e-8, atol=1e-15)
    t = log.columns["time"]
    np.testing.assert_allclose(log.columns["t_signal"], t, atol=1e-6)
    np.testing.assert_allclose(log.columns["theta_s_cmd"], s3211(t), atol=1e-12)
    np.testing.assert_array_equal(log.columns["frame"], np.arange(t.size))
    steps = np.diff(t)
    assert steps.max() > 0.07 and t[-1] >= s3211.end_time + 1.0  # the stall is visible, nothing made up
    # the run after the stall is back on the frame grid (skipped slots, no accumulated delay)
    slots = (t + 1.0) * RATE
    assert np.median(np.abs(slots[110:] - np.round(slots[110:]))) * (1 / RATE) < 0.003


def test_run_file_from_the_log_loads_in_identify(s3211, tmp_path):
    source = ScriptedSource(lambda t: 0.5 * float(s3211(t - 0.3)))
    r = Runner([s3211], source, tmp_path / "c.frames.csv", clock=FakeClock(lateness=jitter(0.003, 1)), audio=False,
               schedule=Schedule(countdown=0.5))
    run = log_to_run(r.fly(), sample_rate=100.0)
    run.to_csv(tmp_path / "c.csv")
    back = read_run(tmp_path / "c.csv", require=["theta_s", "theta_s_cmd"])
    assert back.dt == pytest.approx(0.01) and back.time[0] == 0.0
    np.testing.assert_allclose(back["theta_s_cmd"], s3211(back.time), atol=1e-12)
    # the flown channel holds each frame's value: away from the switches it is the scripted value
    away = np.min(np.abs(back.time[:, None] - (s3211.switch_times() + 0.3)[None, :]), axis=1) > 0.05
    np.testing.assert_allclose(back["theta_s"][away], 0.5 * s3211(back.time[away] - 0.3), atol=1e-12)
    for key in ("signal", "source", "pilot", "frame_stats", "status"):
        assert key in back.meta
    assert back.meta["status"] == "completed"


class FakeJoystick:
    """Stands in for pygame.joystick.Joystick: one device, axis 1 pushed to raw 0.6."""

    opened = 0

    def __init__(self, index):
        FakeJoystick.opened += 1
        self.index = index

    def get_instance_id(self):
        return 40 + FakeJoystick.opened

    def get_axis(self, axis):
        return 0.6 if axis == 1 else 0.0

    def get_name(self):
        return "fake stick"


def test_joystick_removal_pauses_the_run_and_is_logged(s3211, tmp_path):
    FakeJoystick.opened = 0
    source = JoystickSource(factory=FakeJoystick, calibration=Calibration(dead_zone=0.1, full_scale=0.03))
    seen = {}

    def lateness(k):  # scripted hot-plug: remove at wake-up 60, re-add at 150; look at the screen at 100
        if k == 60:
            pygame.event.post(pygame.event.Event(pygame.JOYDEVICEREMOVED, instance_id=41))
        if k == 100:
            seen["warning"] = needle_columns(runner.surface, disp.WARN_COLOR, (0, 60)).size
        if k == 150:
            pygame.event.post(pygame.event.Event(pygame.JOYDEVICEADDED, device_index=0))
        return 0.0

    runner = Runner([s3211], source, tmp_path / "j.frames.csv", clock=FakeClock(lateness=lateness), audio=False,
                    schedule=Schedule(countdown=0.0), screen=Screen(display="headless"))
    pygame.display.init()  # the dummy video driver carries the event queue
    pygame.event.clear()
    log = runner.fly()
    paused = log.columns["paused"].astype(bool)
    t, ts, flown = log.columns["time"], log.columns["t_signal"], log.columns["theta_s"]
    texts = [what for _, what in log.events]
    assert any("removed" in w for w in texts) and any("reconnected" in w for w in texts)
    assert paused.sum() == pytest.approx(90, abs=2) and np.all(np.diff(np.flatnonzero(paused)) == 1)
    assert np.all(flown[paused] == 0.0) and np.ptp(ts[paused]) == 0.0  # stick ignored, signal frozen
    # calibrated stick: (0.6 - 0.1 dead zone) / 0.9 of the 0.03 full scale
    assert flown[~paused][5] == pytest.approx(0.5 / 0.9 * 0.03)
    pause_len = t[paused][-1] - t[paused][0] + 1 / RATE
    after = ~paused & (t > t[paused][-1])
    np.testing.assert_allclose(ts[after], t[after] - pause_len, atol=1e-6)  # resumes where it stopped
    assert seen["warning"] > 0  # the pilot was told on screen
    assert t[-1] > ts[-1] and log.status == "completed"
    run = log_to_run(log)
    assert "removed" in run.meta["events"] and run["t_signal"][-1] == pytest.approx(ts[-1], abs=0.02)


def test_no_joystick_is_one_clear_error(s3211):
    pygame.joystick.init()
    if pygame.joystick.get_count():
        pytest.skip("a real joystick is connected")
    with pytest.raises(CueingError, match="no joystick found"):
        JoystickSource().start([s3211])


def test_calibration_centre_dead_zone_and_range():
    cal = Calibration.from_samples([0.04, 0.05, 0.06, 0.05], full_scale=2.0)
    assert cal.centre == pytest.approx(0.05) and cal.dead_zone == pytest.approx(3 * np.std([0.04, 0.05, 0.06, 0.05]))
    assert cal.apply(0.07, 1.0) == 0.0  # inside the dead zone around the offset centre
    assert cal.apply(1.0, 1.0) == pytest.approx(2.0) and cal.apply(-1.0, 1.0) == pytest.approx(-2.0)
    assert cal.apply(0.05 + cal.dead_zone + 0.5 * (0.95 - cal.dead_zone), 1.0) == pytest.approx(1.0)
    assert Calibration(invert=True).apply(1.0, 0.1) == pytest.approx(-0.15)


def test_joystick_rest_calibration_measures_each_axis(s3211):
    class Drifting(FakeJoystick):
        def get_axis(self, axis):
            return {0: -0.1, 1: 0.08}[axis]

    src = JoystickSource(factory=Drifting, calibration=Calibration(full_scale=0.03))
    src.start([s3211, Signal("doublet", "theta_c", 1.0, [1, -1], AMP)])
    cals = src.calibrate_rest(0.1, sleep=lambda s: None)
    assert cals[0].centre == pytest.approx(0.08) and cals[1].centre == pytest.approx(-0.1)
    assert np.all(src.read(0.0) == 0.0)  # the resting stick now reads zero on both axes
    assert "axis 1: centre 0.08" in src.describe()


def test_closed_window_aborts_but_keeps_the_log(s3211, tmp_path):
    calls = {"n": 0}

    def events():
        calls["n"] += 1
        return [pygame.event.Event(pygame.QUIT)] if calls["n"] == 200 else []

    r = Runner([s3211], PilotSource(skill=0.5, seed=2), tmp_path / "q.frames.csv", clock=FakeClock(), events=events,
               audio=False, schedule=Schedule(countdown=0.5))
    log = r.fly()
    assert log.aborted and "window closed" in log.status and len(log.time) == 199  # frame 200 never happened
    run = log_to_run(log)
    assert run.meta["status"].startswith("aborted") and run.time[-1] == pytest.approx(log.time[-1], abs=1 / RATE)


def test_killed_log_reads_as_aborted_even_cut_mid_line(s3211, tmp_path):
    r = Runner([s3211], PilotSource(seed=1), tmp_path / "k.frames.csv", clock=FakeClock(), audio=False,
               schedule=Schedule(countdown=0.0))
    r.fly()
    text = (tmp_path / "k.frames.csv").read_text().splitlines(keepends=True)
    cut = "".join(text[:300]) + text[300][:7]  # a kill lands in the middle of a row
    (tmp_path / "k.frames.csv").write_text(cut)
    log = read_frame_log(tmp_path / "k.frames.csv")
    assert log.aborted and "killed" in log.status
    rows = sum(1 for line in text[:300] if not line.startswith("#")) - 1  # minus the header
    assert len(log.time) == rows and log.time[-1] > 2.0


def test_ticks_at_every_level_change_and_silent_audio_is_harmless(s3211, tmp_path):
    silent = Ticker(enabled=False)
    silent.tick()
    assert silent.ticks == 1 and not silent.enabled
    r = Runner([s3211], ScriptedSource(lambda t: 0.0), tmp_path / "t.frames.csv", clock=FakeClock(), audio=True,
               schedule=Schedule(countdown=0.2))  # dummy audio driver: must not fail either way
    r.fly()
    assert r.ticker.ticks == s3211.switch_times().size


def test_replay_source_reproduces_a_logged_run(s3211, tmp_path):
    r1 = Runner([s3211], PilotSource(skill=0.3, seed=5), tmp_path / "r1.frames.csv", clock=FakeClock(), audio=False,
                schedule=Schedule(countdown=0.0))
    log1 = r1.fly()
    replay = make_source(f"replay:{tmp_path / 'r1.frames.csv'}")
    assert isinstance(replay, ReplaySource)
    r2 = Runner([s3211], replay, tmp_path / "r2.frames.csv", clock=FakeClock(), audio=False,
                schedule=Schedule(countdown=0.0))
    log2 = r2.fly()
    np.testing.assert_allclose(log2.columns["theta_s"], log1.columns["theta_s"], rtol=1e-7)


def test_keyboard_and_mouse_sources(s3211):
    keys = {pygame.K_LEFT: False, pygame.K_RIGHT: True}
    kb = KeyboardSource(key_state=lambda: {k: keys.get(k, False) for k in (pygame.K_LEFT, pygame.K_RIGHT)})
    kb.start([s3211])
    assert kb.read(0.0)[0] == AMP
    keys.update({pygame.K_LEFT: True, pygame.K_RIGHT: False})
    assert kb.read(0.0)[0] == -AMP
    d = disp.Display([s3211])
    pos = {"x": d.x_of(-0.01)}
    mouse = MouseSource(value_of=d.value_of_pointer, position=lambda: (pos["x"], 10), focused=lambda: True)
    mouse.start([s3211])
    assert mouse.read(0.0)[0] == pytest.approx(-0.01, abs=1.5 * AMP / 360)  # within one pixel


def test_log_is_synced_to_disk_by_the_writer_s_own_timer(tmp_path):
    """The fsyncs come from the writer's timer, not from frames: they keep coming while no frame
    is written. (Their 0.1 s period is measured in benchmarks/cueing_timing.py, not timed here: a
    loaded CI machine may delay a thread.)"""
    import time
    w = FrameLogWriter(tmp_path / "s.frames.csv", ["theta_s"], sync_interval=0.02).open({"x": 1})
    w.frame(0, 0.0, 0.0, False, [0.0], [0.0])
    synced, deadline = w.fsyncs, time.monotonic() + 10.0
    while w.fsyncs < synced + 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert w.fsyncs >= synced + 3
    assert "0,0.000000" in (tmp_path / "s.frames.csv").read_text()
    w.close()


def test_unknown_source_and_bad_replay_are_clear_errors(tmp_path):
    with pytest.raises(CueingError, match="unknown source 'stick'"):
        make_source("stick")
    with pytest.raises(CueingError, match="no such run file"):
        make_source(f"replay:{tmp_path / 'none.csv'}")


def test_exact_flying_scores_perfect_and_errors_are_measured(s3211, s61):
    t = np.arange(0, 10, 0.01)
    cmd = s3211(t)

    def run_of(flown):
        return Run(t, {"theta_s_cmd": cmd, "theta_s": flown})

    perfect = score_run(run_of(cmd), [s3211], s61)
    assert perfect.rms == 0 and perfect.timing_max == 0 and perfect.missed == 0
    assert abs(perfect.level_error_pos) < 1e-12 and abs(perfect.level_error_neg) < 1e-12
    assert perfect.spectral_fidelity == pytest.approx(1.0) and perfect.d_efficiency == pytest.approx(1.0)
    late = score_run(run_of(s3211(t - 0.2)), [s3211])
    assert late.timing_mean == pytest.approx(0.2, abs=0.011) and late.timing_std < 0.011
    lopsided = np.where(cmd > 0, 1.1 * cmd, 0.8 * cmd)
    sc = score_run(run_of(lopsided), [s3211], s61)
    assert sc.level_error_pos == pytest.approx(0.1) and sc.level_error_neg == pytest.approx(-0.2)
    assert sc.asymmetry == pytest.approx(0.3) and sc.spectral_fidelity < 0.99
    assert sc.d_efficiency != pytest.approx(1.0, abs=0.01)


def test_simulated_pilot_skill_and_preview_act_as_modelled(s3211):
    t = np.arange(0, 10, 1 / RATE)

    def mean_scores(skill, preview):
        out = []
        for seed in range(6):
            flown = PilotModel(skill, seed=seed).fly([s3211], t, preview)[:, 0]
            out.append((np.sqrt(np.mean((flown - s3211(t)) ** 2)) / AMP,
                        np.nanmean(switch_timing(t, flown, s3211))))
        return np.mean(out, axis=0)

    rms_novice, late_novice = mean_scores(0.0, False)
    rms_expert, late_expert = mean_scores(1.0, False)
    rms_preview, late_preview = mean_scores(1.0, True)
    assert rms_expert < rms_novice and late_expert < late_novice
    assert 0.3 < late_expert < 0.9  # reaction delay plus lag: late by a few tenths of a second
    assert late_preview < late_expert - 0.2 and rms_preview < rms_expert


def test_practice_history_and_learning_curve(tmp_path):
    for i, rms in enumerate([0.9, 0.7, 0.5]):
        append_attempt("Rix", {"rms": rms, "timing_mean": 0.5 - 0.1 * i, "timing_std": 0.1, "level_error_pos": 0.1,
                               "level_error_neg": -0.1, "asymmetry": 0.2, "spectral_fidelity": 0.9,
                               "d_efficiency": 0.8 + 0.05 * i, "signal": "3211"}, tmp_path)
    records = load_history("Rix", tmp_path)
    assert [r["rms"] for r in records] == [0.9, 0.7, 0.5]
    table = format_history(records)
    assert len(table.splitlines()) == 4 and "90.0" in table
    png = plot_learning_curve("Rix", records, tmp_path / "curve.png")
    assert pygame.image.load(str(png)).get_width() > 100
    with pytest.raises(CueingError, match="no practice history"):
        load_history("Kaletka", tmp_path)
    with pytest.raises(CueingError, match="pilot name"):
        load_history("../etc", tmp_path)


def test_figures_use_no_pyplot_state():
    """cueing's and campaign's figures are drawn on their own Agg canvas (matplotlib.figure.Figure):
    no pyplot, no matplotlib.use() switching a caller's backend."""
    import re

    from tests.helpers import ROOT
    pyplot = re.compile(r"matplotlib\.pyplot|from matplotlib import .*pyplot|matplotlib\.use\(")
    files = [f for package in ("cueing", "campaign") for f in sorted((ROOT / package).rglob("*.py"))]
    hits = [f"{f.relative_to(ROOT)}:{i}" for f in files
            for i, line in enumerate(f.read_text().splitlines(), 1) if pyplot.search(line)]
    assert not hits, hits
