"""Filter-error method (FEM) against output-error ML in turbulence: Monte Carlo.

Three cases, each flown ``N`` times (a new turbulence and noise realisation each time):

``navion``: the Navion longitudinal model (stable), six 30 s runs at 50 Hz: three with a 3211 of
0.7 s steps on the elevator (short period), three with one of 1.5 s steps (phugoid).
``s61``: the S 61 8-state hover model (unstable), two 15 s runs at 50 Hz, one per cyclic axis
(3211 on each), open loop.
``s61_pilot``: the S 61 flown by the simulated pilot in the loop: cueing's pilot model
(:class:`cueing.pilot.PilotModel`, crossover integrator with delay, neuromuscular lag and remnant)
flies a 3211 on each cyclic, and a weak stabilising feedback (a discrete LQR on the true states,
as in ``ml_long_record.py``) is added to the stick; two 30 s runs, one per axis. The recorded
stick carries the pilot's reaction to the gusts: output error's inputs are correlated with its
"measurement noise".

Turbulence, Dryden-like: a first-order Gauss-Markov gust velocity per velocity state (u, w for
the Navion; u, v for the S 61), corner ``--gust-corner`` rad/s, entering as a relative wind
(``dx/dt = A x + B u - A[:, velocity] x_gust``: the aerodynamic derivatives act on the airspeed).
Its level is set per case so that the gust response is ``--gust-share`` (default 0.2) of the
input-driven response (RMS over outputs, averaged; the achieved range is printed). Measurement
noise: 2 % of each output's input-driven RMS. A priori values: the truth 20 % off, alternating signs.

Per case, ML (default options: coloured-residual bounds, automatic multiple shooting) and FEM on
the same data. FEM's model (``--fem-model``): ``dryden`` (default) carries the gust states with
their corner frequency (known, as Dryden's V/L is) and the derivatives acting on the airspeed,
process noise on the gust states only (F estimated); ``white``: independent white process noise
on every equation the gusts drive (those with a velocity derivative), a mis-specified model for
coloured, correlated gusts. Printed: per derivative the bias
(mean error / Monte-Carlo std), Monte-Carlo std / mean reported bound, then the median relative
error, convergence count and the wall-time ratio FEM/ML (sums over the realisations, measured in
this run). ``--calm N`` realisations without turbulence give FEM against ML (max |difference| in
ML standard errors).

``python benchmarks/filter_error.py [--n 50] [--calm 5] [--cases navion,s61,s61_pilot]
[--save results.jsonl]``: results are appended per realisation to ``--save`` and a rerun resumes
(skips what is there). Run with ``nice -n 10``; BLAS is set single-threaded here.
"""
import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from cueing.pilot import PilotModel  # noqa: E402
from identify import ML, LinearModel, Run, load_profile  # noqa: E402
from identify.errors import ConvergenceWarning, PseudostepError  # noqa: E402
from identify.estimators.filter_error import FEM  # noqa: E402
from identify.model.simulate import discretize  # noqa: E402
from ml_speed import steps_3211  # noqa: E402  (this folder)
from _cli import count, parser as cli_parser, positive  # noqa: E402

OUTPUT = Path(__file__).resolve().parent / "output"
DT = 0.02
NOISE_SHARE = 0.02
PILOT_R = 100.0  # LQR input weight (state weight 1): a weak stabiliser, as in ml_long_record.py
CASES = {
    # a flight-test programme's runs: three repeats of a short-period 3211 and three of a slower one
    # that reaches the phugoid (X_u, Z_u, M_u), each 30 s with its own gusts and noise, the input-driven
    # response within the profile's [limits]; one 30 s run held too little information for 2 % (4.5 %,
    # on its Cramer-Rao bound)
    "navion": dict(profile="navion_cruise_long", gusts=("u", "w"),
                   runs=[(30.0, [(1.0, 0.7, 0.02)])] * 3 + [(30.0, [(1.0, 1.5, 0.01)])] * 3),
    "s61": dict(profile="s61_hover_8state", gusts=("u", "v"),
                runs=[(15.0, [(1.0, 0.5, 0.02), None]), (15.0, [None, (1.0, 0.5, 0.02)])]),
    "s61_pilot": dict(profile="s61_hover_8state", gusts=("u", "v"), pilot=True,
                      runs=[(30.0, [(1.0, 0.5, 0.02), None]), (30.0, [None, (1.0, 0.5, 0.02)])]),
}


