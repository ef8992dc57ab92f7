"""``identify refine``: fit, find what the residuals say the model lacks, add it, re-identify
(the pipeline's :meth:`~identify.pipeline.Job.refine`); the evidence printed and written."""
from __future__ import annotations

from ..cliutil import fraction, nonnegative_float, nonnegative_int, positive_float
from . import options
from .estimate import estimator_options


def add_parser(sub) -> None:
    p = sub.add_parser("refine", help="find unmodelled effects in the residuals, add them, re-identify")
    options.add_fit(p, "run files to fit", default_method="ml")
    p.add_argument("--validate", nargs="+", metavar="RUN", help="held-out runs every added effect is checked on")
    p.add_argument("--kinds", metavar="LIST", help="comma-separated effect kinds to try (default: all; "
                   "derivative, delay, lag, sensor_lag, bias, drift, scale, nonlinear, periodic)")
    p.add_argument("--alpha", type=fraction, default=0.01, help="family-wise false-alarm level (default 0.01)")
    p.add_argument("--max-steps", type=nonnegative_int, default=6, help="effects added at most (default 6)")
    p.add_argument("--no-zero-shifts", action="store_true",
                   help="do not estimate per-run output zero shifts (then a common bias is a candidate)")
    p.add_argument("--frequency", type=positive_float, action="append", metavar="HZ",
                   help="known disturbance frequency (e.g. a rotor harmonic); default: residual spectrum peak")
    p.add_argument("--f-min", type=nonnegative_float, default=0.5, metavar="HZ", help="lowest periodic frequency searched")
    p.add_argument("--tau-max", type=positive_float, default=0.5, metavar="S", help="largest delay searched (default 0.5)")
    p.add_argument("--prune", dest="backward", action="store_true",
                   help="a last step of backward elimination: fix at 0, one at a time, the parameters within 2 "
                        "std of zero whose removal does not raise the held-out error (identify structure)")
    p.set_defaults(func=cmd_refine)


def cmd_refine(args) -> int:
    """Fit, find what the residuals say the model lacks, add it, re-identify; write the evidence."""
    from ..errors import EstimationError
    from ..refine.candidates import KINDS

    kinds = KINDS if args.kinds is None else options.names(args.kinds)
    if not kinds:
        raise EstimationError(f"--kinds names no effect kind (catalogue: {', '.join(KINDS)})")
    job = options.job(args, estimator_options(args))
    refinement = job.refine(args.validate or [], names=options.FLAGS, alpha=args.alpha, kinds=kinds,
                            max_steps=args.max_steps, zero_shifts=not args.no_zero_shifts, frequencies=args.frequency,
                            f_min=args.f_min, tau_max=args.tau_max, progress=True,
                            prune=_pruner() if args.backward else None)
    refiner = refinement.refiner
    if refiner.nothing_found:
        print("nothing found: no candidate effect is significant")
    for i, s in enumerate(refiner.steps_, start=1):
        params = ", ".join(f"{k} = {v['value']:.5g} ± {v['std']:.2g}" for k, v in s.parameters.items())
        print(f"step {i}: {s.effect} on {s.target}: {params} (score {s.statistic:.4g} > {s.threshold:.4g})")
    for s in refiner.rejected_:
        print(f"rejected: {s.effect} on {s.target}: {s.reason}")
    for d in refiner.pruned_:
        print(f"prune: {d.term} {'fixed at 0' if d.action == 'dropped' else 'kept'} (|t| = {d.statistic:.2f}; {d.note})")
    if refiner.unconverged_:
        print(f"warning: {len(refiner.unconverged_)} fit(s) inside refine did not converge "
              f"(listed in report.md): {refiner.unconverged_[0]}")
    for where in refiner.error_before_:
        print(f"{where} error (overall): {refiner.error_before_[where]['overall']:.4g} -> "
              f"{refiner.error_after_[where]['overall']:.4g}", flush=True)
    out = refinement.save(args.out)  # after the screen output: a failing write loses nothing shown
    print(f"written to {out}: refine.json, report.md, final_profile.toml")
    return 0


def _pruner():
    from ..structure.prune import Prune

    return Prune()
