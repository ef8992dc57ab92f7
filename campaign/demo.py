"""The whole job on the bundled default profile, without a window: ``make demo``.

1. design: optimised three-level sequences for both cyclics from the a priori model;
2. fly: a simulated pilot flies each through the off-screen two-needle display (every frame
   logged), and the flown stick drives the "real aircraft" — a truth that differs from the a priori
   model and has a control-system time delay the a priori profile does not declare;
3. identify: LS, IV and ML from the two logged runs;
4. refine: the residuals are traced to the undeclared effect, which is added and re-identified,
   checked on a third (validation) run;
5. report: ``report.md`` with the figures, in one folder.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cueing.session import fly
from cueing.sources import PilotSource
from identify import IV, LS, ML, LinearModel, Run, format_modes, load_profile, perturbed_model, simulate_run
from identify.estimators.plots import plot_residuals, plot_time_histories
from identify.refine import Refine
from identify.refine.report import write as write_refine
from signaldesign import save_signals
from signaldesign.baselines import m3211
from signaldesign.design import SequenceDesign
from signaldesign.spectrum import half_power_band, plot_signals

DEFAULT_PROFILE = "s61_hover_8state"
AMPLITUDE = 0.01  # rad of cyclic of the validation run's 3211s (the designs take theirs from the limits)
DELAY = 0.10  # s: the truth's control-system delay, not in the a priori profile
NOISE = 0.03  # measurement noise, fraction of each response channel's standard deviation
PERTURBATION = 0.15  # the real aircraft's derivatives differ from the a priori ones by up to this


@dataclass
class Size:
    """How big the demo is: the full one, or the reduced one the tests run."""

    record: float = 20.0  # s per run
    duration: float = 7.0  # s of designed input
    n_iter: int = 1000  # annealing iterations per restart
    frame_rate: float = 50.0  # Hz display and log rate


FULL, QUICK = Size(), Size(record=12.0, duration=5.0, n_iter=300, frame_rate=30.0)


def run_demo(out: str | Path, profile: str = DEFAULT_PROFILE, quick: bool = False, seed: int = 1,
             say=print, frames: bool = False) -> Path:
    """Run the pipeline into ``out``; return the path of its ``report.md``. The display's frames
    (one a second) are kept in ``display_frames_<run>/`` only with ``frames``; otherwise one of
    them becomes ``display.png`` and the rest are not written to ``out``."""
    import os
    import shutil
    import tempfile

    for var in ("SDL_VIDEODRIVER", "SDL_AUDIODRIVER"):  # no window, no sound: the display is off-screen
        os.environ.setdefault(var, "dummy")
    size = QUICK if quick else FULL
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    apriori = LinearModel(load_profile(profile))
    truth = _real_aircraft(apriori, seed)
    report = _intro(apriori)

    say("1/5 designing the input signals ...")
    designs = _design(apriori, size, seed)
    report += _design_section(designs, out)

    say("2/5 flying them with the simulated pilot (off-screen display) ...")
    fit_runs, flights = [], []
    shots = out if frames else Path(tempfile.mkdtemp(prefix="demo-frames-"))
    for i, design in enumerate(designs):
        flight = fly(design.signals_, PilotSource(skill=0.6, seed=seed + i), out / f"flown_{i + 1}.csv",
                     model=apriori, fast=True, pilot="simulated pilot", display="headless", audio=False,
                     preview=2.0, rate=size.frame_rate, countdown=1.0, tail=size.record - design.duration - 1.0,
                     screenshot_dir=shots / f"display_frames_{i + 1}", screenshot_every=1.0)
        flights.append(flight)
        name = f"testpoint_{i + 1}.csv"
        fit_runs.append(_response(truth, flight.run, seed + 10 + i,
                                  f"{name} (stick flown in {flight.path.name}, simulated aircraft response)"))
        fit_runs[-1].to_csv(out / name)
    validation = _validation_run(truth, size, seed)
    validation.to_csv(out / "testpoint_validation.csv")
    report += _fly_section(flights, out, designs[0].signals_[0], shots / "display_frames_1")
    if not frames:
        shutil.rmtree(shots, ignore_errors=True)

    say("3/5 identifying with LS, IV and ML ...")
    results = {name: est(apriori.profile).fit(fit_runs).result_ for name, est in
               (("LS", LS), ("IV", IV), ("ML", ML))}
    report += _identify_section(results, truth, out)

    say("4/5 refining: tracing the residuals to what the model lacks ...")
    refiner = Refine(apriori.profile).fit(fit_runs, validate=[validation])
    write_refine(refiner, out / "refine")
    report += _refine_section(refiner, truth, out)

    say("5/5 the frequency view: responses, FR fit, handling qualities ...")
    report += _frequency_section(fit_runs, apriori, results["ML"], refiner.result_.model, out)

    report += ["", f"Total run time: {time.perf_counter() - t0:.0f} s."]
    say("writing the report ...")
    path = out / "report.md"
    path.write_text("\n".join(report) + "\n")
    return path


# -- the truth ------------------------------------------------------------------------------------
def _real_aircraft(apriori: LinearModel, seed: int) -> LinearModel:
    """The aircraft flown: every free derivative off its a priori value by up to PERTURBATION."""
    return perturbed_model(apriori, PERTURBATION, np.random.default_rng(seed))


def _response(truth: LinearModel, flown: Run, seed: int, source: str | None = None) -> Run:
    """The measured run: the stick as flown, the aircraft's response to it DELAY s later, noise.
    ``source`` names it (plots and results say which data was fitted); default the flown run's.

    State derivatives are not measured (no such sensors): LS and IV differentiate the rates.
    """
    p = truth.profile
    stick = np.column_stack([flown.channels.get(name, np.zeros(len(flown))) for name in p.input_names])
    sim = simulate_run(truth, flown.time, stick, input_delay=DELAY, noise_fraction=NOISE, seed=seed)
    channels = {name: stick[:, j] for j, name in enumerate(p.input_names)}
    channels.update({y: sim[y] for y in p.outputs})
    channels.update({k: v for k, v in flown.channels.items() if k.endswith("_cmd")})
    meta = {**flown.meta, "truth": "a priori derivatives perturbed, plus a control delay",
            "noise_fraction": str(NOISE)}
    return Run(flown.time, channels, meta, source=source or flown.source)


def _validation_run(truth: LinearModel, size: Size, seed: int) -> Run:
    """A held-out run: 3211s on both cyclics, staggered, flown exactly."""
    p = truth.profile
    dt = 1.0 / size.frame_rate
    time_ = np.arange(int(round(size.record / dt)) + 1) * dt
    width = size.duration / 7
    u = np.column_stack([m3211(width, AMPLITUDE, name, delay=1.0 + 2.0 * j)(time_)
                         for j, name in enumerate(p.input_names)])
    stick = Run(time_, {name: u[:, j] for j, name in enumerate(p.input_names)}, {"signal": "3211 on each cyclic"},
                source="validation run")
    return _response(truth, stick, seed + 99, "testpoint_validation.csv (3211s flown exactly, simulated response)")


# -- stages -------------------------------------------------------------------------------------
def _design(apriori: LinearModel, size: Size, seed: int) -> list[SequenceDesign]:
    # the default design: amplitude an outcome, every output's peak within the profile's [limits]
    return [SequenceDesign(inputs=name, duration=size.duration, record=size.record, delay=1.0,
                           n_iter=size.n_iter, seed=seed).fit(apriori)
            for name in apriori.profile.input_names]


def _intro(apriori: LinearModel) -> list[str]:
    return ["# pseudostep demo", "",
            f"A priori model: **{apriori.profile.name}**. The aircraft actually flown (the truth of this "
            f"simulation) has every free derivative off its a priori value by up to {PERTURBATION:.0%} and a "
            f"{DELAY * 1000:.0f} ms control-system delay on both cyclics that the a priori profile does not "
            f"declare. Measurement noise {NOISE:.0%} of each response channel's standard deviation.", "",
            "A priori modes:", "", "```", format_modes(apriori.modes()), "```"]


def _design_section(designs: list[SequenceDesign], out: Path) -> list[str]:
    signals = [s for d in designs for s in d.signals_]
    save_signals(signals, out / "signals.json")
    plot_signals(signals, out / "signals.png", title="designed inputs and their energy spectra")
    lines = ["", "## 1. Design", "",
             f"The default design, one per cyclic ({designs[0].record:g} s record): three-level sequences with "
             "the most information per unit of peak response, robust to the a priori model's errors, flown at "
             "the largest amplitude that keeps every output within the profile's limits: "
             "[`signals.json`](signals.json).", "",
             "| input | grid [s] | level changes | amplitude [rad] | binding limit | half-power band [rad/s] "
             "| design time [s] |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for d, s in zip(designs, signals):
        lo, hi, _ = half_power_band(s)
        changes = int(np.count_nonzero(np.diff(np.concatenate([[0], s.levels, [0]]))))
        lines.append(f"| {s.input} | {d.width_:.2f} | {changes} | {s.amplitude:.4f} | {d.binding_} | "
                     f"{lo:.2f} – {hi:.2f} | {d.seconds_:.1f} |")
    outputs = designs[0].evaluator_.model.profile.outputs
    lines += ["", "Peak response on the a priori model against the limits:", "",
              "| output | limit | " + " | ".join(f"peak, {s.input} design" for s in signals) + " |",
              "| --- | --- | " + " | ".join("---" for _ in signals) + " |"]
    for j, y in enumerate(outputs):
        lines.append(f"| {y} | {designs[0].limits_[j]:.3g} | "
                     + " | ".join(f"{d.peaks_[j]:.3g}" + (" (binds)" if d.binding_ == y else "") for d in designs)
                     + " |")
    return lines + ["", "![designed signals](signals.png)"]


def _fly_section(flights, out: Path, first_signal, frames: Path) -> list[str]:
    import shutil

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    shots = sorted(frames.glob("*.png"))  # one a second from t = -countdown
    if shots:  # the frame a second before the second switch: needles deflected, switch in the preview
        t_shot = first_signal.switch_times()[min(1, first_signal.switch_times().size - 1)] - 1.0
        shutil.copy(shots[int(np.clip(round(t_shot + 1.0), 0, len(shots) - 1))], out / "display.png")
    fig = Figure(figsize=(8, 2.4 * len(flights)))  # on its own Agg canvas: no pyplot state
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(flights), 1, sharex=True, squeeze=False)
    lines = ["", "## 2. Flight (simulated pilot, off-screen two-needle display)", "",
             "![the display during the first run](display.png)", "",
             "| run | RMS tracking error [% of amplitude] | switch timing [ms, mean ± std] | "
             "information retained [% at the designed peak response] | peak response [% of designed] |",
             "| --- | --- | --- | --- | --- |"]
    for ax, flight in zip(axes[:, 0], flights):
        name = flight.log.inputs[0]
        ax.plot(flight.run.time, flight.run[name + "_cmd"], label="designed", lw=1.2)
        ax.plot(flight.run.time, flight.run[name], label="flown", lw=0.9)
        ax.set_ylabel(f"{name} [rad]")
        ax.legend(loc="upper right", fontsize=8)
        sc = flight.score
        kept = "n/a" if sc.information_retained is None else f"{100 * sc.information_retained:.1f}"
        peak = "n/a" if sc.peak_ratio is None else f"{100 * sc.peak_ratio:.0f}"
        lines.append(f"| `{flight.path.name}` | {100 * sc.rms:.1f} | {1000 * sc.timing_mean:+.0f} ± "
                     f"{1000 * sc.timing_std:.0f} | {kept} | {peak} |")
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(out / "flown_vs_designed.png", dpi=80)
    return lines + ["", "![flown vs designed](flown_vs_designed.png)"]


def _identify_section(results: dict, truth: LinearModel, out: Path) -> list[str]:
    plot_time_histories(results["ML"], out / "time_history_ml.png", run=0)
    plot_residuals(results["ML"], out / "residuals_ml.png")
    names = truth.names
    lines = ["", "## 3. Identification (declared model, two runs)", "",
             "| parameter | a priori | truth | " + " | ".join(f"{m} (± std error)" for m in results) + " |",
             "| --- | --- | --- | " + " | ".join("---" for _ in results) + " |"]
    apriori = dict(zip(names, next(iter(results.values())).apriori))
    for i, n in enumerate(names):
        cells = [f"{r.theta[i]:.4g} ± {r.std[i]:.2g}" for r in results.values()]
        lines.append(f"| `{n}` | {apriori[n]:.4g} | {truth.theta[i]:.4g} | " + " | ".join(cells) + " |")
    lines.append("| average relative error vs truth | " + _avg_err(np.array(list(apriori.values())), truth.theta)
                 + " | | " + " | ".join(_avg_err(r.theta, truth.theta) for r in results.values()) + " |")
    lines += ["", _why_ml(results, truth)]
    return lines + ["", "![ML time histories](time_history_ml.png)", "", "![ML residuals](residuals_ml.png)"]


def _why_ml(results: dict, truth: LinearModel) -> str:
    """Why the estimators rank as they do against the truth: all fit the declared model, which
    lacks the truth's control-system delay, and output error feels that most."""
    err = {m: _rel_err(r.theta, truth.theta) for m, r in results.items()}
    ranking = " < ".join(f"{m} {e:.1%}" for m, e in sorted(err.items(), key=lambda kv: kv[1]))
    text = (f"Average errors: {ranking}. All three fit the declared model, which lacks the truth's "
            f"{DELAY * 1000:.0f} ms control-system delay. ")
    if max(err, key=err.get) == "ML":
        text += ("ML is worst here because output error simulates the whole response from the stick: "
                 "with no delay in the model, the derivatives must bend to shift the simulated response "
                 "in time, which biases them; LS and IV fit each equation's derivatives to the measured "
                 "states at each instant, where the missing delay only mis-times the control term. ")
    return text + ("Section 4 finds the delay in ML's residuals and adds it: the refined ML is the "
                   "estimate to use.")


