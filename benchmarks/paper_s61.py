"""The S 61 hover study of Kaletka & Rix, section 5 (Figs 7-9), repeated with pseudostep.

Simulation model: the bundled 8-state profile ``s61_hover_8state`` (rotor tip-path plane theta_R,
phi_R plus u, v, p, q, theta, phi; two unstable pairs at 0.36 and 0.50 rad/s). Reference for the
rigid-body identifications: its residualised 4-DOF model ``s61_hover_4dof`` (the paper's
"mathematically reduced model", R_n).

Signals (every one starts at t = DELAY s, all with the same amplitude AMP on the axis flown):
A-D doublets lasting 2, 4, 6, 8 s (pulse width 1, 2, 3, 4 s); E an arbitrary, not optimised,
three-level step sequence (0.5 s steps, 7 s); F pseudostep's D-optimal three-level sequence for the
a priori 8-state model on the axis flown (``signaldesign.design.SequenceDesign``, criterion
"nominal", holds of at least 0.5 s on a 0.1 s grid); G the worst-case (robust) design over the a
priori and 8 models with every derivative scaled by 1 -/+ 0.3 (holds of at least 0.3 s). F and G: 7 s, every output's peak response capped at that of a 3211 with 1 s
pulses (without a cap, the D-optimal input for an unstable model over a 20 s record is one long
pulse that lets the divergence grow). Runs: A-G on longitudinal cyclic theta_s (7), on lateral
cyclic theta_c (7), and two combined runs: E on theta_s with F on theta_c, and F on theta_s with E
on theta_c. 20 s each, sampled every DT s.

Measurements: the runs carry every state and the exact state derivatives (``<state>_dot``) as a
simulation provides them; white measurement noise of the levels in NOISE is added to states and
derivatives (inputs exact). Every identification is also done on the noise-free runs: the paper
mentions no noise and its six-digit statement implies none, so those are the figures to set beside
the paper's; the noisy ones are what a flight test would give.

Identification: IV with a priori values from LS (``identify.IV``, start="ls"), a zero shift per run
and equation, for (1) the 8-state model over 20 s, (2) over the first 10 s, (3) the 4-DOF rigid
body model over 20 s, (4) over 10 s. A single-axis run does not excite the other cyclic, so that
cyclic's control derivatives are removed from the free set (held at their a priori value, the
reduced / true value) and left out of the average error. Average error (1/N) sum |(I_n - R_n)/R_n|
over the N identified derivatives: against the reduced model for the 4-DOF identifications, against
the truth for the 8-state ones. Two-run evaluations (first 10 s of each run): B, F, G (the
longitudinal and the lateral run of that signal) and E+F (the two combined runs). ML
(``identify.ML``, multiple shooting, a priori values from LS on the same data; outputs the states
and u_dot, v_dot, p_dot, q_dot, i.e. the channels IV uses, and once the states only) repeats the
4-DOF evaluations for comparison. Further: the two-run pairs over their whole 20 s (structural
error left), IV over ``--seeds`` more noise realisations (Table C), and how well each identified
4-DOF model reproduces the 8-state time histories (Table D, Fig. 9).

    python benchmarks/paper_s61.py             # tables and Figs 7-9 -> benchmarks/output/paper_s61/
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # small matrices: threads only add contention on 2 busy cores

import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field, replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from identify import IV, LS, ML, LinearModel, PseudostepError, load_profile, simulate, simulate_run  # noqa: E402
from signaldesign.baselines import doublet, m3211, step_sequence  # noqa: E402
from signaldesign.design import SequenceDesign  # noqa: E402
from signaldesign.evaluate import Evaluator, perturbed_models  # noqa: E402
from _cli import count, parser as cli_parser  # noqa: E402

OUT = ROOT / "benchmarks" / "output" / "paper_s61"
DT, DURATION, SHORT, DELAY, SEED = 0.025, 20.0, 10.0, 1.0, 61
AMP = np.deg2rad(0.2)  # rad, every signal on every axis: keeps the unstable response small over 20 s
AXES = ("theta_s", "theta_c")
AXIS_LABEL = {"theta_s": "lon", "theta_c": "lat"}
# 1-sigma white measurement noise: flight-test instrumentation grade (rate gyros, attitude
# gyros, accelerometers; rotor tilt as a measured angle); derivatives at the level of a smoothed
# accelerometer or differentiated gyro
_DEG = np.pi / 180
NOISE = {"u": 0.05, "v": 0.05, "p": 0.05 * _DEG, "q": 0.05 * _DEG, "theta": 0.05 * _DEG, "phi": 0.05 * _DEG,
         "theta_R": 0.05 * _DEG, "phi_R": 0.05 * _DEG,
         "u_dot": 0.01, "v_dot": 0.01, "p_dot": 0.2 * _DEG, "q_dot": 0.2 * _DEG,
         "theta_dot": 0.05 * _DEG, "phi_dot": 0.05 * _DEG, "theta_R_dot": 0.2 * _DEG, "phi_R_dot": 0.2 * _DEG}
E_LEVELS = (1, 0, 1, 1, -1, 0, 0, -1, 1, 0, -1, -1, 0, 1)  # signal E: arbitrary, 0.5 s steps
FIG_DERIVS = {"lon": ("M_u", "M_q", "M_p", "M_theta_s"), "lat": ("L_v", "L_p", "L_q", "L_theta_c")}
SIGNALS = "ABCDEFG"
TWO_RUN = {"B": ("B lon", "B lat"), "F": ("F lon", "F lat"), "G": ("G lon", "G lat"),
           "E+F": ("E lon + F lat", "F lon + E lat")}
DPI = 80
ML_DERIVATIVE_OUTPUTS = ("u_dot", "v_dot", "p_dot", "q_dot")
FIG9_RUN = "F lon"  # Fig. 9: pseudostep's design, evaluated over the first 10 s (Table D: every run)


# -- signals ----------------------------------------------------------------------------------
def design(model: LinearModel, axis: str, robust: bool):
    """Signal F (nominal D-optimal, holds of at least 0.5 s) or G (worst case over the a priori and
    8 models with every derivative scaled by 1 -/+ 0.3, holds of at least 0.3 s: the robust design
    with shorter steps, so F and G differ) on ``axis``, at amplitude AMP, every output's peak
    response over the record capped at that of a 3211 with 1 s pulses."""
    ref = Evaluator(model, axis, record=DURATION, dt=0.05, limits={})
    peaks = ref.peaks([m3211(1.0, AMP, axis)])
    limits = {y: float(pk) for y, pk in zip(model.profile.outputs, peaks) if pk > 0}
    models = [model] + perturbed_models(model, 8, spread=0.3, seed=SEED) if robust else None
    d = SequenceDesign(axis, duration=7.0, record=DURATION, amplitude=AMP, dt=0.05, grid=0.1,
                       min_pulse=0.3 if robust else 0.5, criterion="worst" if robust else "nominal",
                       models=models, limits=limits, seed=SEED, n_iter=2000, restarts=2, jobs=1)
    d.fit(model)
    s = d.signals_[0]
    s.delay = DELAY
    return s


def make_signals(model: LinearModel) -> dict[str, dict[str, object]]:
    """{letter: {axis: Signal}} for A-G on both cyclic axes."""
    out = {}
    for axis in AXES:
        sigs = {L: doublet(w, AMP, axis, DELAY) for L, w in zip("ABCD", (1.0, 2.0, 3.0, 4.0))}
        sigs["E"] = step_sequence(E_LEVELS, 0.5, AMP, axis, DELAY, kind="arbitrary steps")
        sigs["F"] = design(model, axis, robust=False)
        sigs["G"] = design(model, axis, robust=True)
        for L, s in sigs.items():
            out.setdefault(L, {})[axis] = s
    return out


def describe(s) -> str:
    """Levels with their holds: ``+1 (2.4 s) 0 (1.6 s) ...`` (a design on a fine grid reads as steps)."""
    edges = np.flatnonzero(np.diff(s.levels)) + 1
    holds = [(int(seg[0]), seg.size * s.dt) for seg in np.split(s.levels, edges)]
    return f"{s.kind}, {s.levels.size * s.dt:g} s: " + " ".join(f"{v:+d} ({h:.3g} s)" for v, h in holds)


# -- runs -------------------------------------------------------------------------------------
@dataclass
class Case:
    """One simulated run: ``label`` ("B lon"), the axes flown, clean and noisy versions."""

    label: str
    axes: tuple[str, ...]
    clean: object
    noisy: object
    peaks: dict = field(default_factory=dict)


def simulate_cases(model: LinearModel, sigs) -> list[Case]:
    t = np.arange(int(round(DURATION / DT)) + 1) * DT
    plan = [(f"{L} {AXIS_LABEL[a]}", {a: sigs[L][a]}) for a in AXES for L in SIGNALS]
    plan += [("E lon + F lat", {"theta_s": sigs["E"]["theta_s"], "theta_c": sigs["F"]["theta_c"]}),
             ("F lon + E lat", {"theta_s": sigs["F"]["theta_s"], "theta_c": sigs["E"]["theta_c"]})]
    names = model.profile.input_names
    cases = []
    for k, (label, flown) in enumerate(plan):
        u = np.zeros((len(t), len(names)))
        for axis, s in flown.items():
            u[:, names.index(axis)] = s(t)
        meta = {"signal": label}
        clean = simulate_run(model, t, u, meta=meta)
        noisy = simulate_run(model, t, u, noise=NOISE, seed=SEED * 100 + k, meta=meta)
        peaks = {c: float(np.abs(clean[c]).max()) for c in ("u", "v", "q", "p", "theta", "phi")}
        cases.append(Case(label, tuple(flown), clean, noisy, peaks))
    return cases


# -- identification ---------------------------------------------------------------------------
def free_for(profile, axes):
    """The profile with the control derivatives of cyclics not flown moved to the fixed set."""
    drop = [n for n in profile.free if any(n.endswith("_" + a) for a in AXES if a not in axes)]
    return replace(profile, free={k: v for k, v in profile.free.items() if k not in drop},
                   fixed={**profile.fixed, **{k: profile.free[k] for k in drop}})


def average_error(values: dict[str, float], reference: dict[str, float]) -> float:
    """(1/N) sum |(I_n - R_n) / R_n| over the identified derivatives, in %."""
    return 100 * float(np.mean([abs((v - reference[k]) / reference[k]) for k, v in values.items()]))


def max_error(values: dict[str, float], reference: dict[str, float]) -> float:
    return float(max(abs((v - reference[k]) / reference[k]) for k, v in values.items()))


def fit_iv(profile, runs):
    """IV parameters {name: value}, or the error text when the evaluation fails."""
    with np.errstate(over="ignore", invalid="ignore"):  # IV shortens its restarts when a simulation diverges
        try:
            return IV(profile).fit(runs).result_.parameters()
        except PseudostepError as exc:  # a failed evaluation is a result too: report it, go on
            return str(exc)


def fit_ml(profile, runs):
    """ML with a priori values from LS on the same runs."""
    try:
        start = LS(profile).fit(runs).result_.parameters()
        return ML(profile.with_values(start)).fit(runs).result_.parameters()
    except PseudostepError as exc:
        return str(exc)


def spans(runs, t_end):
    return [r.slice(0.0, t_end) for r in runs]


def ml_profile(p4):
    """The 4-DOF profile with the measured derivatives u_dot, v_dot, p_dot, q_dot as further ML
    outputs: ML then sees the same channels as IV (theta_dot, phi_dot are q, p: nothing new)."""
    return replace(p4, outputs=tuple(p4.outputs) + ML_DERIVATIVE_OUTPUTS)


def single_runs(cases, p8, p4, do_ml: bool):
    """{label: {key: params or error text}} for every single-run evaluation. Keys (model, span,
    noise): model "8"/"4" IV, "ml" ML with derivative outputs, "mls" ML on the states only."""
    out = {}
    for c in cases:
        f8, f4, fml = free_for(p8, c.axes), free_for(p4, c.axes), free_for(ml_profile(p4), c.axes)
        res = {}
        for T in (DURATION, SHORT):
            for noise in ("clean", "noisy"):
                run = spans([getattr(c, noise)], T)
                res[("8", T, noise)] = fit_iv(f8, run)
                res[("4", T, noise)] = fit_iv(f4, run)
                if do_ml:
                    res[("ml", T, noise)] = fit_ml(fml, run)
            if do_ml:
                res[("mls", T, "noisy")] = fit_ml(f4, spans([c.noisy], T))
        out[c.label] = res
    return out


def two_runs(cases, p4, do_ml: bool):
    by = {c.label: c for c in cases}
    out = {}
    for name, labels in TWO_RUN.items():
        res = {}
        for noise in ("clean", "noisy"):
            runs = spans([getattr(by[l], noise) for l in labels], SHORT)
            res[("4", SHORT, noise)] = fit_iv(p4, runs)
            if do_ml:
                res[("ml", SHORT, noise)] = fit_ml(ml_profile(p4), runs)
        # the same two runs over their whole 20 s: what remains is the structural (rotor-lag) error
        res[("4", DURATION, "clean")] = fit_iv(p4, [by[l].clean for l in labels])
        out[name] = res
    return out


# -- tables -----------------------------------------------------------------------------------
def cell(params, reference, digits=False) -> str:
    if isinstance(params, str):
        return "failed"
    if digits:
        err = max_error(params, reference)
        return f"{-np.log10(max(err, 1e-16)):.1f}"
    return f"{average_error(params, reference):.1f}"


def _n_free(params) -> str:
    return "-" if isinstance(params, str) else str(len(params))


def table_iv(cases, results, truth8, reduced) -> list[list[str]]:
    """Table A: IV, single runs: 8-state digits (noise-free) and average errors."""
    rows = [["run", "N 8st/4dof", "8st 20 s digits", "8st 10 s digits", "8st 20 s noisy %", "8st 10 s noisy %",
             "4-DOF 20 s %", "4-DOF 10 s %", "4-DOF 20 s noisy %", "4-DOF 10 s noisy %"]]
    for c in cases:
        r = results[c.label]
        rows.append([c.label, f"{_n_free(r[('8', DURATION, 'clean')])}/{_n_free(r[('4', DURATION, 'clean')])}",
                     cell(r[("8", DURATION, "clean")], truth8, True), cell(r[("8", SHORT, "clean")], truth8, True),
                     cell(r[("8", DURATION, "noisy")], truth8), cell(r[("8", SHORT, "noisy")], truth8),
                     cell(r[("4", DURATION, "clean")], reduced), cell(r[("4", SHORT, "clean")], reduced),
                     cell(r[("4", DURATION, "noisy")], reduced), cell(r[("4", SHORT, "noisy")], reduced)])
    return rows


def table_ml(labels, results, reduced, spans_s) -> list[list[str]]:
    """Table B: 4-DOF average error, IV beside ML, noise-free and noisy."""
    head = ["run"]
    for T in spans_s:
        head += [f"IV {T:g} s", f"ML {T:g} s", f"IV {T:g} s noisy", f"ML {T:g} s noisy", f"MLs {T:g} s noisy"]
    rows = [head]
    for label in labels:
        r = results[label]
        row = [label]
        for T in spans_s:
            row += [cell(r[(m, T, n)], reduced) for n in ("clean", "noisy") for m in ("4", "ml")]
            row.append(cell(r[("mls", T, "noisy")], reduced))
        rows.append(row)
    return rows


def table_derivs(results, labels, keys, derivs, reduced) -> list[list[str]]:
    """Identified values of ``derivs`` per run and evaluation key, with the reduced model's."""
    rows = [["run", "evaluation"] + list(derivs) + ["av. error %"]]
    rows.append(["reduced model", ""] + [f"{reduced[d]:.4g}" for d in derivs] + [""])
    for label in labels:
        for key, name in keys:
            params = results[label][key]
            if isinstance(params, str):
                rows.append([label, name] + ["failed"] * len(derivs) + [params[:60]])
                continue
            rows.append([label, name] + [f"{params[d]:.4g}" for d in derivs]
                        + [f"{average_error(params, reduced):.1f}"])
    return rows