class Case:
    """The truth of a case augmented with its gust states, discretised exactly (inputs held)."""

    def __init__(self, name: str, corner: float, share: float, length: float = 1.0):
        spec = CASES[name]
        self.length = length
        self.name, self.spec = name, spec
        self.truth = LinearModel(load_profile(spec["profile"]))
        tr, n = self.truth, self.truth.n_states
        self.gust_idx = [tr.profile.state_names.index(s) for s in spec["gusts"]]
        ng = len(self.gust_idx)
        Aa = np.zeros((n + ng, n + ng))
        Aa[:n, :n], Aa[:n, n:], Aa[n:, n:] = tr.A, -tr.A[:, self.gust_idx], -corner * np.eye(ng)
        Ba = np.vstack([tr.B, np.zeros((ng, tr.n_inputs))])
        self.Phi, self.Gamma = discretize(Aa, Ba, DT)
        Fg = np.zeros((n + ng, n + ng))
        Fg[n:, n:] = 2 * corner * np.eye(ng)  # unit-variance gusts
        M = np.zeros((2 * (n + ng), 2 * (n + ng)))
        M[:n + ng, :n + ng], M[:n + ng, n + ng:], M[n + ng:, n + ng:] = -Aa, Fg, Aa.T
        E = scipy.linalg.expm(M * DT)
        Qd = E[n + ng:, n + ng:].T @ E[:n + ng, n + ng:]
        w, V = np.linalg.eigh(0.5 * (Qd + Qd.T))
        self.Qh = V * np.sqrt(np.clip(w, 0, None))
        self.n, self.ng = n, ng
        # FEM's process noise: the equations the gusts drive (a velocity derivative in the row)
        self.noise_states = [s for i, s in enumerate(tr.profile.state_names) if np.any(tr.A[i, self.gust_idx] != 0)]
        self.corner = corner
        self.K = None
        if spec.get("pilot"):
            Phi, Gam = discretize(tr.A, tr.B, DT)
            R = PILOT_R * np.eye(tr.n_inputs)
            X = scipy.linalg.solve_discrete_are(Phi, Gam, np.eye(n), R)
            self.K = np.linalg.solve(R + Gam.T @ X @ Gam, Gam.T @ X @ Phi)
        # gust level for the share of the input-driven response; noise from the input response
        clean = [self.fly(r, 0.0, np.random.default_rng(1000 + k), noise=False) for k, r in enumerate(spec["runs"])]
        gust = [self.fly(r, 1.0, np.random.default_rng(2000 + k), noise=False, inputs=False)
                for k, r in enumerate(spec["runs"])]
        self.y_rms = np.sqrt(np.mean(np.vstack([c[1] for c in clean]) ** 2, axis=0))
        g_rms = np.sqrt(np.mean(np.vstack([g[1] for g in gust]) ** 2, axis=0))
        self.sigma_g = share / float(np.mean(g_rms / self.y_rms))

    def fly(self, run_spec, sigma_g: float, rng, noise: bool = True, inputs: bool = True):
        """``(u (N, m), y (N, ny))`` of one run: the designed 3211s (flown by the pilot model when the
        case has a pilot), the stabilising feedback, gusts of ``sigma_g``, measurement noise."""
        duration, axes = run_spec
        tr, n = self.truth, self.n
        t = np.arange(int(round(self.length * duration / DT)) + 1) * DT
        # the manoeuvre repeated every `duration` s over a record `length` times as long
        design = np.column_stack([steps_3211(np.mod(t, duration), *a) if (a and inputs) else np.zeros_like(t)
                                  for a in axes])
        if self.K is not None and inputs:  # cueing's pilot flies the designed signal (delay, lag, remnant)
            pilot = PilotModel(skill=0.7, seed=int(rng.integers(2 ** 31)))
            pilot.reset(np.maximum(np.abs(design).max(axis=0), 1e-9))
            signal = design

            def command(s):
                return signal[min(max(int(round(s / DT)), 0), len(t) - 1)]

            design = np.array([pilot.step(float(tk), command) for tk in t])
        xa = np.zeros(n + self.ng)
        xa[n:] = sigma_g * rng.standard_normal(self.ng)  # stationary gusts at the start
        X, U = np.empty((len(t), n + self.ng)), np.empty_like(design)
        eta = rng.standard_normal((len(t), n + self.ng)) * sigma_g
        for k in range(len(t)):
            X[k] = xa
            U[k] = design[k] - (self.K @ xa[:n] if self.K is not None else 0.0)
            xa = self.Phi @ xa + self.Gamma @ U[k] + self.Qh @ eta[k]
        y = X[:, :n] @ tr.C.T + U @ tr.D.T
        if noise:
            y = y + NOISE_SHARE * self.y_rms * rng.standard_normal(y.shape)
        return U, y, t

    def runs(self, seed: int, sigma_g: float) -> list[Run]:
        rng = np.random.default_rng(seed)
        p, out = self.truth.profile, []
        for k, spec in enumerate(self.spec["runs"]):
            U, y, t = self.fly(spec, sigma_g, rng)
            channels = {name: U[:, j] for j, name in enumerate(p.input_names)}
            channels.update({name: y[:, j] for j, name in enumerate(p.outputs)})
            out.append(Run(t, channels, source=f"<{self.name} seed {seed} run {k + 1}>"))
        return out

    def apriori(self):
        tr = self.truth
        signs = np.where(np.arange(len(tr.theta)) % 2, 1.0, -1.0)
        return tr.profile.with_values(dict(zip(tr.names, tr.theta * (1 + 0.2 * signs))))

    def gust_profile(self, profile, corner: float):
        """``profile`` with the Dryden-like gust states the FEM model carries: ``<v>g`` per gust
        velocity, ``d<v>g/dt = -corner <v>g + F w`` (corner known, fixed), and every derivative on a
        velocity acting on the airspeed ``v - <v>g`` (a tie on both columns): the same free
        derivatives, process noise on the gust states only."""
        p = profile
        g = {s: f"{s}g" for s in self.spec["gusts"]}
        ties = {}
        for name in p.free:
            entry = p.parse_entry(name)
            col = p.state_names[entry.col]
            if entry.matrix == "A" and col in g:
                ties[name] = {name: 1.0, f"{p.equation(p.state_names[entry.row])}_{g[col]}": -1.0}
        states = {**p.states, **{v: p.states[s] for s, v in g.items()}}
        fixed = {**p.fixed, **{f"{v}_{v}": -corner for v in g.values()}}
        # the gusts' initial values held at 0: with F > 0 the filter estimates the gusts anyway, and
        # in calm air (F -> 0) they would be a transient output error does not have
        return replace(p, states=states, ties=ties, fixed=fixed, process_noise=dict.fromkeys(g.values(), 0.1),
                       initial_state={**p.initial_state, **dict.fromkeys(g.values(), 0.0)},
                       name=p.name + " + gust states")


