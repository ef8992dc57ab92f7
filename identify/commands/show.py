"""``identify show``: what the reader made of run files, before anything is fitted: channels with
their units (as read, as used), ranges, sample rate, duration, gaps, trim, notes and warnings;
``--plot`` draws the channels."""
from __future__ import annotations

from ..cliutil import output_file
from . import options


def add_parser(sub) -> None:
    p = sub.add_parser("show", help="what the reader makes of run files: channels, units, ranges, rate, gaps, warnings")
    p.add_argument("runs", nargs="+", help="run files (.csv or .mat)")
    p.add_argument("--profile", help="profile whose units undeclared channels are checked against and whose "
                                     "delays and pseudo-inputs are applied (optional)")
    options.add_reading(p)
    p.add_argument("--plot", metavar="PNG", type=output_file,
                   help="draw every run's channels into this PNG (several runs: _run<k> added to the name)")
    p.set_defaults(func=cmd_show)


def cmd_show(args) -> int:
    from dataclasses import replace

    from ..model.profile import load_profile

    profile = load_profile(args.profile) if args.profile else None
    reading = replace(options.reading(args), trim=None)  # ranges as read; the trim said beside them
    runs = reading.prepared(args.runs, profile) if profile is not None else reading.recorded(args.runs)
    for run in runs:
        print("\n".join(describe(run, profile, args.trim)) + "\n")
    if args.plot:
        paths = [plot_channels(run, _numbered(args.plot, k, len(runs))) for k, run in enumerate(runs)]
        print(f"written: {', '.join(str(p) for p in paths)}")
    return 0


def describe(run, profile=None, trim: str | None = None) -> list[str]:
    """Lines saying what a run holds and how it was read (see the module notes); ``trim`` the
    trim values ``--trim`` would remove, per channel."""
    import numpy as np

    from ..data import units as U

    declared = dict(item.split("=", 1) for item in _items(run.meta.get("units_declared")))
    expected = dict(profile.states) | dict(profile.inputs) if profile is not None else {}
    trims = _trim_values(run, trim) if trim else {}
    lines = [f"{run.source}: {len(run)} samples at {1 / run.dt:.6g} Hz (dt {run.dt:.6g} s), "
             f"{run.duration:.6g} s (t = {run.time[0]:.6g} .. {run.time[-1]:.6g})",
             f"  {'channel':<16}{'unit read':<14}{'unit used':<16}{'min':>12}{'max':>12}"
             + (f"{'trim':>12}" if trim else "") + "   as read"]
    for name, v in run.channels.items():
        read = declared.get(name)
        if read is not None:
            used = U.si_unit(read)
            factor = U.UNITS[U.canonical(read)][0]
            as_read = f"{np.min(v) / factor:.4g} .. {np.max(v) / factor:.4g} {read}" if factor != 1.0 else ""
        else:
            read, as_read = "(none)", ""
            used = f"{expected[name]} (profile)" if name in expected else "SI (assumed)"
        cut = f"{trims[name]:12.4g}" if name in trims else (f"{'-':>12}" if trim else "")
        lines.append(f"  {name:<16}{read:<14}{used:<16}{np.min(v):12.4g}{np.max(v):12.4g}{cut}   {as_read}".rstrip())
    if trim:
        lines.append(f"  trim: {trim} (the values --trim {trim} removes, in the units used)")
    for key, label in (("time_gaps", "gaps"), ("segment", "segment"), ("dropped_samples", "dropped"),
                       ("interpolated_samples", "interpolated"), ("resampled", "resampled"),
                       ("time_jitter", "time jitter"), ("derived", "derived"), ("channel_map", "channel map")):
        if key in run.meta:
            lines.append(f"  {label}: {run.meta[key]}")
    lines += [f"  processing: {step}" for step in _steps(run)]
    lines += [f"  note: {n}" for n in _items(run.meta.get("notes"), "; ")]
    lines += [f"  warning: {w}" for w in _items(run.meta.get("warnings"), "; ")]
    return lines


def _trim_values(run, trim: str) -> dict[str, float]:
    from ..data.preprocess import processing_steps, remove_trim

    return processing_steps(remove_trim(run, trim))[-1].get("values", {})


def _items(text, sep: str = ", ") -> list[str]:
    return [t.strip() for t in str(text).split(sep) if t.strip()] if text else []


def _steps(run) -> list[str]:
    """The processing steps (trim removed, window, smoothing), one line each."""
    import json

    from ..data.preprocess import processing_steps

    return [json.dumps(s, separators=(",", ":")) for s in processing_steps(run)] if run.meta.get("processing") else []


def _numbered(path: str, k: int, n: int) -> str:
    from pathlib import Path

    p = Path(path)
    return str(p if n == 1 else p.with_name(f"{p.stem}_run{k + 1}{p.suffix or '.png'}"))


def plot_channels(run, path: str):
    """Every channel of ``run`` against time, one panel each, as a PNG (an Agg canvas)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = list(run.channels)
    fig = Figure(figsize=(8, 1.3 * len(names) + 0.8))
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, names):
        ax.plot(run.time, run[name], linewidth=0.8)
        ax.set_ylabel(name, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    axes[0].set_title(run.source, fontsize=9)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    return path
