"""Arguments several subcommands share, and their translation into the pipeline's objects."""
from __future__ import annotations

import sys

from ..cliutil import finite_float, output_dir, positive_float

NAN_HELP = ("missing values inside the analysed window: refuse the file (default), drop their samples "
            "(the hole splits the run) or interpolate them; outside the window the run is cut to it")
MAP_HELP = ('{"channels": {channel: column, variable, matrix column or expression such as "(dar - dal)/2"}, '
            '"units": {name: unit}, "time": ..., "matrix": ..., "dt": ...} as a file or inline JSON '
            '(required for .mat data matrices)')
# estimator parameter -> the flag that sets it, for the one error line of an option a method does not take
FLAGS = {"max_iter": "--max-iter", "diff_cutoff_hz": "--diff-cutoff", "delays": "--fr-delays", "prune": "--prune",
         "x0": "--x0", "n_draws": "--n-draws", "formulation": "--fem-formulation",
         "process_noise": "--process-noise"}


def add_reading(p, window: bool = True, trim: bool = True) -> None:
    """How run files are read: channel map, NaN policy, and (``window``) the analysed window,
    smoothing and (``trim``) the trim removal."""
    p.add_argument("--channel-map", metavar="JSON", help=MAP_HELP)
    p.add_argument("--nan", choices=("refuse", "drop", "interpolate"), default="refuse", help=NAN_HELP)
    if window:
        p.add_argument("--t-start", type=finite_float, metavar="S", help="use samples from this time on")
        p.add_argument("--t-end", type=finite_float, metavar="S", help="use samples up to this time")
        p.add_argument("--smooth", type=positive_float, metavar="HZ", help="zero-phase low-pass cut-off for every channel")
    if trim:
        p.add_argument("--trim", default=None, type=trim_option, metavar="first:1s|mean|none",
                       help="remove each channel's trim value: its mean over the first seconds, over the whole run, "
                            "or none; recorded in result.json (not given: the data are used as they are)")


def add_fit(p, runs_help: str, default_method: str) -> None:
    """Options of every command that reads runs and estimates."""
    from ..estimators.registry import METHOD_NAMES

    p.add_argument("runs", nargs="+", help=f"{runs_help} (.csv or .mat)")
    p.add_argument("--profile", required=True, help="a priori profile TOML path or bundled profile name")
    p.add_argument("--method", choices=METHOD_NAMES, default=default_method,
                   help=f"estimator (default {default_method})")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    add_reading(p)
    p.add_argument("--fix", metavar="LIST", help="free parameters to hold at their a priori values (comma-separated)")
    p.add_argument("--free", metavar="LIST", help="fixed parameters to estimate (comma-separated)")
    p.add_argument("--outputs", metavar="LIST", help="fit these outputs only (comma-separated; default all)")
    p.add_argument("--turbulence", metavar="LIST", help="fem: gust states on these velocities (u,v,w; in a "
                   "flow-angle profile w and v act on alpha and beta), corners and intensities estimated; "
                   "sets the profile's [turbulence] states (fem's default where neither this nor [process_noise] "
                   "is declared: the profile's velocities)")
    p.add_argument("--process-noise", metavar="LIST", help="fem: white process noise on these states' equations "
                   "(F started from the data) instead of the default gust states (as the profile's [process_noise])")
    p.add_argument("--prior-relative", type=positive_float, metavar="PCT",
                   help="a priori weighting: every free parameter's a priori value is a prior with std PCT %% of "
                        "it (at least PCT %% of a tenth of the largest of its equation's parameters of the same unit)")
    p.add_argument("--prior", metavar="FILE", help="a priori weighting: a previous result.json (or a profile with "
                   "meta.std): its estimates and stds become the prior (over the profile's [prior])")


def reading(args):
    """The :class:`~identify.pipeline.Reading` the arguments ask for (options a command lacks: defaults)."""
    from ..pipeline import Reading

    return Reading(getattr(args, "channel_map", None), getattr(args, "nan", "refuse"), getattr(args, "t_start", None),
                   getattr(args, "t_end", None), getattr(args, "smooth", None), getattr(args, "trim", None))


def profile(args):
    """The a priori profile, with ``--free``, ``--fix``, ``--outputs``, the priors (``--prior``,
    ``--prior-relative``) and ``--turbulence`` applied (each said)."""
    from ..errors import EstimationError
    from ..model import subset
    from ..model.prior import prior_options
    from ..model.profile import load_profile

    prof = load_profile(args.profile)
    for option, change in (("free", subset.free), ("fix", subset.fix), ("outputs", subset.with_outputs)):
        if getattr(args, option, None):
            prof = change(prof, getattr(args, option))
            print(f"--{option} {getattr(args, option)}: {len(prof.free)} free parameters, "
                  f"outputs {', '.join(prof.outputs)}", file=sys.stderr)
    prof, lines = prior_options(prof, getattr(args, "prior_relative", None), getattr(args, "prior", None))
    for line in lines:
        print(line, file=sys.stderr)
    if getattr(args, "turbulence", None):
        from ..estimators.registry import estimator_class
        from ..model.turbulence import with_turbulence

        if not estimator_class(args.method).models_turbulence:
            raise EstimationError(f"--turbulence is the filter-error method's model: use --method fem "
                                  f"(--method {args.method} takes every misfit for measurement noise)")
        prof = with_turbulence(prof, args.turbulence)
    return prof


def job(args, options: dict, verify=()):
    """The :class:`~identify.pipeline.Job` of a fitting command."""
    from ..pipeline import Job

    return Job(list(args.runs), profile(args), args.method, options, reading(args), list(verify or []))


def names(text: str | None) -> tuple[str, ...]:
    """``a, b,c`` -> (a, b, c)."""
    return tuple(n.strip() for n in (text or "").split(",") if n.strip())


def trim_option(text: str) -> str:
    """argparse type of --trim (checked without loading numpy-heavy modules)."""
    import argparse

    from ..data.preprocess import parse_trim
    from ..errors import RunError

    try:
        parse_trim(text)
    except RunError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text.strip().lower()