def fit(cls, profile, runs, **options) -> dict:
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            r = cls(profile, **options).fit(runs).result_
    except PseudostepError as exc:
        return {"failed": str(exc), "wall": time.perf_counter() - t0}
    return {"theta": r.theta.tolist(), "std": r.std.tolist(), "converged": r.converged,
            "wall": time.perf_counter() - t0}


def realisation(case: Case, seed: int, calm: bool, model: str) -> dict:
    runs = case.runs(seed, 0.0 if calm else case.sigma_g)
    prof = case.apriori()
    fem = fit(FEM, case.gust_profile(prof, case.corner), runs) if model == "dryden" else \
        fit(FEM, prof, runs, process_noise=dict.fromkeys(case.noise_states))
    rec = {"case": case.name, "seed": seed, "calm": calm, "ml": fit(ML, prof, runs), "fem": fem}
    if calm:  # FEM with F -> 0 is output error over whole runs: ML's plain form (no multiple shooting)
        rec["ml_plain"] = fit(ML, prof, runs, segment="plain")
    return rec


def report(case: Case, recs: list[dict], calm: list[dict]) -> None:
    tr = case.truth
    print(f"\n== {case.name}: {tr.profile.name}; {len(recs)} turbulent realisations; gust sigma "
          f"{case.sigma_g:.3g} (velocity units), gust/input response {100 * case.share:.0f} % (RMS over outputs); "
          f"FEM process noise: {case.fem_model}")
    stats = {}
    for m in ("ml", "fem"):
        ok = [r[m] for r in recs if "theta" in r[m]]
        th, sd = np.array([o["theta"] for o in ok]), np.array([o["std"] for o in ok])
        err = th - tr.theta
        mc = err.std(axis=0, ddof=1)
        stats[m] = dict(bias=err.mean(axis=0) / mc, ratio=mc / np.mean(sd, axis=0),
                        medrel=float(np.median(np.abs(err / tr.theta))), n=len(ok),
                        conv=sum(o["converged"] for o in ok), wall=sum(r[m]["wall"] for r in recs),
                        failed=len(recs) - len(ok))
    print(f"{'derivative':<18}{'truth':>10} | {'ML bias/std':>11}{'std/bound':>10} | "
          f"{'FEM bias/std':>12}{'std/bound':>10}")
    for i, name in enumerate(tr.names):
        print(f"{name:<18}{tr.theta[i]:10.4g} | {stats['ml']['bias'][i]:11.2f}{stats['ml']['ratio'][i]:10.2f} | "
              f"{stats['fem']['bias'][i]:12.2f}{stats['fem']['ratio'][i]:10.2f}")
    for m in ("ml", "fem"):
        s = stats[m]
        print(f"{m.upper():>4}: median relative error {100 * s['medrel']:.2f} %; max |bias|/std "
              f"{np.max(np.abs(s['bias'])):.2f}; std/bound {np.min(s['ratio']):.2f}..{np.max(s['ratio']):.2f}; "
              f"converged {s['conv']}/{s['n']}, failed {s['failed']}; wall {s['wall']:.1f} s")
    fem_ok = stats["fem"]
    print(f"FEM criteria: |bias| < 0.5 std on every derivative: {bool(np.all(np.abs(fem_ok['bias']) < 0.5))}; "
          f"std/bound in 0.8..1.25: {bool(np.all((fem_ok['ratio'] >= 0.8) & (fem_ok['ratio'] <= 1.25)))}; "
          f"median relative error <= 2 %: {fem_ok['medrel'] <= 0.02}")
    print(f"wall time FEM / ML: {stats['fem']['wall'] / stats['ml']['wall']:.2f} (sums over the realisations)")
    if calm:
        diffs = [np.max(np.abs(np.array(r["fem"]["theta"]) - r["ml"]["theta"]) / np.array(r["ml"]["std"]))
                 for r in calm if "theta" in r["fem"] and "theta" in r["ml"]]
        print(f"calm air ({len(calm)} realisations): max |FEM - ML| / ML std per realisation: "
              + ", ".join(f"{d:.3f}" for d in diffs))
        plain = [np.max(np.abs(np.array(r["fem"]["theta"]) - r["ml_plain"]["theta"]) / np.array(r["ml_plain"]["std"]))
                 for r in calm if "theta" in r["fem"] and "theta" in r.get("ml_plain", {})]
        if plain:
            print("  against ML's plain form (one segment per run, as the filter): "
                  + ", ".join(f"{d:.3f}" for d in plain))
        for m in ("ml", "fem"):
            th = np.array([r[m]["theta"] for r in calm if "theta" in r[m]])
            if len(th):
                rel = 100 * np.median(np.abs(th / tr.theta - 1))
                print(f"  calm air {m.upper()} median relative error {rel:.2f} %")


