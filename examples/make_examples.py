"""Make the example files from a known truth (run from the repository root; seeded, so the files
are reproduced exactly):

    python examples/make_examples.py

The a priori model is ``examples/profile.toml`` (the S 61 hover 4-DOF, a copy of the bundled
``s61_hover_4dof``). The "real aircraft" (``examples/truth.toml``) has every free derivative up to
15 % off the a priori and a control-system delay of 0.08 s on both cyclics that the a priori does
not declare. Measurement noise: 3 % of each measured channel's standard deviation. Files:

* ``run_lon.csv``, ``run_lat.csv``: a 3211 on longitudinal cyclic ``theta_s``, one on lateral
  cyclic ``theta_c`` (one run per control axis, as flight tests are flown), 15 s at 50 Hz;
  ``val_1.csv``, ``val_2.csv``: doublets on both cyclics, for validation (refine chooses on one and
  judges on the other, so each moves both inputs);
* ``flight_lon.mat``, ``flight_lat.mat``: the two runs as a data-acquisition system would store them: one matrix
  ``Z`` (column 0 time), angles in degrees, lateral cyclic as two actuator columns ``dar``, ``dal``;
  ``channel_map.json`` reads it;
* ``cockpit_lon.csv`` and ``daq_lon.csv``: a simulated pilot flying a 3211 on the display (the
  display's run file: ``theta_s_cmd`` designed, ``theta_s`` flown, 60 Hz, time from the display's
  start) and the aircraft's recording of the same flight (50 Hz, stick in degrees, started
  ``DAQ_LEAD`` s before the display: the two clocks differ by that much);
* ``gusty_lon.csv``, ``gusty_lat.csv``: the two 3211s flown again in turbulence: first-order gusts
  (correlation time ``1 / GUST_CORNER`` s) of ``GUST_SIGMA`` m/s on u and v entering as a relative
  wind (every derivative on u, v acting on u - u_g, v - v_g), for ``--method fem --turbulence u,v``;
* ``sig.json`` (``theta_s``) and ``both.json`` (both cyclics, one run): sequences designed on the a
  priori as ``signaldesign design --criterion nominal --grid 0.5 --min-pulse 0.5`` would (the default
  robust design takes minutes; these take seconds and serve the documents' quick commands).
"""
from __future__ import annotations

import json
from dataclasses import replace
import shutil
import sys
from pathlib import Path

import numpy as np
import scipy.io

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cueing.pilot import PilotModel  # noqa: E402
from identify import LinearModel, Run, load_profile, perturbed_model, simulate_run  # noqa: E402
from signaldesign.baselines import doublet, m3211  # noqa: E402
from signaldesign.design import SequenceDesign  # noqa: E402
from signaldesign.signal import save_signals  # noqa: E402

HERE = ROOT / "examples"
DT, RECORD, AMP, DELAY, SPREAD, NOISE = 0.02, 15.0, 0.01, 0.08, 0.15, 0.03
DAQ_LEAD = 3.74  # s: the recording starts this long before the display's clock
SEED = 23
GUST_CORNER, GUST_SIGMA = 0.7, {"u": 0.8, "v": 0.5}  # rad/s, m/s


def inputs(model: LinearModel, signals, t: np.ndarray) -> np.ndarray:
    u = np.zeros((t.size, model.n_inputs))
    for s in signals:
        u[:, model.profile.input_names.index(s.input)] += s(t)
    return u


def rounded(run: Run, meta: dict, digits: int = 6) -> Run:
    """Six significant digits (a recorder's resolution, and small files) and only the metadata a
    flight-test file would carry (the simulation's own would give the truth away)."""
    return Run(run.time, {k: np.array([float(f"{v:.{digits}g}") for v in run[k]]) for k in run.channels},
               {**meta, "made_by": "examples/make_examples.py"})


def run_of(truth: LinearModel, signals, t: np.ndarray, seed: int, label: str) -> Run:
    return rounded(simulate_run(truth, t, inputs(truth, signals, t), noise_fraction=NOISE, seed=seed,
                                derivatives=False, input_delay=DELAY), {"signal": label})


def write_mat(run: Run, path: Path) -> None:
    """The run as one matrix Z in degrees, lateral cyclic as two actuators (theta_c = (dar - dal)/2)."""
    deg = np.degrees
    cols = [run.time, deg(run["theta_s"]), deg(run["theta_c"]) + 1.5, -deg(run["theta_c"]) + 1.5,
            run["u"], run["v"], deg(run["p"]), deg(run["q"]), deg(run["theta"]), deg(run["phi"])]
    scipy.io.savemat(path, {"Z": np.column_stack(cols)}, do_compression=True)


