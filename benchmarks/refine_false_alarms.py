"""False alarms of `identify refine` on a matched model, with the full candidate catalogue.

Prints, for each noise realisation, what was added (should be nothing) and the largest score
statistic relative to its threshold; then the count of realisations where something was found and
the wall time. The test suite runs a cheaper version (restricted catalogue); this is the full one.

    .venv/bin/python benchmarks/refine_false_alarms.py [realisations]   # --help: options
"""
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from identify import LinearModel, simulate_run  # noqa: E402
from identify.refine import Refine  # noqa: E402
from tests.identify.refine.test_refine import DT, PROFILE  # noqa: E402
from _cli import counted  # noqa: E402


def main(n: int = 20) -> None:
    model = LinearModel(PROFILE)
    t = np.arange(601) * DT
    found, started = 0, time.perf_counter()
    for seed in range(n):
        u = np.random.default_rng(1000 + seed).choice([-1.0, 0.0, 1.0], size=601 // 25 + 1)
        u = np.repeat(u, 25)[:601, None] * 0.05
        run = simulate_run(model, t, u, noise_fraction=0.02, seed=1000 + seed)
        t0 = time.perf_counter()
        r = Refine(PROFILE).fit([run])
        found += not r.nothing_found
        top = max(r.last_scores_, key=lambda d: d.statistic / d.threshold, default=None)
        worst = f"{top.candidate.name} {top.statistic:.1f} / {top.threshold:.1f}" if top else "-"
        print(f"realisation {seed:2d}: added {[(s.effect, s.target) for s in r.steps_]}, "
              f"largest score / threshold: {worst}; {time.perf_counter() - t0:.2f} s", flush=True)
    print(f"something found in {found} of {n} matched-model realisations (full catalogue: "
          f"{', '.join(Refine(PROFILE).kinds)}); {time.perf_counter() - started:.1f} s")


def parser():
    return counted(__doc__, "realisations", 20, "noise realisations of the matched model (one 12 s run each)")


if __name__ == "__main__":
    main(parser().parse_args().realisations)
