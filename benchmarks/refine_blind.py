"""A blind audit of `identify refine`: cases with an effect the declared profile lacks, handed over
as a user would (CSV runs, one per control axis, and a profile TOML) and refined from the command
line with the default options (`python -m identify refine --profile P RUN ... --validate RUN ...
--out DIR`, as docs/refine.md tells a user). The data come from the shipped profiles
(s61_hover_4dof, navion_cruise_long) simulated here with what the declared model lacks: a missing
cross-coupling or off-axis control derivative, a delay or an actuator lag on one input, a scale
error on one measured output, two effects at once, a small effect, and nothing at all. Every case
has realistic noise: gusts on the force and moment equations through a first-order filter,
measurement noise through a first-order filter, and on most a pilot in the loop (attitude hold
from the measured attitude, 0.2 s reaction time), so the inputs correlate with the noise.

For each case: found / missed / false alarm, the estimate against the truth in standard errors,
the validation error before and after, and the wall time. Writes benchmarks/output/refine_blind/.

    .venv/bin/python benchmarks/refine_blind.py [--cases a,b] [--length S] [--seed N]   # --help
"""
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
from scipy import signal  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from identify import LinearModel, Run, discretize, parse_profile  # noqa: E402
from _cli import count, parser as cli_parser, positive  # noqa: E402

OUT = ROOT / "benchmarks" / "output" / "refine_blind"
DT = 0.02


@dataclass
class Case:
    """One blind case. ``add``: [free] lines the truth has and the declared profile lacks;
    ``drop``: parameter names the declared profile leaves out (the truth keeps them);
    ``truth``: the refine parameter each effect should be found as, with its true value;
    ``delays``/``lags``: s on named inputs; ``scale``: measured = (1 + s) * state."""
    name: str
    profile: str
    what: str
    add: dict = field(default_factory=dict)
    drop: tuple = ()
    delays: dict = field(default_factory=dict)
    lags: dict = field(default_factory=dict)
    scale: dict = field(default_factory=dict)
    truth: dict = field(default_factory=dict)  # parameter -> (effect, target, value)
    pilot: bool = True
    gust: float = 1.0  # times the profile's reference gust level


# per-profile: input amplitude (rad), pilot loops (input, attitude, rate, k_att, k_rate), gust std on
# each state equation (std of the filtered acceleration, bandwidth 2 rad/s)
SETUP = {
    "s61_hover_4dof": dict(amp=0.01, pilot=[("theta_s", "theta", "q", -0.15, -0.1),
                                             ("theta_c", "phi", "p", -0.1, -0.03)],
                           gust=[0.03, 0.03, 0.006, 0.003, 0.0, 0.0]),
    "navion_cruise_long": dict(amp=0.02, pilot=[("delta_e", "theta", "q", 0.15, 0.0)],
                               gust=[0.02, 0.1, 0.02, 0.0]),
}

CASES = [
    Case("cross_Mv", "s61_hover_4dof", "missing cross-coupling derivative M_v (pitch from lateral speed)",
         add={"M_v": -0.02}, truth={"M_v": ("derivative", "M_v", -0.02)}),
    Case("offaxis_Lths", "s61_hover_4dof", "missing off-axis control derivative L_theta_s",
         drop=("L_theta_s",), truth={"L_theta_s": ("derivative", "L_theta_s", -1.16)}),
    Case("delay_thc", "s61_hover_4dof", "0.06 s delay on theta_c only",
         delays={"theta_c": 0.06}, truth={"tau_theta_c": ("delay", "theta_c", 0.06)}),
    Case("lag_de", "navion_cruise_long", "first-order actuator lag 0.1 s on delta_e",
         lags={"delta_e": 0.1}, truth={"k_delta_e_lag": ("lag", "delta_e", 10.0)}),
    Case("scale_p", "s61_hover_4dof", "roll-rate gyro scale error +10 %",
         scale={"p": 0.10}, truth={"sf_p": ("scale", "p", 0.10)}),
    Case("two_effects", "s61_hover_4dof", "0.08 s delay on theta_s and missing M_v together",
         add={"M_v": -0.02}, delays={"theta_s": 0.08},
         truth={"tau_theta_s": ("delay", "theta_s", 0.08), "M_v": ("derivative", "M_v", -0.02)}),
    Case("small_Xde", "navion_cruise_long", "small missing X_delta_e (3.2: about 3.5 of its std 0.9)",
         add={"X_delta_e": 3.2}, truth={"X_delta_e": ("derivative", "X_delta_e", 3.2)}),
    Case("null_s61", "s61_hover_4dof", "nothing missing, turbulence x2 and a pilot", gust=2.0),
    Case("null_navion", "navion_cruise_long", "nothing missing, turbulence x2 and a pilot", gust=2.0),
]