def gusty_runs(truth: LinearModel, t: np.ndarray) -> None:
    """``gusty_lon.csv``, ``gusty_lat.csv``: the truth with gust states (corner held at GUST_CORNER),
    white noise driving them; only the inputs and the measured outputs are written."""
    from identify.model.turbulence import augment, with_turbulence

    p = with_turbulence(truth.profile, "u,v")
    gm = augment(replace(p, turbulence={**p.turbulence, "corner": dict.fromkeys(("u", "v"), GUST_CORNER)}))
    model = LinearModel(gm.augmented)
    # F = sigma sqrt(2 corner); simulate_run's per-sample white noise of std F / sqrt(dt)
    sigma = [GUST_SIGMA[s[:-2]] * np.sqrt(2 * GUST_CORNER / DT) if s in gm.gusts.values() else 0.0
             for s in model.profile.state_names]
    for k, (name, signal, label) in enumerate((("gusty_lon.csv", m3211(0.8, AMP, "theta_s", 1.0), "theta_s"),
                                                ("gusty_lat.csv", m3211(0.6, AMP, "theta_c", 1.0), "theta_c"))):
        run = simulate_run(model, t, inputs(model, [signal], t), noise_fraction=NOISE, seed=SEED + 40 + k,
                           derivatives=False, input_delay=DELAY, process_noise=sigma)
        kept = Run(run.time, {c: run[c] for c in truth.profile.channels})
        rounded(kept, {"signal": f"3211 on {label} in turbulence"}).to_csv(HERE / name)


def cockpit_and_daq(truth: LinearModel) -> tuple[Run, Run]:
    signal = m3211(0.8, AMP, "theta_s", delay=2.0)
    t60 = np.arange(int(RECORD * 60)) / 60
    flown = PilotModel(skill=0.5, seed=SEED).fly([signal], t60)[:, 0]
    cockpit = Run(t60, {"theta_s_cmd": signal(t60), "theta_s": flown})
    # the recording: its own clock, starting DAQ_LEAD s earlier and running 2 s longer
    t_daq = np.arange(int((RECORD + DAQ_LEAD + 2.0) / DT)) * DT
    stick = np.interp(t_daq - DAQ_LEAD, t60, flown, left=0.0, right=flown[-1])
    u = np.column_stack([stick, np.zeros_like(stick)])
    daq = simulate_run(truth, t_daq, u, noise={"theta_s": 2e-5, "theta_c": 2e-5}, noise_fraction=NOISE,
                       seed=SEED + 1, derivatives=False, input_delay=DELAY)
    daq = daq.with_channels({"theta_s": np.degrees(daq["theta_s"]), "theta_c": np.degrees(daq["theta_c"])})
    return (rounded(cockpit, {"source": "pilot", "signal": "3211 0.8 s on theta_s"}),
            rounded(daq, {"units": "theta_s=deg, theta_c=deg", "recorder": "data acquisition, own clock"}))


def main() -> None:
    shutil.copy(ROOT / "profiles" / "s61_hover_4dof.toml", HERE / "profile.toml")
    apriori = LinearModel(load_profile(HERE / "profile.toml"))
    truth = perturbed_model(apriori, SPREAD, np.random.default_rng(SEED))
    p = truth.profile.with_values(dict(zip(truth.names, truth.theta)), name="S 61 hover, the examples' truth")
    p = replace(p, meta={"delays": {"theta_s": DELAY, "theta_c": DELAY},
              "made_by": "examples/make_examples.py: a priori x U(0.85, 1.15) per derivative, seed 23"})
    p.save(HERE / "truth.toml")
    truth = LinearModel(load_profile(HERE / "truth.toml"))

    t = np.arange(int(RECORD / DT)) * DT
    runs = {"run_lon.csv": ([m3211(0.8, AMP, "theta_s", 1.0)], "3211 0.8 s on theta_s"),
            "run_lat.csv": ([m3211(0.6, AMP, "theta_c", 1.0)], "3211 0.6 s on theta_c"),
            "val_1.csv": ([doublet(1.0, AMP, "theta_s", 1.0), doublet(0.8, AMP, "theta_c", 6.0)],
                          "doublets on theta_s (1 s) and theta_c (0.8 s)"),
            "val_2.csv": ([doublet(0.8, AMP, "theta_c", 1.0), doublet(1.2, AMP, "theta_s", 6.0)],
                          "doublets on theta_c (0.8 s) and theta_s (1.2 s)")}
    made = {}
    for i, (name, (signals, label)) in enumerate(runs.items()):
        made[name] = run_of(truth, signals, t, SEED + 10 + i, label)
        made[name].to_csv(HERE / name)
    write_mat(made["run_lon.csv"], HERE / "flight_lon.mat")
    write_mat(made["run_lat.csv"], HERE / "flight_lat.mat")
    (HERE / "channel_map.json").write_text(json.dumps(
        {"time": 0, "matrix": "Z",
         "channels": {"theta_s": 1, "dar": 2, "dal": 3, "u": 4, "v": 5, "p": 6, "q": 7, "theta": 8, "phi": 9,
                      "theta_c": "(dar - dal)/2"},
         "units": {"theta_s": "deg", "dar": "deg", "dal": "deg", "p": "deg/s", "q": "deg/s", "theta": "deg",
                   "phi": "deg"}}, indent=1) + "\n")
    for name, axes in (("sig.json", ["theta_s"]), ("both.json", ["theta_s", "theta_c"])):
        d = SequenceDesign(axes, criterion="nominal", grid=0.5, min_pulse=0.5, jobs=1).fit(apriori)
        save_signals(d.signals_, HERE / name)
    gusty_runs(truth, t)
    cockpit, daq = cockpit_and_daq(truth)
    cockpit.to_csv(HERE / "cockpit_lon.csv")
    daq.to_csv(HERE / "daq_lon.csv")
    for f in sorted(HERE.iterdir()):
        print(f"{f.relative_to(ROOT)}: {f.stat().st_size // 1024} kB")


if __name__ == "__main__":
    main()