def _frequency_section(runs: list[Run], apriori: LinearModel, ml, refined: LinearModel, out: Path) -> list[str]:
    """Section 5: the runs' frequency responses with the a priori, ML, refined and FR-fitted models
    (FR with an equivalent delay per cyclic, as a frequency-domain analyst would fit the unknown
    control delay), J, and the handling-qualities point of the flown aircraft beside the a priori
    model's."""
    from identify.estimators.frequency.bode import plot_bode
    from identify.estimators.frequency.hq import hq_of_model, hq_of_response
    from identify.estimators.frequency.response import cost_report, frequency_response
    from identify.estimators.frequency.response_fit import FR

    p = apriori.profile
    lines = ["", "## 5. The frequency view", ""]
    try:
        fr_result = FR(p, prune=True, delays=tuple(p.input_names)).fit(runs).result_
    except Exception as exc:  # said in the report, never silent
        fr_result = None
        lines.append(f"FR fit: not done ({exc}).")
    models = {"a priori": apriori, "ML": ml.model, "refined ML": refined,
              **({"FR": fr_result.model} if fr_result else {})}
    fr = frequency_response(runs, p.input_names, list(p.outputs))
    plots = plot_bode(fr, models, out / "frequency")
    text, _ = cost_report(runs, models)
    hq = hq_of_response(fr)
    hq_model = hq_of_model(apriori)
    hq.save(out / "frequency", hq_model)
    lines += ["Frequency responses of the flown runs (composite windows, coherence), Tischler's J of each "
              "model, and the FR fit (the model fitted to the responses, CIFER's gates with pruning, an "
              "equivalent delay per cyclic: the truth's control delay is " + f"{DELAY:g} s):", "",
              "```", text, *(fr_result.info["report_lines"][1:] if fr_result else []), "```", ""]
    lines += [f"![Bode {path.stem}](frequency/{path.name})" for path in plots]
    lines += ["", "Handling qualities (ADS-33, from the flown runs; the a priori model's point beside):", "",
              "```", *hq.lines(), "```", "", "![ADS-33 roll](frequency/hq_roll.png)",
              "", "Definitions and limits: docs/frequency.md."]
    return lines


