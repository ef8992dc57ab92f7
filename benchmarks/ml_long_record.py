"""ML on a long record: peak memory and result.json size for one hour at 100 Hz.

Two cases, each in its own process (the peak resident memory of a process never falls):

``navion``: the Navion longitudinal model (stable, so plain output error: one segment per run),
one run of ``HOURS`` hours at 100 Hz (360 000 samples for 1 h), a 3211 on the elevator every
20 s, process noise (turbulence) and 5 % measurement noise; a priori values 20 % off.

``s61``: the S 61 8-state hover model (unstable, so multiple shooting: segments of ~3.2 s from
the a priori model's modes, ~1100 in an hour, each with its 8 initial states: ~9100 unknowns,
which ML solves by eliminating each segment's states, never forming the dense information
matrix), flown for ``HOURS`` hours at 100 Hz by
a stabilising pilot (an LQR on the true model, acting on the true states) on top of a 3211 on
the longitudinal cyclic at 1 s and on the lateral cyclic at 10 s of every 20 s; the run records
the total stick. Process noise on the body accelerations, 5 % measurement noise on every output;
a priori values 20 % off (alternating signs). The air is calm (``TURB``): output error does not
model process noise, and under strong turbulence its estimates are biased far beyond their bounds.

ML with the coloured-residual bounds (the default), then ``result.save``. Printed per case:
wall time, iterations, convergence, peak resident memory of the case's process
(``resource.getrusage``, so it includes numpy's imports, ~60 MB) and the size of
``result.json``; the limits of issue 11 are 1 GB and 1 MB.

``python benchmarks/ml_long_record.py [HOURS] [navion|s61|both]`` (default 1 h, both; ``--help``: options).
BLAS single-threaded.
"""
import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import scipy.linalg  # noqa: E402

from identify import ML, LinearModel, Run, load_profile, simulate_run  # noqa: E402
from identify.model.simulate import discretize  # noqa: E402
from ml_speed import steps_3211  # noqa: E402  (this folder: the script's own)
from _cli import parser as cli_parser, positive  # noqa: E402

LIMIT_MB, JSON_LIMIT_KB = 1024, 1024
PILOT_R = 100.0  # LQR input weight of the S 61's pilot (state weight 1): a weak stabiliser
# S 61 turbulence, white per sample: (m/s^2 on u, v; rad/s^2 on p, q). Calm air: with 5 x as much
# (0.5, 0.02) output error, which does not model process noise, was off by 160 % mean relative
# error (measured on 3 min; the pilot's feedback correlates the disturbance with the stick)
TURB = (0.1, 0.005)


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


def long_run(truth, hours: float, dt: float = 0.01):
    t = np.arange(int(round(hours * 3600 / dt)) + 1) * dt
    u = steps_3211(np.mod(t, 20.0), 1.0, 0.5, 0.02)  # a 3211 (width 0.5 s) at the start of every 20 s
    clean = simulate_run(truth, t[:20001], u[:20001, None])
    noise = {y: 0.05 * float(np.std(clean[y])) for y in truth.profile.outputs}
    return simulate_run(truth, t, u[:, None], noise=noise, process_noise=[0.05, 0.05, 0.002, 0.0], seed=1)


