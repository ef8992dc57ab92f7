"""Frequency-domain identification: batch FDEE against ML, and the live estimate in the cockpit.

1. Batch: on the (unstable) S 61 4-DOF, Monte Carlo over noise realisations of two runs of
   staggered 3211s on both cyclics (3 % measurement noise, and the same with process noise): FDEE
   and ML fitted to the same runs in the same process; prints the median fit time of each, the
   ratio, and for FDEE the spread of its estimates against its own standard errors (empirical /
   reported) and the largest |estimate - truth| / std error.
2. Live: a sequence designed for both cyclics (signaldesign) flown by the simulated pilot on the
   real monotonic clock at 60 Hz, off-screen display, once without and once with ``--live``; prints
   the live work per frame (p50/p99, target under 2 ms), the drawing time per frame with and
   without the panel, when "test point complete" lit, and the end-of-run live estimates against
   post-flight ML on the same run. Then 30 flights on the fake clock with other pilot and noise
   seeds: how often the live estimate lies within 2 live standard errors of ML, the spread of the
   difference against theory, both estimators' calibration against the truth, and for every miss
   which of the two is off the truth.
3. Writes the live display screenshot benchmarks/output/frequency/live_display.png (a frame after
   "complete" lit; copy it to docs/figures/live/ to renew the README's figure).

Run: ``python benchmarks/frequency.py`` (about 6 minutes on two loaded cores; ``--quick`` for a short check;
``--help`` for the options).
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from cueing.live import fly_live  # noqa: E402
from cueing.session import fly  # noqa: E402
from cueing.sources import PilotSource  # noqa: E402
from identify import ML, LinearModel, load_profile, simulate_run  # noqa: E402
from identify.estimators.frequency.equation_error import FDEE  # noqa: E402
from signaldesign.baselines import m3211  # noqa: E402
from signaldesign.design import SequenceDesign  # noqa: E402
from _cli import parser as cli_parser  # noqa: E402

PROFILE = "s61_hover_4dof"
RATE = 60.0
AMPLITUDE = 0.01  # rad: the S 61 is unstable; small inputs keep the response a small perturbation


def batch(model: LinearModel, n: int, process_noise: float) -> None:
    t = np.arange(0, 20, 0.02)
    t_fd, t_ml, est, std = [], [], [], []
    for seed in range(n):
        runs = []
        for k in range(2):
            U = np.column_stack([m3211(0.6, AMPLITUDE, "theta_s", delay=1.0 + k)(t),
                                 m3211(0.5, AMPLITUDE, "theta_c", delay=4.0 + k)(t)])
            runs.append(simulate_run(model, t, U, noise_fraction=0.03, process_noise=process_noise,
                                     seed=100 * seed + k, derivatives=False))
        c0 = time.perf_counter()
        fd = FDEE(model.profile).fit(runs).result_
        c1 = time.perf_counter()
        ML(model.profile).fit(runs)
        c2 = time.perf_counter()
        t_fd.append(c1 - c0)
        t_ml.append(c2 - c1)
        est.append(fd.theta)
        std.append(fd.std)
    est, std = np.array(est), np.array(std)
    ratio = est.std(axis=0) / std.mean(axis=0)
    z = np.abs(est - model.theta) / std
    print(f"  process noise {process_noise:g}: FDEE {np.median(t_fd) * 1e3:.0f} ms, ML {np.median(t_ml) * 1e3:.0f} ms "
          f"per fit (median of {n}); ML / FDEE = {np.median(t_ml) / np.median(t_fd):.0f}x")
    print(f"    FDEE empirical / reported std: median {np.median(ratio):.2f}, range {ratio.min():.2f}..{ratio.max():.2f}; "
          f"largest |error| / std {z.max():.2f}; share within 3 std {np.mean(z < 3):.3f}")


def design(apriori: LinearModel, quick: bool):
    d = SequenceDesign(inputs=("theta_s", "theta_c"), duration=7.0, record=20.0, amplitude=AMPLITUDE,
                       delay=1.0, n_iter=300 if quick else 1500, seed=1).fit(apriori)
    return d.signals_


def live_real_clock(signals, truth, folder: Path):
    common = dict(display="headless", audio=False, countdown=1.0, tail=12.0, rate=RATE)
    plain = fly(signals, PilotSource(skill=0.6, seed=2), folder / "plain.csv", **common)
    shots = folder / "shots"
    flight, live, ml = fly_live(signals, PilotSource(skill=0.6, seed=2), folder / "live.csv", PROFILE,
                                simulate=truth, seed=4, screenshot_dir=shots, screenshot_every=0.5, **common)
    work, cpu = np.array(live.times_) * 1e3, np.array(live.cpu_times_) * 1e3
    draw0 = np.array(plain.runner.render_times_) * 1e3
    draw1 = np.array(flight.runner.render_times_) * 1e3
    stats = flight.log.frame_stats()
    print(f"  live work per frame (response, transforms, re-solve share, log, panel): p50 {np.percentile(work, 50):.3f} ms, "
          f"p99 {np.percentile(work, 99):.3f} ms, max {work.max():.2f} ms over {work.size} frames (target p99 < 2 ms)")
    print(f"    the same in CPU time of the frame loop's thread (other processes' load excluded): "
          f"p50 {np.percentile(cpu, 50):.3f} ms, p99 {np.percentile(cpu, 99):.3f} ms, max {cpu.max():.2f} ms")
    print(f"  drawing per frame without / with the panel: p50 {np.median(draw0):.3f} / {np.median(draw1):.3f} ms, "
          f"p99 {np.percentile(draw0, 99):.3f} / {np.percentile(draw1, 99):.3f} ms")
    print(f"  frames: {stats['frames']:.0f}, achieved {stats['rate_achieved']:.2f} Hz, late frames {stats['late_frames']:.0f}")
    print(f"  test point complete lit at {live.complete_at_} s (sequence ends at "
          f"{max(s.end_time for s in signals):.1f} s, run at {flight.run.duration:.1f} s)")
    _compare(live, ml)
    _keep_screenshot(shots, live, flight)


def _compare(live, ml) -> None:
    if ml is None:
        print("  post-flight ML failed: see the .live.md")
        return
    print(f"  {'parameter':<12}{'live':>11}{'live std':>10}{'ML':>11}{'ML std':>10}{'(live-ML)/std':>15}")
    ml_of = dict(zip(ml.names, zip(ml.theta, ml.std)))
    for n in live.targets:
        i = live.names.index(n)
        v, s = live.latest.theta[i], live.latest.std[i]
        m, ms = ml_of[n]
        print(f"  {n:<12}{v:11.5g}{s:10.3g}{m:11.5g}{ms:10.3g}{(v - m) / s:15.2f}")


def _keep_screenshot(shots: Path, live, flight) -> None:
    frames = sorted(shots.glob("frame_*.png"))
    if not frames or live.complete_at_ is None:
        return
    # the last frame while the sequence was still flying and "complete" was lit
    t_frames = flight.log.time[[int(f.stem.split("_")[1]) for f in frames]]
    ok = [f for f, t in zip(frames, t_frames) if live.complete_at_ + 0.5 < t]
    target = ROOT / "benchmarks" / "output" / "frequency" / "live_display.png"  # never a tracked file
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(ok[0] if ok else frames[-1], target)
    print(f"  screenshot written to {target.relative_to(ROOT)}")


def live_fake_clock(signals, truth, folder: Path, n: int) -> None:
    """Flights with other pilot and noise seeds: how often the live estimate is within 2 live
    standard errors of ML, and, for every miss, which of the two is off the truth.

    Theory: ML is the more efficient of the two (ratio r = ML std / live std < 1), so if both
    standard errors are right, (live - ML) / live std has a spread of sqrt(1 - r^2) (Hausman), and a
    miss is ML's or live's own error, not a defect, unless one of them is off its truth by more
    than its standard errors allow."""
    d, z_live, z_ml, ratio, complete = [], [], [], [], []
    for k in range(n):
        flight, live, ml = fly_live(signals, PilotSource(skill=0.6, seed=10 + k), folder / f"mc{k}.csv", PROFILE,
                                    simulate=truth, seed=20 + k, fast=True, audio=False, countdown=1.0,
                                    tail=12.0, rate=RATE)
        names = [n_ for n_ in live.names if n_[0] in "LM"]
        idx = [live.names.index(n_) for n_ in names]
        ml_of = dict(zip(ml.names, zip(ml.theta, ml.std)))
        m_theta, m_std = np.array([ml_of[n_] for n_ in names]).T
        true = np.array([truth.theta[truth.profile.free_names.index(n_)] for n_ in names])
        v, s = live.latest.theta[idx], live.latest.std[idx]
        d.append((v - m_theta) / s)
        z_live.append((v - true) / s)
        z_ml.append((m_theta - true) / m_std)
        ratio.append(m_std / s)
        complete.append(live.complete_at_)
    d, z_live, z_ml, ratio = map(np.array, (d, z_live, z_ml, ratio))
    prim = [names.index(n_) for n_ in live.targets]
    ok = np.abs(d[:, prim]) <= 2
    rms = lambda x: float(np.sqrt(np.mean(x ** 2)))  # noqa: E731
    print(f"  {n} flights: all {len(prim)} targeted parameters within 2 live std of ML in {ok.all(axis=1).sum()} "
          f"of {n} flights ({ok.mean():.1%} of the targeted estimates); all {len(names)} moment-equation "
          f"derivatives {np.mean(np.abs(d) <= 2):.1%} (largest {np.abs(d).max():.2f})")
    print(f"    spread of (live - ML) / live std: {rms(d):.2f} (targets {rms(d[:, prim]):.2f}); if both stds are right "
          f"and ML efficient: sqrt(1 - r^2) = {np.sqrt(1 - np.mean(ratio ** 2)):.2f} (r = ML std / live std, "
          f"mean {ratio.mean():.2f})")
    print(f"    calibration against the truth, RMS of error / own std: live {rms(z_live):.2f} (mean {z_live.mean():+.2f}), "
          f"ML {rms(z_ml):.2f} (mean {z_ml.mean():+.2f}); largest: live {np.abs(z_live).max():.2f}, "
          f"ML {np.abs(z_ml).max():.2f}")
    for k, j in zip(*np.where(np.abs(d) > 2)):
        print(f"    miss: flight {k} {names[j]}: (live - ML) / live std {d[k, j]:+.2f}; live - truth "
              f"{z_live[k, j]:+.2f} live std, ML - truth {z_ml[k, j]:+.2f} ML std"
              f"{'  (targeted)' if j in prim else ''}")
    print(f"  complete lit at (s): {', '.join('never' if c is None else f'{c:.1f}' for c in complete)}")


def main(quick: bool = False) -> None:
    apriori = LinearModel(load_profile(PROFILE))
    truth = apriori.with_theta(apriori.theta * np.random.default_rng(5).uniform(0.85, 1.15, apriori.theta.size))
    print(f"1. batch FDEE vs ML on {PROFILE} (unstable), two 20-s runs, 3 % noise")
    for pn in (0.0, 0.02):
        batch(apriori, 4 if quick else 20, pn)
    print("2. live estimate: a designed sequence on both cyclics, simulated pilot, 60 Hz real clock, headless")
    signals = design(apriori, quick)
    with tempfile.TemporaryDirectory() as tmp:
        live_real_clock(signals, truth, Path(tmp))
        print("   fake-clock flights, other pilot and noise seeds:")
        live_fake_clock(signals, truth, Path(tmp), 3 if quick else 30)


def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("--quick", action="store_true",
                    help="a short check: 4 batch realisations instead of 20, 3 fake-clock flights instead of 30, "
                         "and a design search of 300 iterations instead of 1500")
    return ap


if __name__ == "__main__":
    main(quick=parser().parse_args().quick)