def _rel_err(estimate: np.ndarray, truth: np.ndarray) -> float:
    """The paper's average error: the mean of |estimate - truth| / |truth| over the derivatives."""
    return float(np.mean(np.abs((estimate - truth) / truth)))


def _avg_err(estimate: np.ndarray, truth: np.ndarray) -> str:
    return f"{_rel_err(estimate, truth):.1%}"


def _refined_parameters(refiner: Refine, truth: LinearModel) -> list[str]:
    """Average error of the aircraft's derivatives before and after refinement (ML both)."""
    def err(result):
        est = dict(zip(result.names, result.theta))
        # a lag on an input moves that input's derivatives onto its lag state (X_u -> X_u_lag)
        return _avg_err(np.array([est.get(n, est.get(f"{n}_lag")) for n in truth.names]), truth.theta)
    return ["", f"Average relative error of the {len(truth.names)} derivatives against the truth (ML): "
                f"declared model {err(refiner.initial_result_)}, refined model {err(refiner.result_)}. "
                f"(Refine fits every model it compares on one multiple-shooting segmentation, "
                f"{refiner.segment_:.2f} s here: cut shorter than ML's automatic choice when the declared "
                f"model's first fit diverges faster than the a priori; so its declared-model error can "
                f"differ from the ML column of section 3.)"]


