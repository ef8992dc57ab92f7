"""``identify compat``: flight-path reconstruction (sensor biases, scale factors, time skews)."""
from __future__ import annotations

import sys

from ..cliutil import fraction, nonnegative_int, output_dir, positive_float
from ..errors import EstimationError
from . import options


def cmd_compat(args) -> int:
    """Flight-path reconstruction: sensor biases, scale factors and time skews; corrected runs."""
    from ..compat import Compat
    from ..compat.report import write

    runs = options.reading(args).recorded(args.runs)
    errors = None if args.errors is None else [e.strip() for e in args.errors.split(",") if e.strip()]
    compat = Compat(errors, alpha=args.alpha, max_steps=args.max_steps, segment=args.segment,
                    input_noise=_input_noise(args.input_noise),
                    progress=lambda text: print(text, file=sys.stderr, flush=True)).fit(runs)
    print(compat.result_.summary(), flush=True)
    written = write(compat.result_, runs, args.out, plots=args.plots)
    print(f"written to {args.out}: {', '.join(written)}")
    return 0


def _input_noise(text: str | None) -> dict | None:
    """``a_z=0.01,q=0.00035`` -> {channel: std}; one clear error for a malformed item."""
    if not text:
        return None
    out = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, _, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise EstimationError(f"--input-noise: '{item}' is not channel=std (e.g. q=0.00035)") from None
    return out


def add_parser(sub) -> None:
    p = sub.add_parser("compat", help="flight-path reconstruction: sensor biases, scale factors, time skews; "
                                      "corrected runs")
    p.add_argument("runs", nargs="+", help="run files (.csv or .mat) with a_x, a_y, a_z, p, q, r and any of "
                                           "V, alpha, beta, phi, theta, psi, h")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    options.add_reading(p, trim=False)
    p.add_argument("--errors", metavar="LIST", help="estimate exactly these sensor errors (e.g. b_q,b_alpha,"
                   "K_alpha,tau_alpha) instead of selecting them by score tests")
    p.add_argument("--alpha", type=fraction, default=0.01, help="family-wise false-alarm level (default 0.01)")
    p.add_argument("--max-steps", type=nonnegative_int, default=12, help="sensor errors added at most (default 12)")
    p.add_argument("--segment", type=positive_float, default=3.0, metavar="S",
                   help="integration segment length, each from its own initial state (default 3 s)")
    p.add_argument("--input-noise", metavar="LIST", help="white-noise std of inertial sensors for the bounds, "
                   "SI units (e.g. a_z=0.01,q=0.00035, from a data sheet); others estimated from the data")
    p.add_argument("--plots", action="store_true", help="also draw residuals_before_after.png")
    p.set_defaults(func=cmd_compat)