def table_two(results, reduced, do_ml) -> list[list[str]]:
    derivs = FIG_DERIVS["lon"] + FIG_DERIVS["lat"]
    keys = [(("4", SHORT, "clean"), "IV"), (("4", SHORT, "noisy"), "IV noisy")]
    if do_ml:
        keys += [(("ml", SHORT, "clean"), "ML"), (("ml", SHORT, "noisy"), "ML noisy")]
    keys.append((("4", DURATION, "clean"), "IV, 2 x 20 s"))
    return table_derivs(results, list(TWO_RUN), keys, derivs, reduced)


def markdown(rows) -> str:
    lines = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
    lines += ["| " + " | ".join(r) + " |" for r in rows[1:]]
    return "\n".join(lines)


def plain(rows) -> str:
    widths = [max(len(r[j]) for r in rows) for j in range(len(rows[0]))]
    fmt = lambda r: "  ".join(v.rjust(w) if j else v.ljust(w) for j, (v, w) in enumerate(zip(r, widths)))  # noqa: E731
    return "\n".join([fmt(rows[0]), "-" * sum(w + 2 for w in widths)] + [fmt(r) for r in rows[1:]])


# -- figures ----------------------------------------------------------------------------------
def _figure(w, h):
    fig = Figure(figsize=(w, h), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _ratio_bars(ax, params_list, labels, derivs, reduced, title):
    """Bars of identified / reduced per derivative (1 = the reduced model), one group per run."""
    x = np.arange(len(labels))
    width = 0.8 / len(derivs)
    for j, d in enumerate(derivs):
        vals = [np.nan if isinstance(p, str) else p[d] / reduced[d] for p in params_list]
        ax.bar(x + (j - (len(derivs) - 1) / 2) * width, np.clip(vals, -1.5, 3.5), width, label=d)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(0.0, color="0.5", lw=0.5)
    ax.set_ylim(-1.5, 3.5)
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel("identified / reduced\n(clipped -1.5..3.5)", fontsize=7)
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=7)