def _lag_as_delay(step) -> str:
    """A lag's time constant 1/k ± its standard error (delta method), the delay it stands for."""
    if step.effect != "lag":
        return ""
    (k,) = step.parameters.values()
    return f"; time constant 1/k = {1 / k['value']:.4g} ± {k['std'] / k['value'] ** 2:.2g} s"


def _refine_section(refiner: Refine, truth: LinearModel, out: Path) -> list[str]:
    lines = ["", "## 4. Closing the loop", ""]
    if refiner.nothing_found:
        lines.append("Nothing found: no candidate effect is significant.")
    for i, s in enumerate(refiner.steps_, start=1):
        params = ", ".join(f"`{k}` = {v['value']:.4g} ± {v['std']:.2g}" for k, v in s.parameters.items())
        lines.append(f"- step {i}: **{s.effect}** on `{s.target}`: {params} "
                     f"(score {s.statistic:.4g} > threshold {s.threshold:.4g})" + _lag_as_delay(s))
    for s in refiner.rejected_:
        lines.append(f"- rejected: {s.effect} on `{s.target}`: {s.reason}")
    lines += ["", f"The truth's delay is {DELAY:g} s on each cyclic (estimates within 3 standard errors of it "
                  "confirm the step). Where the signals excite only frequencies well below 1/delay, a delay "
                  "and a first-order lag of the same time constant are indistinguishable (phase ωτ against "
                  "atan ωτ); refine then keeps the likelier, and a lag's time constant 1/k stands for the delay."]
    lines += _refined_parameters(refiner, truth)
    lines += ["",
              "| error (normalised RMS, all outputs) | before | after |", "| --- | --- | --- |"]
    for where in refiner.error_before_:
        lines.append(f"| {where} runs | {refiner.error_before_[where]['overall']:.4g} | "
                     f"{refiner.error_after_[where]['overall']:.4g} |")
    figures = sorted(p.name for p in (out / "refine").glob("*.png"))
    lines += ["", "Full evidence: [`refine/report.md`](refine/report.md), "
              "[`refine/refine.json`](refine/refine.json), final model "
              "[`refine/final_profile.toml`](refine/final_profile.toml).", ""]
    lines += [f"![{name}](refine/{name})" for name in figures]
    return lines