def profile_text(name: str, add: dict, drop=()) -> str:
    """The shipped profile's text with ``add`` put in [free] and the ``drop`` lines removed."""
    lines = (ROOT / "profiles" / f"{name}.toml").read_text().splitlines()
    out = []
    for line in lines:
        if line.split("=")[0].strip() in drop:
            continue
        out.append(line)
        if line.strip() == "[free]":
            out += [f"{k} = {v}" for k, v in add.items()]
    return "\n".join(out) + "\n"


def excitation(n: int, j: int, m: int, amp: float, rng) -> np.ndarray:
    """A 3-2-1-1 then random 0.5 s steps on input ``j`` only (one run per control axis)."""
    u = np.zeros((n, m))
    k = int(0.5 / DT)
    seq = [1, 1, 1, -1, -1, 1, -1] + list(rng.choice([-1.0, 0.0, 1.0], size=n // k))
    start = int(1.0 / DT)
    for i, s in enumerate(seq):
        a, b = start + i * k, min(n, start + (i + 1) * k)
        if a >= n - int(1.0 / DT):
            break
        u[a:b, j] = s * amp
    return u


def ar1(n: int, pole: float, rng, width=1) -> np.ndarray:
    """Unit-variance first-order filtered white noise."""
    return signal.lfilter([np.sqrt(1 - pole ** 2)], [1.0, -pole], rng.standard_normal((n, width)), axis=0)


def simulate(case: Case, axis: int, n: int, seed: int) -> Run:
    """One run: the truth flown with an excitation on input ``axis``, gusts, a pilot and sensors."""
    setup = SETUP[case.profile]
    truth = LinearModel(parse_profile(profile_text(case.profile, case.add)))
    p = truth.profile
    rng = np.random.default_rng(seed)
    nx, m = truth.n_states, truth.n_inputs
    Phi, Gam = discretize(truth.A, truth.B, DT)
    stick = excitation(n, axis, m, setup["amp"], rng)
    gust = ar1(n, np.exp(-DT * 2.0), rng, nx) * np.asarray(setup["gust"]) * case.gust * DT
    meas_noise = ar1(n, 0.8, rng, len(p.outputs)) * 0.5 + 0.5 * rng.standard_normal((n, len(p.outputs)))
    react = int(0.2 / DT)
    delay = {name: int(round(case.delays.get(name, 0.0) / DT)) for name in p.input_names}
    lag_a = {name: np.exp(-DT / case.lags[name]) for name in case.lags}
    x = np.zeros(nx)
    lag = np.zeros(m)
    u = np.zeros((n, m))
    felt = np.zeros((n, m))
    X = np.zeros((n, nx))
    Y = np.zeros((n, len(p.outputs)))
    out_ix = {y: i for i, y in enumerate(p.outputs)}
    for k in range(n):
        X[k] = x
        u[k] = stick[k]
        if case.pilot and k >= react:
            for inp, att, rate, ka, kr in setup["pilot"]:
                j = p.input_names.index(inp)
                u[k, j] += ka * Y[k - react, out_ix[att]] + kr * Y[k - react, out_ix[rate]]
        for j, name in enumerate(p.input_names):
            d = delay[name]
            cmd = u[k - d, j] if k >= d else 0.0
            if name in lag_a:
                felt[k, j] = lag[j]
                lag[j] = lag_a[name] * lag[j] + (1 - lag_a[name]) * cmd
            else:
                felt[k, j] = cmd
        Y[k] = truth.C @ x + truth.D @ felt[k]  # the pilot sees the gust response, not the sensor noise
        x = Phi @ x + Gam @ felt[k] + gust[k]
    scale = np.std(Y, axis=0)
    Y = Y + 0.02 * scale * meas_noise
    channels = {name: u[:, j] for j, name in enumerate(p.input_names)}
    for y, i in out_ix.items():
        channels[y] = Y[:, i] * (1 + case.scale.get(y, 0.0))
    return Run(np.arange(n) * DT, channels, source=f"<{case.name} seed {seed}>")


def write_case(case: Case, length: float, seed: int) -> tuple[Path, list[Path], list[Path]]:
    where = OUT / case.name
    where.mkdir(parents=True, exist_ok=True)
    declared = where / "profile.toml"
    declared.write_text(profile_text(case.profile, {}, case.drop))
    p = parse_profile(declared.read_text())
    n = int(length / DT) + 1
    names = p.input_names + list(p.outputs)
    fit, val = [], []
    for axis, inp in enumerate(p.input_names):
        for role, bucket, s in (("fit", fit, seed + 10 * axis), ("val", val, seed + 10 * axis + 5)):
            run = simulate(case, axis, n, s)
            bucket.append(run.to_csv(where / f"{role}_{inp}.csv", names))
    return declared, fit, val


def run_refine(case: Case, declared: Path, fit: list, val: list, method: str = "ml") -> dict:
    cmd = [sys.executable, "-m", "identify", "refine", "--profile", str(declared), *map(str, fit),
           "--validate", *map(str, val), "--out", str(OUT / case.name / "out")]
    cmd += [] if method == "ml" else ["--method", method]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    started = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
    wall = time.perf_counter() - started
    (OUT / case.name / "stderr.txt").write_text(proc.stderr)
    if proc.returncode != 0:
        return {"wall": wall, "crash": proc.stderr.strip().splitlines()[-1:] or ["?"], "rc": proc.returncode}
    data = json.loads((OUT / case.name / "out" / "refine.json").read_text())
    data["wall"] = wall
    return data


def verdict(case: Case, data: dict) -> list[str]:
    if "crash" in data:
        return [f"CRASH (status {data['rc']}): {data['crash'][0]}"]
    lines = []
    wanted = {(e, t): (name, v) for name, (e, t, v) in case.truth.items()}
    # a delay and a lag are the same effect to first order: either counts as found
    alias = {"delay": "lag", "lag": "delay"}
    seen = set()
    for s in data["steps"]:
        key = (s["effect"], s["target"])
        other = (alias.get(s["effect"]), s["target"])
        params = ", ".join(f"{k} = {v['value']:.4g} ± {v['std']:.2g}" for k, v in s["parameters"].items())
        if key in wanted:
            name, v = wanted[key]
            est = s["parameters"][name]
            lines.append(f"found {s['effect']} {s['target']}: {params} (truth {v:g}, "
                         f"{(est['value'] - v) / est['std']:+.1f} std)")
            seen.add(key)
        elif other in wanted:
            lines.append(f"found as {s['effect']} {s['target']}: {params} (truth: {other[0]} {wanted[other][1]:g})")
            seen.add(other)
        else:
            lines.append(f"FALSE ALARM {s['effect']} {s['target']}: {params} (score {s['statistic']:.1f} > "
                         f"{s['threshold']:.1f})")
    for key in set(wanted) - seen:
        lines.append(f"MISSED {key[0]} {key[1]} (truth {wanted[key][1]:g}); stopped: {data.get('stopped')}")
    if not data["steps"] and not wanted:
        lines.append("nothing found (correct)")
    return lines


# what refused a candidate that passed the score test, from its recorded reason
GATES = [("estimate", ("could not be estimated", "re-fit failed", "not determined", "not determinable")),
         ("validity", ("outside their validity",)),
         ("disagree", ("metric disagree",)), ("LR", ("likelihood ratio",)),
         ("Wald", ("Wald",)), ("choosing", ("choosing data",)), ("judging", ("judging data",))]


def gate(reason: str) -> str:
    return next((g for g, keys in GATES if any(k in reason for k in keys)), "implausible")


def tally(case: Case, runs: list[dict]) -> list[str]:
    """Over seeds: how often each true effect was found, false alarms, and the score-test passes
    (accepted + refused candidates; the score stage's family level is the loop's ``alpha``)
    with the gate that stopped each and the metric it passed in."""
    ok = [d for d in runs if "crash" not in d]
    lines = [f"{len(runs)} seeds, {len(runs) - len(ok)} crashed"]
    for name, (effect, target, v) in case.truth.items():
        alias = {"delay": "lag", "lag": "delay"}.get(effect)
        hits = [s for d in ok for s in d["steps"] if s["target"] == target and s["effect"] in (effect, alias)]
        z = [(s["parameters"][name]["value"] - v) / s["parameters"][name]["std"] for s in hits if name in s["parameters"]]
        lines.append(f"{effect} {target}: found {len(hits)}/{len(ok)}; error/std " +
                     (f"mean {np.mean(z):+.2f}, rms {np.sqrt(np.mean(np.square(z))):.2f}, |.|>2: "
                      f"{sum(abs(x) > 2 for x in z)}" if z else "-"))
    wanted = {(e, t) for e, t, _ in case.truth.values()}
    false = sum(1 for d in ok for s in d["steps"]
                if (s["effect"], s["target"]) not in wanted and ({"delay": "lag", "lag": "delay"}.get(s["effect"]),
                                                                 s["target"]) not in wanted)
    passes = [len(d["steps"]) + len(d["rejected"]) for d in ok]
    any_pass = sum(1 for d in ok if d["rejected"] or (not case.truth and d["steps"]))
    stopped: dict = {}
    for d in ok:
        for r in d["rejected"]:
            key = (gate(r.get("reason", "")), r.get("metric", "?"))
            stopped[key] = stopped.get(key, []) + [f"{r['effect']} {r['target']}"]
    alpha = ok[0]["alpha"] if ok else float("nan")
    lines.append(f"false alarms accepted: {false} in {len(ok)} runs; score-test passes {sum(passes)} "
                 f"(runs with a refused candidate: {any_pass}; family level alpha {alpha:g} per round)")
    for (g, metric), who in sorted(stopped.items()):
        names = ", ".join(f"{n} x{who.count(n)}" for n in dict.fromkeys(who))
        lines.append(f"  stopped by {g:9s} ({metric} metric): {len(who)}: {names}")
    return lines


def main(names, length: float, seed: int, seeds: int = 1, method: str = "ml") -> None:
    print(f"refine_blind: {length:g} s runs at {1 / DT:g} Hz, one fit and one validation run per "
          f"control axis, seeds {seed}..{seed + seeds - 1}, --method {method}; load average {os.getloadavg()[0]:.1f}")
    rows = []
    for case in CASES:
        if names and case.name not in names:
            continue
        if seeds > 1:
            runs = []
            for s in range(seed, seed + seeds):
                data = run_refine(case, *write_case(case, length, s), method=method)
                runs.append(data)
            lines = tally(case, runs)
            print(f"\n[{case.name}] {case.what} ({case.profile}); {sum(d['wall'] for d in runs):.0f} s")
            for line in lines:
                print("  " + line)
            rows.append({"case": case.name, "tally": lines, "runs": [
                {k: d.get(k) for k in ("steps", "rejected", "wall", "crash")} for d in runs]})
            continue
        declared, fit, val = write_case(case, length, seed)
        data = run_refine(case, declared, fit, val, method)
        lines = verdict(case, data)
        err = ""
        if "error_before" in data:
            b, a = data["error_before"]["validation"]["overall"], data["error_after"]["validation"]["overall"]
            err = f"validation error {b:.4g} -> {a:.4g}"
        print(f"\n[{case.name}] {case.what} ({case.profile}); {data['wall']:.0f} s; {err}")
        for line in lines:
            print("  " + line)
        for r in data.get("rejected", [])[:4]:
            print(f"  refused: {r['effect']} {r['target']}: {r.get('reason', '')[:120]}")
        rows.append({"case": case.name, "verdict": lines, "wall": data["wall"], "error": err})
    (OUT / "summary.json").write_text(json.dumps(rows, indent=1))
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}; details in {OUT}")


def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("--cases", default="", help="comma-separated case names (default all: "
                    + ", ".join(c.name for c in CASES) + ")")
    ap.add_argument("--length", type=positive, default=30.0, help="length of each run, s")
    ap.add_argument("--seed", type=count, default=1, help="first seed of the simulated runs")
    ap.add_argument("--seeds", type=count, default=1, help="number of seeds from --seed; above 1, a tally per "
                    "case: effects found, false alarms, score-test passes and the check that refused each")
    ap.add_argument("--method", default="ml", choices=["ml", "fem"], help="the estimator refine uses "
                    "(fem: filter error, process noise modelled)")
    return ap


if __name__ == "__main__":
    args = parser().parse_args()
    main([c for c in args.cases.split(",") if c], args.length, args.seed, max(args.seeds, 1), args.method)
