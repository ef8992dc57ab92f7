"""Refine under FEM: are the warm-started nested fits at the optimum a fit from scratch finds?

Refine starts each nested FEM fit's F and R from the fit of the model it extends (one start:
``FEM(noise_start=...)``, ``Fitting.refit``) instead of FEM's two starts from scratch, and fits from
scratch too only where the warm fit ends above the parent's -log L. The nested likelihood-ratio
test needs each fit at its optimum: a warm start that stayed on a worse optimum would bias the
ratio. This audit runs refine exactly as ``benchmarks/refine_blind.py --method fem`` does (the same
cases, data and command line, in this process) and, for every warm-started fit, also fits the same
problem from scratch (both starts) without using it: per fit the -log L kept, from scratch and the
parent's; per case the largest amount by which the kept fit is worse than the one from scratch.

    .venv/bin/python benchmarks/refine_fem_warm.py [--cases a,b] [--seed N] [--seeds K]   # --help
"""
import json
import os
import sys
import warnings
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
import refine_blind as rb  # noqa: E402
from identify.cli import main as cli  # noqa: E402
from identify.estimators import filter_error as fe  # noqa: E402
from _cli import count, parser as cli_parser, positive  # noqa: E402

OUTPUT = ROOT / "benchmarks" / "output" / "refine_fem_warm"
AUDIT: list[dict] = []
_shipped = fe.FEM._solve_warm


def _audited(self, prob, beta, active):
    """The shipped warm start, then (unused) the same problem from scratch: both -log L recorded."""
    kept = _shipped(self, prob, beta, active)
    rec = {**kept.warm, "cost": dict(kept.warm["cost"]), "kept_cost": float(kept.history[-1])}
    if "scratch" not in rec["cost"]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec["cost"]["scratch"] = float(self._solve(prob, beta, active).history[-1])
    AUDIT.append(rec)
    return kept


def main(names, length: float, seed: int, seeds: int) -> None:
    rb.OUT = OUTPUT  # refine_blind's data are written here, not in its own folder
    fe.FEM._solve_warm = _audited
    print(f"refine_fem_warm: refine --method fem on {', '.join(names)}, seeds {seed}..{seed + seeds - 1}, "
          f"{length:g} s runs; load average {os.getloadavg()[0]:.1f}")
    print(f"{'case':12s} {'seed':>4} {'warm':>5} {'+scratch':>8} {'kept - scratch: max':>20} "
          f"{'worse by > 1':>12} {'steps':s}")
    rows, worst = [], -float("inf")
    for case in rb.CASES:
        if case.name not in names:
            continue
        for s in range(seed, seed + seeds):
            declared, fit, val = rb.write_case(case, length, s)
            AUDIT.clear()
            out = OUTPUT / case.name / "out"
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cli(["refine", "--profile", str(declared), *map(str, fit), "--validate", *map(str, val),
                     "--out", str(out), "--method", "fem"])
            data = json.loads((out / "refine.json").read_text())
            gap = [a["kept_cost"] - a["cost"]["scratch"] for a in AUDIT]
            fell_back = sum(1 for a in AUDIT if a["kept"] == "scratch" or "reason" in a)
            worse = sum(1 for g in gap if g > fe.SAME_OPTIMUM)
            worst = max([worst, *gap])
            steps = ", ".join(f"{st['effect']} {st['target']}" for st in data["steps"]) or "none"
            print(f"{case.name:12s} {s:4d} {len(AUDIT):5d} {fell_back:8d} {max(gap, default=float('nan')):20.4g} "
                  f"{worse:12d} {steps}", flush=True)
            rows.append({"case": case.name, "seed": s, "fits": list(AUDIT), "steps": steps})
    (OUTPUT / "audit.json").write_text(json.dumps(rows, indent=1))
    print(f"\nlargest (kept - from scratch) -log L over all warm-started fits: {worst:.4g} "
          f"(> {fe.SAME_OPTIMUM:g}: a warm start on a worse optimum); load average at the end "
          f"{os.getloadavg()[0]:.1f}; details in {OUTPUT}")


def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("--cases", default="small_Xde,lag_de,null_navion", help="comma-separated refine_blind cases")
    ap.add_argument("--length", type=positive, default=30.0, help="length of each run, s")
    ap.add_argument("--seed", type=count, default=1, help="first seed of the simulated runs")
    ap.add_argument("--seeds", type=count, default=3, help="number of seeds from --seed")
    return ap


if __name__ == "__main__":
    a = parser().parse_args()
    main([c.strip() for c in a.cases.split(",") if c.strip()], a.length, a.seed, a.seeds)
