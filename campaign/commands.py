"""The test-campaign subcommands of ``python -m campaign``: design, identify, stitch, report.

Each ``add_<name>(sub)`` adds its parser (registered in :data:`campaign.cli.COMMANDS`); the
libraries load only when a command runs, so ``--help`` answers at once.
"""
from __future__ import annotations

from identify.cliutil import output_dir, positive_float, positive_int


def _executor_options(p) -> None:
    g = p.add_argument_group("where the points run")
    g.add_argument("--executor", choices=("serial", "local", "dask"), default="local",
                   help="serial, a local process pool (default) or Dask")
    g.add_argument("--workers", type=positive_int, metavar="N",
                   help="worker processes (local: default the CPUs; Dask LocalCluster: default 2)")
    g.add_argument("--dask", action="store_true", help="a Dask LocalCluster on this machine (loopback only)")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler (tls://host:8786); workers must see the run files "
                        "under the same paths and have pseudostep installed")
    g.add_argument("--tls-ca", metavar="PEM", help="CA certificate for a TLS scheduler")
    g.add_argument("--tls-cert", metavar="PEM", help="this client's certificate")
    g.add_argument("--tls-key", metavar="PEM", help="this client's private key")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")


def _executor(args):
    from .executors import make_executor, security_from

    security = security_from(args.tls_ca, args.tls_cert, args.tls_key)
    kind = "dask" if args.dask else args.executor
    return make_executor(kind, args.workers, args.scheduler, security)


def _manifest(args):
    from .manifest import load_manifest

    return load_manifest(args.manifest, method=getattr(args, "method", None),
                         refine=True if getattr(args, "refine", False) else None,
                         profile=getattr(args, "profile", None), condition=args.condition)


def _common(p) -> None:
    p.add_argument("manifest", help="campaign manifest (.toml) or test matrix (.csv)")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="campaign output folder")
    p.add_argument("--condition", metavar="NAME",
                   help="the condition column trends and the stitch run over (default: the manifest's, else "
                        "the first numeric column)")


def cmd_identify(args) -> int:
    from .report import write_report
    from .runner import run_campaign

    campaign = _manifest(args)
    executor = _executor(args)
    try:
        stats = run_campaign(campaign, args.out, executor, retry_failed=args.retry_failed,
                             progress=not args.no_progress)
        if campaign.prior == "stitch":  # a second pass: each point with the others' stitch as its prior
            from .prior import run_with_stitch_prior, screen_lines as prior_screen_lines

            second = run_with_stitch_prior(campaign, args.out, executor, retry_failed=args.retry_failed,
                                           progress=not args.no_progress)
            stats["failed"] += second["failed"]
            for line in prior_screen_lines(args.out):
                print(line)
    finally:
        executor.close()
    print(f"{stats['points']} points: {stats['computed']} identified now, {stats['already_done']} already "
          f"stored, {stats['failed']} failed ({stats['executor']}, {stats['workers']} workers, "
          f"{stats['seconds']:.1f} s after {stats['startup_s']:.1f} s to start them)")
    report = write_report(campaign, args.out)
    print(f"written to {args.out}: points/, results.csv, trends.png, {report.name}")
    print(f"coordinator peak memory {peak_memory_mb():.0f} MB (this process, identification and report)")
    return 1 if stats["failed"] else 0  # a script sees that some point needs attention


def peak_memory_mb() -> float:
    """This process's largest resident set so far (Linux reports kB)."""
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def add_identify(sub) -> None:
    from identify.estimators.registry import METHOD_NAMES

    p = sub.add_parser("identify", help="identify every test point (in parallel; resumes); exit status 1 "
                                        "when a point failed (listed first in report.md)")
    _common(p)
    p.add_argument("--method", choices=METHOD_NAMES, help="estimator (default: the manifest's, else ml)")
    p.add_argument("--refine", action="store_true", help="refine every point (default: the manifest's)")
    p.add_argument("--profile", help="a priori profile for every point (overrides the manifest)")
    p.add_argument("--retry-failed", action="store_true", help="recompute points whose record is a failure")
    _executor_options(p)
    p.set_defaults(func=cmd_identify)


def cmd_design(args) -> int:
    from .design import run_design

    campaign = _manifest(args)
    options = {k: v for k, v in (("duration", args.duration), ("record", args.record),
                                 ("restarts", args.restarts), ("n_iter", args.n_iter)) if v is not None}
    executor = _executor(args)
    try:
        stats = run_design(campaign, args.out, executor, options, progress=not args.no_progress)
    finally:
        executor.close()
    print(f"{stats['designed']} of {stats['points']} points designed ({stats['computed']} now, "
          f"{stats['already_done']} already stored, {stats['failed']} failed); campaign flight time "
          f"{stats['flight_time_s'] / 60:.1f} min of records, one per control axis per point")
    print(f"signals written to {args.out}/designs/<point>.signals.json")
    return 0 if not stats["failed"] else 1


def add_design(sub) -> None:
    p = sub.add_parser("design", help="design every test point's inputs (signaldesign's robust default)")
    _common(p)
    p.add_argument("--duration", type=positive_float, metavar="S", help="signal duration per axis (default 7)")
    p.add_argument("--record", type=positive_float, metavar="S", help="record length per axis (default 20)")
    p.add_argument("--restarts", type=positive_int, metavar="N", help="search restarts (default 10)")
    p.add_argument("--n-iter", type=positive_int, metavar="N", help="proposals per restart (default 1000)")
    _executor_options(p)
    p.set_defaults(func=cmd_design)


