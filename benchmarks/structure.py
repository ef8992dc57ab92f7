"""Model structure determination (identify structure, its defaults): does it drop what is truly zero,
keep what is not, and estimate the kept derivatives better than the full a priori profile?

Case 1, the 8-state S 61 hover (rotor tip-path plane): the truth is the bundled s61_hover_8state
model; the a priori profile declares its 18 free derivatives plus 9 that are truly zero (speed
stability M_u, dihedral L_v, cross-coupling M_p, L_q, X_q, Y_p, Y_u, direct cyclic moments
M_theta_s, L_theta_c: in this model the cyclics act only through the rotor), a third of its 27.
Per realisation: four 15 s runs at 50 Hz, a 3211 on one cyclic each (two per axis), 3 % measurement
noise on every output, light turbulence (white process noise 0.05 m/s^2 on u and v, which the
estimator does not model). No --validate: the command's default hold-out (each run cut where its
excitation is halved). Reported: the share of truly zero parameters dropped and of truly non-zero
ones kept, the median relative error of the kept non-zero derivatives against ML with the full
profile on the same runs, and the equation-error pass's time (the Done-when bound is 5 s).

Not measured here (NOT DONE in issue #31): case 2, the fixed-wing longitudinal truth with C_L and
C_m nonlinear in alpha flown at several trims (coefficient-form profiles are not implemented).
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import replace
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import warnings  # noqa: E402

import numpy as np  # noqa: E402

from _cli import counted  # noqa: E402
from identify import LinearModel, load_profile, simulate_run  # noqa: E402
from identify.estimators.ml import ML  # noqa: E402
from identify.structure import StructureSearch  # noqa: E402
from signaldesign.baselines import m3211  # noqa: E402

ZERO = ("M_u", "L_v", "M_p", "L_q", "X_q", "Y_p", "Y_u", "M_theta_s", "L_theta_c")
DT, RECORD, AMP, NOISE, GUST = 0.02, 15.0, 0.01, 0.03, 0.05


def parser():
    ap = counted(__doc__, "realisations", 30, "realisations of each case")
    ap.add_argument("--cases", default="12", help="cases to run, any of 12")
    return ap


def hover_runs(truth: LinearModel, seed: int):
    t = np.arange(0, RECORD, DT)
    p = truth.profile
    gust = np.array([GUST if s in ("u", "v") else 0.0 for s in p.state_names])
    runs = []
    for k, name in enumerate(("theta_s", "theta_c", "theta_s", "theta_c")):
        u = np.zeros((t.size, truth.n_inputs))
        u[:, p.input_names.index(name)] = m3211(0.6, AMP, name, delay=1.0 + 0.5 * k)(t)
        runs.append(simulate_run(truth, t, u, noise_fraction=NOISE, process_noise=gust, seed=1000 * seed + k,
                                 derivatives=False))
    return runs


def rel_errors(values: dict, truth: dict, names) -> list[float]:
    return [abs(values[n] - truth[n]) / abs(truth[n]) for n in names]


def case_hover(n: int) -> None:
    base = load_profile("s61_hover_8state")
    truth = LinearModel(base)
    apriori = replace(base, free={**base.free, **dict.fromkeys(ZERO, 0.0)}, name="S 61 hover 8-state, 27 free")
    nonzero = list(base.free)
    dropped = kept = 0
    err_final, err_full, ee_times, wall = [], [], [], []
    for seed in range(n):
        runs = hover_runs(truth, seed)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            s = StructureSearch(apriori).fit(runs)
            full = ML(apriori).fit(runs).result_
        wall.append(time.perf_counter() - t0)
        ee_times.append(s.equation_error_seconds_)
        d = sum(z in s.dropped_ for z in ZERO)
        k = sum(v in s.kept_ for v in nonzero)
        dropped, kept = dropped + d, kept + k
        final = dict(zip(s.result_.names, s.result_.theta))
        both = [v for v in nonzero if v in final]
        e1 = np.median(rel_errors(final, base.free, both))
        e0 = np.median(rel_errors(dict(zip(full.names, full.theta)), base.free, both))
        err_final.append(e1)
        err_full.append(e0)
        print(f"realisation {seed + 1}: zero dropped {d}/{len(ZERO)}, non-zero kept {k}/{len(nonzero)}, "
              f"added {', '.join(s.added_) or 'none'}; median rel. error kept {e1:.3%} vs full {e0:.3%}; "
              f"equation error {s.equation_error_seconds_:.2f} s, all {wall[-1]:.0f} s", flush=True)
    print(f"\ncase 1, {n} realisations: truly zero dropped {dropped}/{n * len(ZERO)} = {dropped / (n * len(ZERO)):.1%} "
          f"(goal >= 90 %); truly non-zero kept {kept}/{n * len(nonzero)} = {kept / (n * len(nonzero)):.1%} (goal >= 95 %)")
    print(f"median over realisations of the kept derivatives' median relative error: selected {np.median(err_final):.3%}, "
          f"full profile {np.median(err_full):.3%}; selected lower in {sum(a < b for a, b in zip(err_final, err_full))}/{n}")
    print(f"equation-error pass: median {np.median(ee_times):.2f} s, max {np.max(ee_times):.2f} s (goal < 5 s); "
          f"whole search + full fit median {np.median(wall):.0f} s")


# -- case 2: a fixed-wing aircraft, nonlinear in alpha ------------------------------------------------
G, RHO, S, CHORD, MASS, IYY = 9.81, 1.225, 16.7, 1.74, 1270.0, 4070.0
ALPHA_BREAK = np.radians(10.0)
NONLINEAR = ("alpha", "q", "delta_e")  # squares, x|x|, the spline at ALPHA_BREAK and the products of these
TRUE_TERMS = {"Z": {"C_L_alpha", "C_L_delta_e", "C_L_alpha_k1"}, "M": {"C_m_alpha", "C_m_q", "C_m_delta_e", "C_m_alpha_sq"}}


def lift(alpha, de):
    return 0.25 + 4.5 * alpha - 3.0 * np.maximum(alpha - ALPHA_BREAK, 0.0) + 0.36 * de


def moment(alpha, qhat, de):
    return 0.05 - 0.7 * alpha - 2.0 * alpha ** 2 - 12.0 * qhat - 1.1 * de


def forces(x, de, thrust):
    """Body-axis specific forces, pitch acceleration and the air data of state (u, w, q, theta)."""
    u, w, q, theta = x
    V = np.hypot(u, w)
    alpha = np.arctan2(w, u)
    qbar = 0.5 * RHO * V ** 2
    cl = lift(alpha, de)
    cd = 0.03 + 0.06 * cl ** 2
    cx = cl * np.sin(alpha) - cd * np.cos(alpha)
    cz = -cl * np.cos(alpha) - cd * np.sin(alpha)
    ax = (thrust + qbar * S * cx) / MASS
    az = qbar * S * cz / MASS
    qdot = qbar * S * CHORD * moment(alpha, q * CHORD / (2 * V), de) / IYY
    return ax, az, qdot, V, alpha


def trim(alpha):
    """Level flight at ``alpha``: elevator from C_m = 0, airspeed from the Z balance, thrust from X."""
    de = (0.05 - 0.7 * alpha - 2.0 * alpha ** 2) / 1.1
    cl = lift(alpha, de)
    cd = 0.03 + 0.06 * cl ** 2
    qbar = MASS * G * np.cos(alpha) / (S * (cl * np.cos(alpha) + cd * np.sin(alpha)))
    V = np.sqrt(2 * qbar / RHO)
    thrust = MASS * G * np.sin(alpha) - qbar * S * (cl * np.sin(alpha) - cd * np.cos(alpha))
    return np.array([V * np.cos(alpha), V * np.sin(alpha), 0.0, alpha]), de, thrust


def fly(alpha0, signal, seed):
    """A run at the trim of ``alpha0`` with elevator perturbation ``signal(t)`` (RK4, held input)."""
    from identify.data.runs import Run

    x, de0, thrust = trim(alpha0)
    t = np.arange(0, RECORD, DT)
    de = de0 + signal(t)

    def f(x, d):
        u, w, q, theta = x
        ax, az, qdot, _, _ = forces(x, d, thrust)
        return np.array([ax - G * np.sin(theta) - q * w, az + G * np.cos(theta) + q * u, qdot, q])

    rec = {k: np.empty(t.size) for k in ("u", "w", "q", "theta", "V", "alpha", "a_x", "a_z")}
    for k in range(t.size):
        ax, az, _, V, alpha = forces(x, de[k], thrust)
        for name, v in zip(rec, (*x, V, alpha, ax, az)):
            rec[name][k] = v
        k1 = f(x, de[k])
        k2 = f(x + 0.5 * DT * k1, de[k])
        k3 = f(x + 0.5 * DT * k2, de[k])
        k4 = f(x + DT * k3, de[k])
        x = x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    rng = np.random.default_rng(seed)
    channels = {name: v + NOISE * np.std(v) * rng.standard_normal(t.size) for name, v in rec.items()}
    channels["delta_e"] = de
    return Run(t, channels, {"trim_alpha_deg": f"{np.degrees(alpha0):g}"}, source=f"<alpha0 {np.degrees(alpha0):g} deg>")


def case_fixed_wing(n: int) -> None:
    from identify.structure.equation_error import held_out_error, problems
    from identify.structure import pool
    from signaldesign.baselines import doublet

    profile = load_profile("light_aircraft_coefficients_long")
    trims = np.radians([4.0, 8.0, 12.0])
    found = clean = 0
    ratios, times = [], []
    for seed in range(n):
        amp = np.radians(1.5)
        runs = [fly(a, m3211(0.4, amp, "delta_e", delay=1.0), 10 * seed + i) for i, a in enumerate(trims)]
        val = [fly(a, doublet(0.8, -amp, "delta_e", delay=1.0), 10 * seed + 5 + i) for i, a in enumerate(trims)]
        t0 = time.perf_counter()
        s = StructureSearch(profile, nonlinear=NONLINEAR, knots={"alpha": [float(ALPHA_BREAK)]}).fit(runs, validate=val)
        times.append(time.perf_counter() - t0)
        chosen = {sel.problem.label: set(sel.fit.terms) for sel in s.selections_}
        hit = "C_L_alpha_k1" in chosen["Z"] and "C_m_alpha_sq" in chosen["M"]
        spurious = sorted((chosen["Z"] - TRUE_TERMS["Z"]) | (chosen["M"] - TRUE_TERMS["M"]))
        found += hit
        clean += not spurious
        ext = pool.extended(profile, s.pool_)
        fit_p = {pr.label: pr for pr in problems(ext, profile, prepare_runs(ext, runs))}
        val_p = {pr.label: pr for pr in problems(ext, profile, prepare_runs(ext, val))}
        sel_err = np.sqrt(np.mean([held_out_error(fit_p[e], val_p[e], sorted(chosen[e])) ** 2 for e in ("Z", "M")]))
        true_err = np.sqrt(np.mean([held_out_error(fit_p[e], val_p[e], sorted(TRUE_TERMS[e])) ** 2 for e in ("Z", "M")]))
        ratios.append(sel_err / true_err)
        print(f"realisation {seed + 1}: C_L {sorted(chosen['Z'])}, C_m {sorted(chosen['M'])}; "
              f"spurious {', '.join(spurious) or 'none'}; held-out error selected/true {sel_err:.4g}/{true_err:.4g} "
              f"({times[-1]:.1f} s)", flush=True)
    print(f"\ncase 2, {n} realisations: both nonlinear terms found in {found}/{n} = {found / n:.0%} (goal >= 80 %); "
          f"no spurious term in {clean}/{n} = {clean / n:.0%} (goal >= 80 %)")
    print(f"held-out equation error, selected / true structure: median {np.median(ratios):.4f}, max {np.max(ratios):.4f} "
          f"(goal within 1.10); search time median {np.median(times):.2f} s")


def prepare_runs(profile, runs):
    from identify.model.pseudo_inputs import prepare

    return prepare(profile, runs)


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.realisations and "1" in args.cases:
        case_hover(args.realisations)
    if args.realisations and "2" in args.cases:
        case_fixed_wing(args.realisations)
    return 0


if __name__ == "__main__":
    sys.exit(main())
