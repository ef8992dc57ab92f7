"""``identify estimate``: a profile's free parameters identified from runs (the pipeline's
:meth:`~identify.pipeline.Job.estimate`), printed and written."""
from __future__ import annotations

import sys

from ..cliutil import positive_float, positive_int, state_values
from . import options

DEFAULT_METHOD = "ml"  # output-error ML: what refine, VERIFY and the bounds' checks assume (docs/walkthrough.md)


def add_parser(sub) -> None:
    p = sub.add_parser("estimate", help="identify a profile's parameters from runs (LS, IV, ML, FDEE, FR or FEM)")
    options.add_fit(p, "run files", default_method=DEFAULT_METHOD)
    p.add_argument("--diff-cutoff", type=positive_float, metavar="HZ",
                   help="cut-off of the smoothed differentiator for states without measured derivatives")
    p.add_argument("--max-iter", type=positive_int, metavar="N",
                   help="iterations at most for iv (default 30), ml and fem (default 100)")
    p.add_argument("--plots", action="store_true",
                   help="also draw time_history_run<k>.png and residuals.png (slower than the fit)")
    p.add_argument("--x0", type=state_values, metavar="STATE=VALUE,...",
                   help="known initial states, held in every run (ml, fem; adds to the profile's [initial_state])")
    p.add_argument("--verify", nargs="+", metavar="RUN", help="held-out runs the identified model must predict "
                   "(VERIFY: initial state and zero shifts fitted; Theil coefficient and J_rms reported)")
    p.add_argument("--fem-formulation", choices=("measurement", "innovation"),
                   help="fem: R the measurement noise, fitted with the derivatives (default), or the textbook's "
                        "innovation covariance, relaxed, with C K <= 1 (where the default fit is degenerate)")
    p.add_argument("--fr-delays", metavar="INPUTS", help="fr: comma-separated inputs given a fitted time delay")
    p.add_argument("--prune", action="store_true", help="fr: fix parameters that fail CIFER's gates "
                   "(insensitivity <= 10 %%, Cramér-Rao <= 20 %%) at their a priori values, one at a time")
    p.add_argument("--n-draws", type=_n_draws, metavar="N",
                   help="fr: surrogate sets of runs behind the bootstrap standard errors (default 30; 0: Tischler's "
                        "bound from J alone, which takes correlated points as independent and is too small)")
    p.set_defaults(func=cmd_estimate)


def estimator_options(args) -> dict:
    """The estimator's constructor arguments the flags give (None: not given, the default)."""
    return dict(max_iter=getattr(args, "max_iter", None), diff_cutoff_hz=getattr(args, "diff_cutoff", None),
                delays=options.names(getattr(args, "fr_delays", None)) or None,
                prune=getattr(args, "prune", None) or None, x0=getattr(args, "x0", None),
                n_draws=getattr(args, "n_draws", None), formulation=getattr(args, "fem_formulation", None),
                process_noise=dict.fromkeys(options.names(getattr(args, "process_noise", None))) or None)


def progress(method: str):
    """The iterative estimators' progress, one line per iteration on stderr."""
    from ..estimators.registry import estimator_class

    quantity = estimator_class(method).progress_quantity

    def show(it, value, theta):
        print(f"{method.upper()} iteration {it}: {quantity} {value:.4g}", file=sys.stderr, flush=True)
    return show


def cmd_estimate(args) -> int:
    """Identify a profile's free parameters from runs; write result.json, the profile and plots."""
    job = options.job(args, estimator_options(args), verify=args.verify)
    est = job.estimate(progress=progress(args.method), names=options.FLAGS)
    print(est.text(), flush=True)  # on screen before anything is written
    written = est.save(args.out, plots=args.plots)
    print(f"\nwritten to {args.out}: {', '.join(written)}" + ("" if args.plots else " (plots: add --plots)"))
    return 0


def _n_draws(text: str) -> int:
    """argparse type of --n-draws: 0 or at least 3 (a sample covariance needs three refits)."""
    import argparse

    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if n != 0 and n < 3:
        raise argparse.ArgumentTypeError(f"0 or at least 3, got {n}")
    return n
