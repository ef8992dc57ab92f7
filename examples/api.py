"""design -> fly -> estimate -> refine through the Python API, on the example aircraft (about 20 s):

    python examples/api.py

1. design: an optimised three-level sequence per cyclic on the a priori model (one run per axis);
2. fly: a simulated pilot flies each; the flown stick drives the "real aircraft"
   (examples/truth.toml: derivatives up to 15 % off, a 0.08 s delay on both cyclics) with 3 %
   measurement noise; two more flights (both cyclics, other pilot seeds) for validation;
3. estimate: ML on the two runs, against the truth;
4. refine: what the a priori model lacks, found in the residuals, chosen and judged on the
   validation flights. (On a pilot's smooth stick a first-order lag of time constant 1/k close to
   the delay can explain the data as well as the delay does; refine says which it chose.)
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from cueing.pilot import PilotModel  # noqa: E402
from identify import ML, LinearModel, load_profile, simulate_run  # noqa: E402
from identify.refine import Refine  # noqa: E402
from signaldesign import SequenceDesign  # noqa: E402

DT, RECORD = 0.02, 15.0


def fly(truth: LinearModel, signals, seed: int):
    """The simulated pilot flies ``signals``; the truth responds, with its delays, plus noise."""
    t = np.arange(int(RECORD / DT)) * DT
    flown = PilotModel(skill=0.5, seed=seed).fly(signals, t)
    u = np.zeros((t.size, truth.n_inputs))
    for k, s in enumerate(signals):
        u[:, truth.profile.input_names.index(s.input)] = flown[:, k]
    delays = {k: float(v) for k, v in truth.profile.meta.get("delays", {}).items()}
    return simulate_run(truth, t, u, noise_fraction=0.03, seed=seed, derivatives=False, input_delay=delays)


def main() -> None:
    apriori = load_profile(HERE / "profile.toml")
    truth = LinearModel(load_profile(HERE / "truth.toml"))

    # 1. design, one sequence per axis (nominal criterion on a 0.5 s grid: seconds, not minutes)
    designs = {axis: SequenceDesign(axis, duration=7.0, record=RECORD, criterion="nominal", grid=0.5,
                                    min_pulse=0.5, delay=1.0, jobs=1).fit(LinearModel(apriori))
               for axis in ("theta_s", "theta_c")}
    for axis, d in designs.items():
        print(f"designed on {axis}: amplitude {np.degrees(d.amplitude_[0]):.2f} deg, "
              f"binding output {d.binding_}")

    # 2. fly: one run per axis, and two validation flights moving both cyclics
    runs = [fly(truth, d.signals_, seed=i) for i, d in enumerate(designs.values())]
    both = [designs["theta_s"].signals_[0], designs["theta_c"].signals_[0]]
    validate = [fly(truth, both, seed=10 + i) for i in range(2)]

    # 3. estimate
    result = ML(apriori).fit(runs).result_
    print(result.summary(truth=dict(zip(truth.names, truth.theta))).split("\n\n")[0])

    # 4. refine
    refine = Refine(apriori).fit(runs, validate=validate)
    for step in refine.steps_:
        found = ", ".join(f"{k} = {v['value']:.4g} ± {v['std']:.2g}" for k, v in step.parameters.items())
        print(f"refine added a {step.effect} on {step.target}: {found}")
    print(f"refine stopped: {refine.stopped_}")
    print(f"validation error {refine.error_before_['validation']['overall']:.4g} -> "
          f"{refine.error_after_['validation']['overall']:.4g} (truth: 0.08 s delays on both cyclics)")


if __name__ == "__main__":
    main()
