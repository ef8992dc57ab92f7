"""Cueing display timing: a headless 60 Hz run of a 7 s signal on the real monotonic clock.

Measures, from the frame log the run wrote: achieved frame rate, frame-interval jitter (std, max),
the command's timing error at every switch (time from the switch to the first frame showing the new
level: bounded by one frame interval), signal drift (command vs the signal at each frame's own
clock stamp, and the frame stamps' slope against the nominal grid), the off-screen render time
per frame, and whether the low-frame-rate flag stays down. Baseline, measured in the same run: the
naive loop (pygame.time.Clock.tick(60), signal evaluated from the frame count) with the same drawing.

Targets: logged rate within 0.5 % of nominal, jitter std under 1 ms, zero signal drift.
Run: ``python benchmarks/cueing_timing.py`` (about 25 s; no options).
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from cueing.display import Display, FrameState  # noqa: E402 (cueing first: it hides pygame's banner)
from cueing.flightlog import LOW_RATE, SYNC_INTERVAL, FrameLogWriter, frame_rate_warning  # noqa: E402
from cueing.runner import Runner, Schedule, Screen  # noqa: E402
from cueing.sources import PilotSource  # noqa: E402
from signaldesign.baselines import m3211  # noqa: E402
from _cli import parser as cli_parser  # noqa: E402
import pygame  # noqa: E402

RATE = 60.0


def cueing_run(signal, folder: Path):
    runner = Runner([signal], PilotSource(skill=0.5, seed=1), folder / "t.frames.csv",
                    schedule=Schedule(rate=RATE, countdown=1.0, tail=0.5), screen=Screen(display="headless"),
                    audio=False)
    log = runner.fly()
    return log, np.array(runner.render_times_)


def naive_run(signal, duration: float):
    """The baseline: frame-count time, paced by pygame.time.Clock.tick."""
    display = Display([signal])
    surface = pygame.Surface(display.size)
    clock = pygame.time.Clock()
    stamps, k, start = [], 0, time.perf_counter()
    while k / RATE <= duration:
        t_frames = k / RATE  # what the naive loop believes the time is
        stamps.append(time.perf_counter() - start)
        value = float(signal(t_frames))
        display.render(surface, FrameState(t_frames, t_frames, np.array([value]), np.array([value])))
        clock.tick(int(RATE))
        k += 1
    return np.array(stamps)


def interval_stats(t: np.ndarray) -> tuple[float, float, float, float]:
    steps = np.diff(t)
    rate = steps.size / (t[-1] - t[0])
    return rate, float(np.std(steps)), float(np.max(steps)), float(np.max(np.abs(steps - 1 / RATE)))


def sync_period(folder: Path, seconds: float = 1.0) -> float:
    """Mean time between the frame log's fsyncs while frames are written at the display rate [s]."""
    w = FrameLogWriter(folder / "sync.frames.csv", ["theta_s"]).open({})
    start, k = time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        w.frame(k, k / RATE, k / RATE, False, [0.0], [0.0])
        k += 1
        time.sleep(1 / RATE)
    n = w.fsyncs - 1  # the one at open is not periodic
    elapsed = time.perf_counter() - start
    w.close()
    return elapsed / max(n, 1)


def parser():
    return cli_parser(__doc__)  # no options: --help only