def _error_bars(ax, params_list, labels, reduced, title):
    errs = [np.nan if isinstance(p, str) else average_error(p, reduced) for p in params_list]
    x = np.arange(len(labels))
    ax.bar(x, np.minimum(errs, 300), color="0.4")
    for xi, e in zip(x, errs):
        ax.text(xi, min(e, 300) + 3, "fail" if np.isnan(e) else f"{e:.0f}", ha="center", fontsize=6)
    ax.axhline(10, color="C3", lw=0.8, ls="--")
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel("av. error %", fontsize=7)
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=7)


def fig7(results, reduced, path, noise):
    fig = _figure(11, 7.5)
    axes = fig.subplots(4, 2)
    for col, side in enumerate(("lon", "lat")):
        labels = [f"{L} {side}" for L in SIGNALS]
        for k, T in enumerate((DURATION, SHORT)):
            params = [results[l][("4", T, noise)] for l in labels]
            _ratio_bars(axes[2 * k, col], params, list(SIGNALS), FIG_DERIVS[side], reduced,
                        f"{side} cyclic runs, {T:g} s: identified / reduced")
            _error_bars(axes[2 * k + 1, col], params, list(SIGNALS), reduced,
                        f"{side} cyclic runs, {T:g} s: average error over all identified derivatives")
        axes[0, col].legend(fontsize=6, ncol=4, loc="upper right")
    fig.suptitle(f"Fig. 7: S 61 hover, 4-DOF IV, one run evaluated ({noise} data)", fontsize=10)
    fig.savefig(path, dpi=DPI)


