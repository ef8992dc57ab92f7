"""``identify structure``: which parameters the data support and which terms they ask for
(stepwise regression in equation error, then backward elimination in output error)."""
from __future__ import annotations

from ..cliutil import fraction, nonnegative_float, positive_float
from ..errors import EstimationError
from . import options
from .estimate import estimator_options


def add_parser(sub) -> None:
    p = sub.add_parser("structure", help="model structure determination: which parameters the data support, "
                                         "which terms they ask for (stepwise regression, then output error)")
    options.add_fit(p, "run files to fit", default_method="ml")
    p.add_argument("--validate", nargs="+", metavar="RUN",
                   help="held-out runs the output-error removals are judged on (default: half of each run)")
    p.add_argument("--alpha", type=fraction, default=0.05,
                   help="stepwise regression's level: partial F to stay per term, to enter for the family of "
                        "candidates (default 0.05)")
    p.add_argument("--no-candidates", action="store_true", help="do not try undeclared A/B entries")
    p.add_argument("--nonlinear", metavar="LIST",
                   help="channels whose squares, x|x|, splines and pairwise products are candidates")
    p.add_argument("--knots", metavar="SPEC", help="spline knots of --nonlinear channels: 'alpha=0.1,0.2;w=3'")
    p.add_argument("--level", type=positive_float, default=2.0,
                   help="|estimate|/std below which output error calls a parameter unsupported (default 2)")
    p.add_argument("--tolerance", type=nonnegative_float, default=0.01,
                   help="relative rise of the held-out error a removal may cause (default 0.01)")
    p.add_argument("--equation-error-only", action="store_true", help="stop after the equation-error pass")
    p.set_defaults(func=cmd_structure)


def cmd_structure(args) -> int:
    """Which parameters the data support and which terms they ask for: stepwise regression in
    equation error, then backward elimination in output error; the decisions and the final profile."""
    from ..structure.report import write
    from ..structure.search import StructureSearch

    job = options.job(args, estimator_options(args))
    profile = job.profile_()
    search = StructureSearch(profile, estimator=job.estimator(profile, names=options.FLAGS), alpha=args.alpha,
                             candidates=not args.no_candidates, nonlinear=options.names(args.nonlinear),
                             knots=_knots(args.knots), level=args.level, tolerance=args.tolerance,
                             confirm=not args.equation_error_only, progress=True)
    held = job.reading.prepared(args.validate, profile, window=False) if args.validate else []
    search.fit(job.reading.prepared(job.runs, profile), validate=held)
    print(search.summary())
    if getattr(search, "unconverged_", None):
        print(f"warning: {len(search.unconverged_)} fit(s) did not converge: {search.unconverged_[0]}")
    out = write(search, args.out)
    print(f"written to {out}: structure.json, final_profile.toml")
    return 0


def _knots(text: str | None) -> dict[str, list[float]]:
    """``--knots alpha=0.1,0.2;w=3`` -> {"alpha": [0.1, 0.2], "w": [3.0]}."""
    out = {}
    for part in filter(None, (p.strip() for p in (text or "").split(";"))):
        name, _, values = part.partition("=")
        try:
            out[name.strip()] = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            raise EstimationError(f"--knots: not numbers in {part!r} (write name=k1,k2;other=k)") from None
        if not name.strip() or not out[name.strip()]:
            raise EstimationError(f"--knots: {part!r} is not name=k1,k2")
    return out