def s61_run(truth, hours: float, dt: float = 0.01, seed: int = 1) -> Run:
    """The unstable S 61 hover flown for ``hours`` by a stabilising pilot (a discrete LQR on the
    true states) on top of 3211s on both cyclics every 20 s; records the total stick and noisy outputs."""
    p = truth.profile
    t = np.arange(int(round(hours * 3600 / dt)) + 1) * dt
    phase = np.mod(t, 20.0)
    design = np.column_stack([steps_3211(phase, 1.0, 0.5, 0.03), steps_3211(phase, 10.0, 0.5, 0.03)])
    Phi, Gamma = discretize(truth.A, truth.B, dt)
    R = PILOT_R * np.eye(truth.n_inputs)  # a weak pilot: the stick is mostly the designed signal
    X = scipy.linalg.solve_discrete_are(Phi, Gamma, np.eye(truth.n_states), R)
    K = np.linalg.solve(R + Gamma.T @ X @ Gamma, Gamma.T @ X @ Phi)
    rng = np.random.default_rng(seed)
    w_std = np.zeros(truth.n_states)
    w_std[[p.state_names.index(s) for s in ("u", "v")]] = TURB[0] * dt  # turbulence: m/s^2 over a sample
    w_std[[p.state_names.index(s) for s in ("p", "q")]] = TURB[1] * dt  # rad/s^2
    w = rng.standard_normal((len(t), truth.n_states)) * w_std
    x, u = np.zeros((len(t), truth.n_states)), np.empty_like(design)
    for k in range(len(t)):
        u[k] = design[k] - K @ x[k]
        if k + 1 < len(t):
            x[k + 1] = Phi @ x[k] + Gamma @ u[k] + w[k]
    y = x @ truth.C.T + u @ truth.D.T
    ref = y[:int(round(20 / dt))]
    y = y + 0.05 * ref.std(axis=0) * rng.standard_normal(y.shape)
    channels = {name: u[:, j] for j, name in enumerate(p.input_names)}
    channels.update({name: y[:, j] for j, name in enumerate(p.outputs)})
    return Run(t, channels, source=f"<S 61 stabilised hover, {hours:g} h>")


def case(name: str, hours: float) -> None:
    if name == "navion":
        truth = LinearModel(load_profile("navion_cruise_long"))
        run = long_run(truth, hours)
        start = truth.profile.with_values(dict(zip(truth.names, truth.theta * 1.2)))
        title, note = "Navion longitudinal (stable)", ""
    else:
        truth = LinearModel(load_profile("s61_hover_8state"))
        run = s61_run(truth, hours)
        signs = np.where(np.arange(len(truth.theta)) % 2, 1.0, -1.0)
        start = truth.profile.with_values(dict(zip(truth.names, truth.theta * (1 + 0.2 * signs))))
        title = "S 61 8-state hover (unstable, stabilised by a pilot)"
        note = ", and the pilot's feedback correlates it with the inputs"
    base = peak_mb()
    t0 = time.perf_counter()
    est = ML(start).fit(run)
    res = est.result_
    wall = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as out:
        res.save(out)
        size_kb = (Path(out) / "result.json").stat().st_size / 1024
        json.loads((Path(out) / "result.json").read_text(), parse_constant=lambda c: 1 / 0)  # strict JSON
    peak = peak_mb()
    err = np.abs(res.theta - truth.theta) / res.std
    rel = np.abs(res.theta / truth.theta - 1)
    print(f"ML long record: {title}, {hours:g} h at 100 Hz ({len(run)} samples), {res.info['form']} "
          f"output error ({res.info['n_segments']} segments, {est.problem_.n_beta} unknowns), coloured-residual bounds")
    print(f"  fit: {wall:.1f} s, {res.info['iterations']} iterations, converged {res.info['converged']} "
          f"({res.info['stop']})")
    print(f"  estimates vs truth: mean |relative error| {100 * rel.mean():.1f} % (max {100 * rel.max():.1f} %), "
          f"max |error| / std = {err.max():.1f} (output error ignores the process noise{note}: a bias "
          f"the Cramer-Rao bounds do not cover)")
    print(f"  peak memory: {peak:.0f} MB (after simulating the run: {base:.0f} MB); limit {LIMIT_MB} MB: "
          f"{'met' if peak < LIMIT_MB else 'NOT met'}")
    print(f"  result.json: {size_kb:.1f} kB, strict JSON; limit {JSON_LIMIT_KB} kB: "
          f"{'met' if size_kb < JSON_LIMIT_KB else 'NOT met'}")


def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("hours", nargs="?", type=positive, default=1.0, help="record length in hours, at 100 Hz")
    ap.add_argument("case", nargs="?", choices=("navion", "s61", "both"), default="both",
                    help="which case (both: each in its own process)")
    return ap


def main(argv=None):
    args = parser().parse_args(argv)
    hours, which = args.hours, args.case
    if which == "both":  # each case in its own process: its own peak memory
        for name in ("navion", "s61"):
            subprocess.run([sys.executable, __file__, str(hours), name], check=True)
    else:
        case(which, hours)


if __name__ == "__main__":
    main()