def cmd_stitch(args) -> int:
    from pathlib import Path

    from identify.errors import CampaignError

    from . import stitch as st
    from .report import write_report
    from .table import records, rows

    campaign = _manifest(args)
    recs, table = records(campaign, args.out), rows(campaign, args.out)
    if all(r is None for _, r in recs):
        raise CampaignError(f"{args.out}: no identified point: run 'campaign identify' first")
    names = {p.name for p, _ in recs}
    if args.hold_out_points:
        held = [n.strip() for n in args.hold_out_points.split(",") if n.strip()]
        unknown = sorted(set(held) - names)
        if unknown:
            raise CampaignError(f"--hold-out-points: no point named {', '.join(unknown)}")
    else:
        held = st.held_out_points(campaign, recs, table, args.hold_out) if args.hold_out else []
    profile, summary = st.stitch(campaign, recs, table, exclude=held)
    checks = st.verify(profile, campaign, recs, held)
    if args.check:  # a held-out campaign: its points identified (resumable), each judged
        from .manifest import load_manifest
        from .runner import run_campaign

        other = load_manifest(args.check)
        executor = _executor(args)
        try:
            run_campaign(other, Path(args.out) / "check", executor, progress=not args.no_progress)
        finally:
            executor.close()
        checks += st.verify(profile, other, records(other, Path(args.out) / "check"), [p.name for p in other.points],
                            label="check")
    paths = st.write(Path(args.out) / "stitch", profile, summary, checks)
    print(f"stitched {summary['points']} points over {summary['condition']} "
          f"{summary['range'][0]:g}..{summary['range'][1]:g}: {paths['profile']}")
    for c in checks:
        if "ratio" in c:
            held = f"; on its held-out runs x{c['validation_ratio']:.3f}" if "validation_ratio" in c else ""
            print(f"  {c['set']} {c['point']} ({summary['condition']} {c[summary['condition']]:g}): prediction error "
                  f"on its runs: own model {c['own_error']:.4f}, stitched {c['stitched_error']:.4f} "
                  f"(x{c['ratio']:.3f}, {'within' if c['within_10pct'] else 'NOT within'} 10 %){held}")
        else:
            print(f"  {c['set']} {c['point']}: not verified ({c['error']})")
    write_report(campaign, args.out)
    bad = [c for c in checks if not c.get("within_10pct")]
    return 1 if bad else 0


def add_stitch(sub) -> None:
    p = sub.add_parser("stitch", help="derivatives and trim as functions of the condition: one stitched profile")
    _common(p)
    held = p.add_mutually_exclusive_group()
    held.add_argument("--hold-out", type=int, default=0, metavar="N",
                      help="leave N interior points out of the stitch and check the stitched model on them")
    held.add_argument("--hold-out-points", metavar="NAMES", help="comma-separated points to leave out and check on")
    p.add_argument("--check", metavar="MANIFEST",
                   help="a held-out campaign: identify its points (into OUT/check) and check the stitched model on each")
    _executor_options(p)
    p.set_defaults(func=cmd_stitch)


def cmd_report(args) -> int:
    from .report import write_report

    path = write_report(_manifest(args), args.out)
    print(f"report written to {path}")
    return 0


def add_report(sub) -> None:
    p = sub.add_parser("report", help="(re)write the campaign report: failures, trends, stitch, tables")
    _common(p)
    p.set_defaults(func=cmd_report)


def cmd_synthetic(args) -> int:
    import numpy as np

    from .synthetic import write_campaign

    speeds = np.linspace(args.min_speed, args.max_speed, args.points)
    undeclared = (args.points // 2,) if args.undeclared else ()
    manifest = write_campaign(args.out, speeds, runs=args.runs, seed=args.seed, undeclared=undeclared,
                              duration=args.duration)
    print(f"{args.points} test points x {args.runs} runs written to {args.out}: {manifest.name} (the manifest), "
          f"truth.csv (the true derivatives){f'; undeclared control delay at point {undeclared[0]}' if undeclared else ''}")
    return 0


def add_synthetic(sub) -> None:
    p = sub.add_parser("synthetic", help="write a synthetic campaign (Navion over airspeed) to try the commands on")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="folder for the runs and the manifest")
    p.add_argument("--points", type=positive_int, default=12, help="test points (default 12)")
    p.add_argument("--runs", type=positive_int, default=4, help="runs per point, the last held out (default 4)")
    p.add_argument("--min-speed", type=positive_float, default=35.0, metavar="M/S", help="lowest airspeed (35)")
    p.add_argument("--max-speed", type=positive_float, default=80.0, metavar="M/S", help="highest airspeed (80)")
    p.add_argument("--duration", type=positive_float, default=15.0, metavar="S", help="run length (15)")
    p.add_argument("--seed", type=int, default=0, help="random seed (0)")
    p.add_argument("--undeclared", action="store_true",
                   help="one point with a 0.15 s control delay no model declares (it breaks the trends)")
    p.set_defaults(func=cmd_synthetic)