def main(argv=None) -> int:
    parser().parse_args(argv)
    pygame.display.init()
    signal = m3211(1.0, amplitude=0.02, delay=0.5)  # 7 s of signal
    with tempfile.TemporaryDirectory() as tmp:
        log, render = cueing_run(signal, Path(tmp))
        synced = sync_period(Path(tmp))
    t, ts, cmd = log.columns["time"], log.columns["t_signal"], log.columns["theta_s_cmd"]
    seq = t >= 0
    rate, jit_std, jit_max, dev_max = interval_stats(t[seq])
    # switch timing: first frame at/after each switch shows the new level; the one before the old
    errors, wrong = [], 0
    for s in signal.switch_times():
        k = int(np.searchsorted(ts, s - 1e-9))
        errors.append(ts[k] - s)
        wrong += int(cmd[k] != float(signal(s + 1e-6))) + int(k > 0 and cmd[k - 1] != float(signal(s - 1e-6)))
    errors = np.array(errors)
    mismatch = np.max(np.abs(cmd - signal(ts)))  # command vs the signal at the frame's own stamp
    # frame stamps against the nominal grid: the slope is the drift of the schedule (s per s)
    n = np.floor(t[seq] * RATE + 1e-6)  # the grid slot each frame belongs to
    slope = np.polyfit(t[seq], t[seq] - n / RATE, 1)[0]

    duration = float(t[-1])
    base = naive_run(signal, duration)
    b_rate, b_std, b_max, b_dev = interval_stats(base)
    b_drift_end = base[-1] - (base.size - 1) / RATE  # wall time minus frame-count time at the end
    b_slope = np.polyfit(base, base - np.arange(base.size) / RATE, 1)[0]

    print(f"cueing timing: headless {RATE:g} Hz, {signal.kind} signal of {signal.duration:g} s "
          f"({t[seq].size} frames after the start, {t.size} logged)")
    print(f"{'':34s}{'cueing runner':>16s}{'naive tick(60)':>18s}")
    print(f"{'achieved rate [Hz]':34s}{rate:16.3f}{b_rate:18.3f}")
    print(f"{'rate error vs nominal [%]':34s}{100 * (rate / RATE - 1):+16.3f}{100 * (b_rate / RATE - 1):+18.3f}")
    print(f"{'frame interval std [ms]':34s}{1e3 * jit_std:16.3f}{1e3 * b_std:18.3f}")
    print(f"{'frame interval max [ms]':34s}{1e3 * jit_max:16.3f}{1e3 * b_max:18.3f}")
    print(f"{'max |interval - 1/60| [ms]':34s}{1e3 * dev_max:16.3f}{1e3 * b_dev:18.3f}")
    print(f"{'schedule drift [ms/s]':34s}{1e3 * slope:+16.4f}{1e3 * b_slope:+18.4f}")
    print(f"{'signal time error at end [ms]':34s}{1e3 * np.max(np.abs(ts[seq] - t[seq])):16.4f}"
          f"{1e3 * b_drift_end:18.3f}")
    late = t[seq] - n / RATE  # wake-up lateness behind the frame's grid slot
    print(f"wake-up lateness behind the grid slot: median {1e3 * np.median(late):.3f} ms, "
          f"p95 {1e3 * np.percentile(late, 95):.3f} ms, max {1e3 * late.max():.3f} ms")
    print(f"command vs signal at each frame's own stamp: max |error| {mismatch:.3g} (control units)")
    print(f"command timing at {errors.size} switches: mean {1e3 * errors.mean():.2f} ms, "
          f"max {1e3 * errors.max():.2f} ms (one frame = {1e3 / RATE:.2f} ms), wrong level shown: {wrong}")
    stats = log.frame_stats()
    print(f"lowest rate over any 1 s: {stats['rate_lowest_1s']:.2f} Hz; low-frame-rate flag "
          f"(< {100 * LOW_RATE:g} % of target): {frame_rate_warning(stats) or 'not raised'}")
    print(f"frame log fsync: every {1e3 * synced:.1f} ms on average (target {1e3 * SYNC_INTERVAL:g} ms)")
    print(f"off-screen render time per frame: mean {1e3 * render.mean():.3f} ms, "
          f"p95 {1e3 * np.percentile(render, 95):.3f} ms, max {1e3 * render.max():.3f} ms")
    ok_rate = abs(rate / RATE - 1) < 0.005
    ok_jitter = jit_std < 1e-3
    ok_drift = mismatch == 0 and np.max(np.abs(ts - t)) < 1e-6 and wrong == 0
    print(f"targets: rate within 0.5 % {'PASS' if ok_rate else 'FAIL'}; jitter std < 1 ms "
          f"{'PASS' if ok_jitter else 'FAIL'}; zero signal drift {'PASS' if ok_drift else 'FAIL'}")
    print(f"(load average while measuring: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