def _cases(text: str) -> list[str]:
    names = text.split(",")
    if set(names) - set(CASES):
        raise argparse.ArgumentTypeError(f"{text}: comma-separated among {', '.join(CASES)}")
    return names


def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("--n", type=count, default=50, help="turbulent realisations per case")
    ap.add_argument("--calm", type=count, default=5, help="calm-air realisations per case")
    ap.add_argument("--cases", type=_cases, default=",".join(CASES), help="the cases, comma-separated")
    ap.add_argument("--gust-corner", type=positive, default=2.0, help="gust corner frequency, rad/s")
    ap.add_argument("--gust-share", type=float, default=0.2, help="gust response / input response (RMS)")
    ap.add_argument("--length", type=positive, default=1.0,
                    help="record length factor: each run this many times as long, its manoeuvre repeated")
    ap.add_argument("--fem-model", choices=("dryden", "white"), default="dryden",
                    help="FEM's process-noise model: the gust states (corner known) or independent white "
                         "noise on every equation the gusts drive")
    ap.add_argument("--save", default=str(OUTPUT / "filter_error_mc.jsonl"),
                    help="results file (appended; a rerun resumes)")
    return ap


def main(argv=None):
    args = parser().parse_args(argv)
    path = Path(args.save)
    path.parent.mkdir(parents=True, exist_ok=True)
    done = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    print(f"filter error vs output error, Monte Carlo: {args.n} turbulent + {args.calm} calm realisations per "
          f"case, gust corner {args.gust_corner} rad/s, {DT * 1000:.0f} ms samples, 2 % measurement noise, "
          f"records x {args.length:g}")
    for name in args.cases:
        case = Case(name, args.gust_corner, args.gust_share, args.length)
        case.share = args.gust_share
        case.fem_model = ("gust states " + ", ".join(f"{v}g" for v in case.spec["gusts"]) + f" (corner "
                          f"{args.gust_corner} rad/s known)") if args.fem_model == "dryden" else \
            "independent white noise on " + ", ".join(case.noise_states)
        # a record from another design (runs, record length, gusts, FEM model) is not resumed
        design = repr((case.spec["runs"], args.length, args.gust_share, args.gust_corner, args.fem_model))
        done = [r for r in done if r["case"] != name or r.get("design") == design]
        have = {(r["seed"], r["calm"]) for r in done if r["case"] == name}
        todo = [(s, False) for s in range(args.n)] + [(10_000 + s, True) for s in range(args.calm)]
        for seed, calm in todo:
            if (seed, calm) in have:
                continue
            rec = {**realisation(case, seed, calm, args.fem_model), "design": design}
            done.append(rec)
            with path.open("a") as f:
                f.write(json.dumps(rec) + "\n")
            print(f"  {name} seed {seed}{' calm' if calm else ''}: ML {rec['ml']['wall']:.1f} s, "
                  f"FEM {rec['fem']['wall']:.1f} s", flush=True)
        recs = [r for r in done if r["case"] == name and not r["calm"] and r["seed"] < args.n]
        calm = [r for r in done if r["case"] == name and r["calm"] and r["seed"] < 10_000 + args.calm]
        report(case, recs, calm)


if __name__ == "__main__":
    main()
