"""After the flight: the live estimate beside post-flight ML, as a Markdown table."""
from __future__ import annotations

import numpy as np

from .estimate import LiveIdentification


def comparison(live: LiveIdentification, ml_result) -> str:
    """Markdown table: the live (recursive FDEE) estimate at the end of the flight beside ML's."""
    est = live.latest
    complete = "at %.1f s" % live.complete_at_ if live.complete_at_ is not None else "never"
    lines = ["# Live estimate beside post-flight ML", "",
             f"Live: recursive frequency-domain equation error, last re-solved at {est.t:.1f} s "
             f"({', '.join(f'{k}: {v}' for k, v in est.errors.items()) or 'all equations solved'}); "
             f"test point complete {complete}. "
             f"ML: output error on the run file. CR % and I % (insensitivity: the bound were the other "
             f"parameters known) as Tischler & Remple; their guidelines CR % <= 20, I % <= 10.", "",
             "| parameter | target % | live | live std | live CR % | live I % | ML | ML std | (live - ML) / live std |",
             "|---|---|---|---|---|---|---|---|---|"]
    ml = dict(zip(ml_result.names, zip(ml_result.theta, ml_result.std)))
    for i, n in enumerate(live.names):
        v, s = est.theta[i], est.std[i]
        mv, ms = ml.get(n, (np.nan, np.nan))
        tgt = f"{live.targets[n]:g}" if n in live.targets else ""
        lines.append(f"| {n} | {tgt} | {v:.5g} | {s:.3g} | {100 * s / abs(v):.1f} | "
                     f"{est.relative_insensitivity[i]:.1f} | {mv:.5g} | {ms:.3g} | {(v - mv) / s:+.2f} |")
    if live.fixed_unflown:
        lines += ["", f"Fixed at a priori values (their inputs were not flown): {', '.join(live.fixed_unflown)}."]
    return "\n".join(lines) + "\n"
