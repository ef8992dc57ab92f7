"""``identify freq``: frequency responses and coherence of runs, Bode plots with models, J."""
from __future__ import annotations

import sys

from ..cliutil import output_dir, positive_float
from ..errors import EstimationError
from . import options


def cmd_freq(args) -> int:
    """Frequency responses and coherence of runs; Bode plots with the a priori model, CSV, J."""
    from pathlib import Path

    import numpy as np

    from ..estimators.frequency.bode import plot_bode
    from ..estimators.frequency.response import cost_report, frequency_response

    from ..model.linear import LinearModel
    from ..model.profile import load_profile

    profile = load_profile(args.profile)
    runs = options.reading(args).recorded(args.runs, profile)
    inputs, skipped = _moved_inputs(runs, profile.input_names)
    runs = [r.with_channels({u: np.zeros(len(r)) for u in profile.input_names if u not in r.channels})
            for r in runs]  # an input a run lacks was held at trim
    f_range = None if args.f_min is None and args.f_max is None else (args.f_min or 0.05, args.f_max or 5.0)
    fr = frequency_response(runs, inputs, list(profile.outputs), f_range=f_range)
    if skipped:  # said once the responses exist (a missing output is the one error line otherwise)
        print(f"note: skipped input(s) {', '.join(skipped)}: no run moves them (absent or constant); "
              f"responses to {', '.join(inputs)} only", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    models = {"a priori": LinearModel(profile)}
    for k, path in enumerate(args.identified or []):  # e.g. identified_profile.toml from identify estimate
        label = "identified" if len(args.identified) == 1 else f"identified {k + 1} ({Path(path).parent.name})"
        models[label] = LinearModel(load_profile(path))
    plots = plot_bode(fr, models, out)
    fr.to_csv(out / "frequency_response.csv")
    print(f"windows {', '.join(f'{w:.3g}' for w in fr.windows)} s over {len(runs)} run(s)")
    print("\n".join(fr.resolved_lines()))
    print(cost_report(runs, models)[0])
    print(f"written to {out}: frequency_response.csv, {', '.join(p.name for p in plots)}")
    return 0


def _moved_inputs(runs, inputs) -> tuple[list[str], list[str]]:
    """The profile inputs some run moves (present and not constant), and those none does: a
    response to an input never moved is not estimable (its cross-spectra are empty), and keeping
    it would make every other input's response singular. A moved input absent from some run is
    taken at trim (zero) there."""
    import numpy as np

    def moved(u):
        return any(u in r.channels and np.ptp(r[u]) > 0 for r in runs)

    used = [u for u in inputs if moved(u)]
    if not used:
        raise EstimationError(f"no run moves any input of the profile ({', '.join(inputs)})")
    return used, [u for u in inputs if u not in used]


def add_parser(sub) -> None:
    p = sub.add_parser("freq", help="frequency responses with coherence (Bode plots, CSV, fit cost J)")
    p.add_argument("runs", nargs="+", help="run files (.csv or .mat)")
    p.add_argument("--profile", required=True, help="profile (inputs, outputs and the a priori model overlaid)")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    p.add_argument("--identified", metavar="TOML", action="append",
                   help="an identified profile to overlay and judge (J) too; repeat for several (e.g. ML and FR)")
    p.add_argument("--f-min", type=positive_float, metavar="HZ", help="lowest frequency (default: from the windows)")
    p.add_argument("--f-max", type=positive_float, metavar="HZ", help="highest frequency (default 0.4 x sample rate, <= 5)")
    options.add_reading(p)
    p.set_defaults(func=cmd_freq)