def fig8(results, reduced, path, do_ml):
    evals = [(("4", SHORT, "clean"), "IV, noise-free"), (("4", SHORT, "noisy"), "IV, noisy")]
    if do_ml:
        evals += [(("ml", SHORT, "clean"), "ML, noise-free"), (("ml", SHORT, "noisy"), "ML, noisy")]
    fig = _figure(3.2 * len(evals), 4.5)
    axes = fig.subplots(2, len(evals), squeeze=False)
    labels = list(TWO_RUN)
    for col, (key, name) in enumerate(evals):
        params = [results[l][key] for l in labels]
        _ratio_bars(axes[0, col], params, labels, FIG_DERIVS["lon"] + FIG_DERIVS["lat"], reduced,
                    f"two runs x 10 s, {name}")
        _error_bars(axes[1, col], params, labels, reduced, f"average error, {name}")
    axes[0, 0].legend(fontsize=5, ncol=4, loc="upper right")
    fig.suptitle("Fig. 8: S 61 hover, 4-DOF, two runs evaluated (first 10 s of each)", fontsize=10)
    fig.savefig(path, dpi=DPI)


def fig9(case, params, p4, reduced_model, path, T):
    """8-state simulation (+), reduced model (--), IV-identified 4-DOF model (-) on one run."""
    run = case.clean.slice(0.0, T)
    u = run.matrix(p4.input_names)
    ident = LinearModel(p4.with_values(params))
    y_red = simulate(reduced_model, u, run.dt).y
    y_id = simulate(ident, u, run.dt).y
    outs = list(p4.outputs)
    fig = _figure(9, 6)
    axes = fig.subplots(3, 2, sharex=True).T.ravel()
    every = max(1, len(run) // 60)
    for ax, name in zip(axes, outs):
        j = outs.index(name)
        scale = 1.0 if name in ("u", "v") else 180 / np.pi
        ax.plot(run.time[::every], run[name][::every] * scale, "+", color="0.3", ms=5, label="8-state simulation")
        ax.plot(run.time, y_red[:, j] * scale, "--", color="C1", label="reduced 4-DOF")
        ax.plot(run.time, y_id[:, j] * scale, "-", color="C0", lw=1.2, label="IV identified 4-DOF")
        ax.set_ylabel(f"{name} [{'m/s' if scale == 1 else ('deg/s' if name in ('p', 'q') else 'deg')}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=6)
    for ax in (axes[2], axes[5]):
        ax.set_xlabel("time [s]", fontsize=8)
    fig.suptitle(f"Fig. 9: run {case.label}, {T:g} s evaluated (av. error "
                 f"{average_error(params, dict(p4.free)):.0f} %)", fontsize=10)
    fig.savefig(path, dpi=DPI)
    sim = run.matrix(outs)
    rel = lambda y: np.sqrt(np.mean((y - sim) ** 2, axis=0)) / np.sqrt(np.mean(sim ** 2, axis=0))  # noqa: E731
    return {"reduced 4-DOF": dict(zip(outs, rel(y_red))), "IV identified 4-DOF": dict(zip(outs, rel(y_id)))}


def relative_rms(case: Case, params, p4, T: float) -> np.ndarray:
    """RMS difference (per output) between the 8-state simulation and the 4-DOF model with
    ``params`` simulated from rest over the first ``T`` s, over the simulation's RMS."""
    run = case.clean.slice(0.0, T)
    y = simulate(LinearModel(p4.with_values(params)), run.matrix(p4.input_names), run.dt).y
    sim = run.matrix(list(p4.outputs))
    return np.sqrt(np.mean((y - sim) ** 2, axis=0)) / np.sqrt(np.mean(sim ** 2, axis=0))


def table_time_histories(cases, results, p4) -> list[list[str]]:
    """Table D: do the identified 4-DOF models reproduce the time histories? Noise-free IV."""
    reduced = dict(p4.free)
    rows = [["run", "av. error 20 s %", "rel. RMS 20 s", "av. error 10 s %", "rel. RMS 10 s"]]
    for c in cases:
        row = [c.label]
        for T in (DURATION, SHORT):
            params = results[c.label][("4", T, "clean")]
            if isinstance(params, str):
                row += ["failed", "-"]
                continue
            row += [f"{average_error(params, reduced):.1f}", f"{np.mean(relative_rms(c, params, p4, T)):.3f}"]
        rows.append(row)
    row = ["reduced model (range over the runs)"]
    for T in (DURATION, SHORT):
        ref = [np.mean(relative_rms(c, reduced, p4, T)) for c in cases]
        row += ["0", f"{min(ref):.3f}..{max(ref):.3f}"]
    rows.append(row)
    return rows


def renoise(model: LinearModel, case: Case, seed: int):
    """The case's run with a new measurement-noise realisation."""
    run = case.clean
    return simulate_run(model, run.time, run.matrix(model.profile.input_names), noise=NOISE, seed=seed)


def monte_carlo(model: LinearModel, cases, p4, n_seeds: int) -> list[list[str]]:
    """4-DOF IV average errors over further noise realisations: single runs (20 s, 10 s) and the
    two-run evaluations (10 s each)."""
    reduced = dict(p4.free)
    errs: dict[tuple[str, float], list[float]] = {}
    fails: dict[tuple[str, float], int] = {}
    for s in range(n_seeds):
        noisy = {c.label: renoise(model, c, 10_000 + 100 * s + k) for k, c in enumerate(cases)}
        jobs = [(c.label, T, free_for(p4, c.axes), [noisy[c.label]]) for c in cases for T in (DURATION, SHORT)]
        jobs += [(f"two runs {name}", SHORT, p4, [noisy[l] for l in labels]) for name, labels in TWO_RUN.items()]
        for label, T, prof, runs in jobs:
            params = fit_iv(prof, spans(runs, T))
            if isinstance(params, str):
                fails[(label, T)] = fails.get((label, T), 0) + 1
            else:
                errs.setdefault((label, T), []).append(average_error(params, reduced))

    def stat(key):
        v = errs.get(key, [])
        text = f"{np.median(v):.1f} [{min(v):.1f}, {max(v):.1f}]" if v else "-"
        return text + (f" ({fails[key]} failed)" if key in fails else "")

    rows = [["run", "IV 20 s noisy %", "IV 10 s noisy %"]]
    rows += [[c.label, stat((c.label, DURATION)), stat((c.label, SHORT))] for c in cases]
    rows += [[f"two runs {name}", "", stat((f"two runs {name}", SHORT))] for name in TWO_RUN]
    return rows


def noise_text(name: str, value: float) -> str:
    if name in ("u", "v"):
        return f"{value:g} m/s"
    if name in ("u_dot", "v_dot"):
        return f"{value:g} m/s^2"
    unit = "deg" + ("/s^2" if name in ("p_dot", "q_dot") else "/s" if name in ("p", "q") or "_dot" in name else "")
    return f"{np.degrees(value):g} {unit}"


# -- main -------------------------------------------------------------------------------------
def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("--no-ml", action="store_true", help="skip the ML comparison")
    ap.add_argument("--seeds", type=count, default=5, help="further noise realisations for Table C (0: skip)")
    ap.add_argument("--out", type=Path, default=OUT, help="output folder")
    return ap


def main(argv=None):
    args = parser().parse_args(argv)
    do_ml = not args.no_ml
    started = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    p8, p4 = load_profile("s61_hover_8state"), load_profile("s61_hover_4dof")
    m8, m4 = LinearModel(p8), LinearModel(p4)
    truth8, reduced = dict(p8.free), dict(p4.free)
    print(f"S 61 hover, Kaletka & Rix section 5 with pseudostep: dt {DT} s, {DURATION:g} s runs, "
          f"amplitude {np.degrees(AMP):g} deg on every signal, seed {SEED}")
    print("measurement noise (1 sigma): " + ", ".join(f"{k} {noise_text(k, v)}" for k, v in NOISE.items()))

    t0 = time.perf_counter()
    sigs = make_signals(m8)
    print(f"\nsignals (designs {time.perf_counter() - t0:.1f} s), all starting at {DELAY:g} s:")
    for L in SIGNALS:
        for axis in AXES:
            print(f"  {L} {AXIS_LABEL[axis]}: {describe(sigs[L][axis])}")

    cases = simulate_cases(m8, sigs)
    print("\nresponse peaks over 20 s (noise-free): " + "; ".join(
        f"{c.label}: |theta| {np.degrees(c.peaks['theta']):.1f}, |phi| {np.degrees(c.peaks['phi']):.1f} deg"
        for c in cases))

    t0 = time.perf_counter()
    single = single_runs(cases, p8, p4, do_ml)
    two = two_runs(cases, p4, do_ml)
    print(f"\nidentification ({'IV and ML' if do_ml else 'IV'}): {time.perf_counter() - t0:.1f} s")
    failures = [(l, k, v) for res in (single, two) for l, r in res.items() for k, v in r.items() if isinstance(v, str)]
    for l, k, v in failures:
        print(f"  failed: {l} {k}: {v}")

    tables = {}

    def show(title, rows):
        print(f"\n{title}")
        print(plain(rows))
        tables[title] = rows

    show("Table A: IV, single runs. 8-state: 'digits' = -log10 of the largest relative error vs the truth "
         "(noise-free), 'noisy %' = average error vs the truth; 4-DOF: average error % vs the reduced model",
         table_iv(cases, single, truth8, reduced))
    if do_ml:
        show("Table B: 4-DOF single runs, average error % vs the reduced model: IV beside ML (a priori from LS; "
             "outputs the states and u_dot, v_dot, p_dot, q_dot as IV uses; MLs: the states only)",
             table_ml([c.label for c in cases], single, reduced, (DURATION, SHORT)))
    keys = [(("4", DURATION, "clean"), "IV 20 s"), (("4", SHORT, "clean"), "IV 10 s"),
            (("4", DURATION, "noisy"), "IV 20 s noisy"), (("4", SHORT, "noisy"), "IV 10 s noisy")]
    if do_ml:
        keys += [(("ml", DURATION, "clean"), "ML 20 s"), (("ml", SHORT, "clean"), "ML 10 s"),
                 (("ml", DURATION, "noisy"), "ML 20 s noisy"), (("ml", SHORT, "noisy"), "ML 10 s noisy")]
    for side in ("lon", "lat"):
        show(f"Fig. 7 table ({side}): 4-DOF identified derivatives, single {side} runs",
             table_derivs(single, [f"{L} {side}" for L in SIGNALS], keys, FIG_DERIVS[side], reduced))
    show("Combined-input runs, single-run 4-DOF evaluations",
         table_derivs(single, ["E lon + F lat", "F lon + E lat"], keys, FIG_DERIVS["lon"] + FIG_DERIVS["lat"],
                      reduced))
    show("Fig. 8 table: two runs x first 10 s, 4-DOF (all 20 derivatives free; last row of each: the whole 20 s)",
         table_two(two, reduced, do_ml))
    show("Table D: time histories of the IV-identified 4-DOF models (noise-free) simulated from rest over the "
         "span evaluated: RMS difference from the 8-state simulation / its RMS, mean over u, v, p, q, theta, phi",
         table_time_histories(cases, single, p4))
    if args.seeds > 0:
        t0 = time.perf_counter()
        show(f"Table C: 4-DOF IV average error % over {args.seeds} further noise realisations: "
             f"median [min, max]", monte_carlo(m8, cases, p4, args.seeds))
        print(f"(Monte Carlo {time.perf_counter() - t0:.1f} s)")

    md = [f"# S 61 hover study (pseudostep), measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}", ""]
    for title, rows in tables.items():
        md += [f"## {title}", "", markdown(rows), ""]
    (args.out / "tables.md").write_text("\n".join(md))
    fig7(single, reduced, args.out / "fig7_single_runs.png", "clean")
    fig7(single, reduced, args.out / "fig7_single_runs_noisy.png", "noisy")
    fig8(two, reduced, args.out / "fig8_two_runs.png", do_ml)
    by = {c.label: c for c in cases}
    params = single[FIG9_RUN][("4", SHORT, "clean")]
    if not isinstance(params, str):
        fit9 = fig9(by[FIG9_RUN], params, p4, m4, args.out / "fig9_time_histories.png", SHORT)
        print(f"\nFig. 9 run {FIG9_RUN}, first {SHORT:g} s, noise-free: RMS difference from the 8-state "
              f"simulation / RMS of the simulation, per output (both models simulated from rest)")
        for name, rel in fit9.items():
            print(f"  {name:<20} " + ", ".join(f"{y} {v:.3f}" for y, v in rel.items()))
        print("eigenvalues (1/s):")
        for name, model in (("8-state simulation", m8), ("reduced 4-DOF", m4),
                            ("IV identified 4-DOF", LinearModel(p4.with_values(params)))):
            print(f"  {name:<20} " + ", ".join(f"{m.eigenvalue.real:+.3f}{m.eigenvalue.imag:+.3f}j"
                                                for m in model.modes() if m.eigenvalue.imag >= 0))
    print(f"\nwrote {args.out}: tables.md, fig7_single_runs.png, fig7_single_runs_noisy.png, fig8_two_runs.png, "
          f"fig9_time_histories.png")
    print(f"total {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
