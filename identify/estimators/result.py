"""Identification results: parameter table with standard errors, fit metrics, export.

Every estimator returns an :class:`IdentificationResult`, in the spirit of a statsmodels results
object: ``summary()`` prints a table an engineer can paste into a report; ``to_dict()`` /
``save()`` give ``result.json`` and the identified model as a profile TOML, which can be the next a
priori model.

``result.json`` is strict JSON (``allow_nan=False``): a value that is not finite (the infinite
standard error of a parameter no input excites, a NaN) is written as ``null``, as its ``notes``
say; long per-sample or per-segment arrays are summarised so that the file stays small (well
under 1 MB for an hour of data) — the time histories themselves belong in the plots and runs.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..model.linear import LinearModel, format_modes
from ..model.profile import Profile
from . import identifiability
from .prior import summary_lines as prior_summary_lines
from .whiteness import whiteness_line


def insensitivity(cov: np.ndarray) -> np.ndarray:
    """Tischler & Remple's insensitivity (p,) from a covariance (p, p): the standard error each
    parameter would have were all the others known, ``1 / sqrt(F_ii)`` with ``F = cov^-1`` the
    information matrix (the Hessian of the fit cost). Large: the fit hardly depends on the
    parameter at all. The Cramér-Rao bound ``sqrt((F^-1)_ii)`` is never smaller; much larger than
    the insensitivity: the parameter is correlated with others. inf where the variance is not finite."""
    d = np.diag(cov)
    ok = np.isfinite(d) & (d > 0)
    out = np.full(d.shape, np.inf)
    if ok.any():
        sub = cov[np.ix_(ok, ok)]
        try:
            info = np.linalg.inv(sub)
        except np.linalg.LinAlgError:
            info = np.linalg.pinv(sub)
        with np.errstate(divide="ignore"):
            out[ok] = 1 / np.sqrt(np.maximum(np.diag(info), 0.0))
    return out


def theil(measured: np.ndarray, modelled: np.ndarray) -> float:
    """Theil inequality coefficient: 0 is a perfect fit, 1 the worst possible."""
    num = np.sqrt(np.mean((measured - modelled) ** 2))
    den = np.sqrt(np.mean(measured ** 2)) + np.sqrt(np.mean(modelled ** 2))
    return float(num / den) if den > 0 else 0.0


def fit_metrics(outputs: list[str], measured: list[np.ndarray], modelled: list[np.ndarray]) -> dict:
    """RMS error and Theil coefficient per output over all runs (arrays (N_r, ny) per run)."""
    z, y = np.vstack(measured), np.vstack(modelled)
    return {name: {"rms": float(np.sqrt(np.mean((z[:, j] - y[:, j]) ** 2))), "theil": theil(z[:, j], y[:, j])}
            for j, name in enumerate(outputs)}


@dataclass
class IdentificationResult:
    """Estimates of a profile's free parameters.

    ``theta`` (p,) estimates; ``std`` (p,) standard errors (Cramér-Rao bounds, by default
    corrected for coloured residuals: ``info["standard_errors"]`` says which); ``profile`` the a priori
    profile (structure and a priori values); ``fit`` {output: {"rms", "theil"}}; ``info`` method
    details (iterations, cost history, per-run initial states and zero shifts, ...); ``runs`` the
    runs' sources.
    """

    method: str
    profile: Profile
    theta: np.ndarray
    std: np.ndarray
    fit: dict[str, dict[str, float]] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    runs: list[str] = field(default_factory=list)
    # (p, p) covariance of theta (std = sqrt of its diagonal); None: only the stds are known
    covariance: np.ndarray | None = field(default=None, repr=False)
    # per run, for plots and residual analysis (not written to JSON): time (N,), measured and
    # modelled outputs (N, ny) in the order of profile.outputs
    time: list[np.ndarray] = field(default_factory=list, repr=False)
    measured: list[np.ndarray] = field(default_factory=list, repr=False)
    modelled: list[np.ndarray] = field(default_factory=list, repr=False)
    # where ``modelled`` is not a simulation (the filter-error method's one-step predictions): the
    # identified model's open-loop simulation of each run, (N, ny), beside it in the plots
    simulated: list[np.ndarray] = field(default_factory=list, repr=False)

    def __post_init__(self):
        """A standard error that is not a positive number (a variance clipped at zero or negative:
        the covariance is not positive definite, e.g. after a fit stopped short of the minimum),
        a parameter that duplicates the zero shift fitted per run and the members of an exactly
        redundant set are not determined: NaN, with the reason in ``info["not_determined"]``."""
        self.theta = np.asarray(self.theta, dtype=float)
        self.std = np.array(self.std, dtype=float)
        reasons = dict(self.info.get("not_determined") or {})
        for i, s in enumerate(self.std):
            if not (s > 0):  # 0, negative or NaN (inf stays: a parameter no input excites)
                reasons.setdefault(self.names[i], "variance not positive (the covariance is not positive definite: "
                                   "a fit stopped before its minimum or a singular information matrix)")
        zero_shift_std = self.info.get("zero_shift_std") or []
        # only outputs whose zero shift was estimated in some run (a held one has an infinite std; FEM
        # lists them all, held ones too)
        shifted = {y for run in zero_shift_std for y, s in run.items() if not np.isinf(s)}
        if shifted:
            for name, y in identifiability.zero_shift_duplicates(self.model).items():
                if y not in shifted:
                    continue
                reasons[name] = (f"a declared output bias on '{y}' duplicating the zero shift fitted per run "
                                 f"(only their sum is determined: drop the bias or fit without zero shifts)")
        if self.covariance is not None and len(self.names) > 1:
            for r in identifiability.redundant(self.names, self.theta, self.covariance):
                for name in r["parameters"] if r["exact"] else ():
                    reasons.setdefault(name, f"exactly redundant with {', '.join(n for n in r['parameters'] if n != name)}"
                                       + (f" (determined: {r['determined']})" if r["determined"] else ""))
        for name in reasons:
            if name in self.names:
                self.std[self.names.index(name)] = np.nan
        if reasons:
            self.info["not_determined"] = reasons

    def residuals(self) -> list[np.ndarray]:
        """Measured minus modelled outputs, (N, ny) per run."""
        return [z - y for z, y in zip(self.measured, self.modelled)]

    @property
    def names(self) -> list[str]:
        return self.profile.free_names

    @property
    def apriori(self) -> np.ndarray:
        return np.array(list(self.profile.free.values()))

    @property
    def relative_std(self) -> np.ndarray:
        """Standard error in % of |estimate| (inf where the estimate is 0)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100 * self.std / np.abs(self.theta)

    @property
    def model(self) -> LinearModel:
        return LinearModel(self.profile, self.theta)

    @property
    def converged(self) -> bool:
        """False only when an iterative estimator stopped before convergence."""
        return bool(self.info.get("converged", True))

    @property
    def correlation(self) -> np.ndarray:
        """(p, p) parameter correlation matrix (identity where only the stds are known)."""
        return identifiability.correlation(self.parameter_covariance())

    def identifiability(self) -> dict:
        """Correlated pairs, poorly determined parameters and modes whose stability these runs do
        not determine (:func:`identify.identifiability.assess`)."""
        check = identifiability.assess(self.names, self.theta, self.std, self.parameter_covariance(), self.model)
        held = {n for names in self.info.get("held", {}).values() for n in names}
        # a degenerate fit's bounds are no measure (said on their own line): not "poorly determined"
        held |= {n for n, why in (self.info.get("not_determined") or {}).items() if why.startswith("not meaningful")}
        if held:  # held at the a priori, said on their own line: not "poorly determined"
            check["poorly_determined"] = [n for n in check["poorly_determined"] if n not in held]
        return check

    @property
    def insensitivity(self) -> np.ndarray:
        """Tischler & Remple's insensitivity (p,), units of theta: see :func:`insensitivity`."""
        return insensitivity(self.parameter_covariance())

    def accuracy(self) -> dict[str, dict]:
        """Per parameter the Cramér-Rao % and insensitivity % of the estimate and the guidelines
        each exceeds (Tischler & Remple: CR % <= 20, insensitivity % <= 10 for a parameter worth
        keeping in a frequency-domain fit)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            ins = 100 * self.insensitivity / np.abs(self.theta)
        out = {}
        for name, cr, i in zip(self.names, self.relative_std, ins):
            over = ([f"CR > {CR_GUIDELINE:g} %"] if not cr <= CR_GUIDELINE else []) + \
                   ([f"insensitive (I > {INSENSITIVITY_GUIDELINE:g} %)"] if not i <= INSENSITIVITY_GUIDELINE else [])
            out[name] = {"cramer_rao_pct": float(cr), "insensitivity_pct": float(i), "over_guidelines": over}
        return out

    def accuracy_lines(self) -> list[str]:
        """The :meth:`accuracy` table for reports; a parameter over a guideline is flagged."""
        lines = [f"accuracy (Tischler & Remple guidelines: Cramér-Rao % <= {CR_GUIDELINE:g}, "
                 f"insensitivity % <= {INSENSITIVITY_GUIDELINE:g}):",
                 f"{'parameter':<18}{'CR %':>10}{'insens. %':>11}  flag"]
        for name, a in self.accuracy().items():
            lines.append(f"{name:<18}{a['cramer_rao_pct']:10.1f}{a['insensitivity_pct']:11.1f}  "
                         f"{', '.join(a['over_guidelines'])}".rstrip())
        bad = [n for n, a in self.accuracy().items() if a["over_guidelines"]]
        lines.append(f"over a guideline: {', '.join(bad)} -- consider fixing or dropping them" if bad
                     else "all parameters within the guidelines")
        return lines

    def parameter_covariance(self) -> np.ndarray:
        """(p, p) covariance of the estimates: the full matrix, or the stds' diagonal where only
        they are known."""
        return np.diag(self.std ** 2) if self.covariance is None else self.covariance

    def parameters(self) -> dict[str, float]:
        return dict(zip(self.names, map(float, self.theta)))

    def compare_lr_test(self, restricted: "IdentificationResult") -> tuple[float, int] | None:
        """statsmodels' ``compare_lr_test``: the likelihood-ratio statistic of this fit against a
        nested ``restricted`` fit of the same data, and its degrees of freedom (the parameters this
        fit adds), in the criterion the estimator minimised, where it records one
        (``info["criterion"]``); None where it does not (output error, filter error: the caller
        measures the likelihoods on the residuals itself, as refine does).

        The record: ``cost`` the minimised sum of squares, ``dispersion`` its residual variance
        per point (cost / (points - parameters)) and ``inflation`` {parameter: factor} by which
        the points' correlation and weighting enlarge the variance of the parameter over the bound
        that takes the points as independent (NaN where not measured). Statistic: the cost's drop
        over ``dispersion`` times the added parameters' mean inflation (a mean-scaled statistic
        with independent points' degrees of freedom, Satorra and Bentler's correction), so that a
        null effect gives chi-square(df) although neighbouring points are not independent; NaN
        when an added parameter's inflation is unknown."""
        mine, theirs = self.info.get("criterion"), restricted.info.get("criterion")
        added = [n for n in self.names if n not in restricted.names]
        if not (mine and theirs) or mine.get("kind") != theirs.get("kind") or not added:
            return None
        inflation = np.mean([mine.get("inflation", {}).get(n, np.nan) for n in added])
        return float((theirs["cost"] - mine["cost"]) / (mine["dispersion"] * inflation)), len(added)

    def identified_profile(self, name: str | None = None) -> Profile:
        return self.model.to_profile(name or f"{self.profile.name} - identified ({self.method.upper()})")

    def summary(self, truth: dict[str, float] | None = None) -> str:
        """Parameter table (estimate, standard error, rel. std %, a priori [, truth]), fit and modes."""
        head = f"{'parameter':<18}{'estimate':>13}{'std error':>12}{'rel. std %':>11}{'a priori':>12}"
        if truth:
            head += f"{'truth':>12}"
        lines = [f"{self.method.upper()} identification of '{self.profile.name}' from "
                 f"{len(self.runs) or 1} run(s)", head, "-" * len(head)]
        for name, v, s, r, a in zip(self.names, self.theta, self.std, self.relative_std, self.apriori):
            spread = f"{s:12.4g}{r:11.2f}" if not np.isnan(s) else f"{'not determined':>23}"
            row = f"{name:<18}{v:13.6g}{spread}{a:12.5g}"
            if truth:
                row += f"{truth.get(name, float('nan')):12.5g}"
            lines.append(row)
        lines.append(f"standard errors: {self.info.get('standard_errors', 'Cramér-Rao (white residuals)')}")
        if self.info.get("bounds_choice"):
            lines.append(f"bounds: {self.info['bounds_choice']}")
        if self.info.get("whiteness"):
            lines.append(whiteness_line(self.info["whiteness"], "innovations" if "process_noise" in self.info
                                        else "residuals"))
        if self.info.get("degenerate"):
            lines.append(f"warning: {self.info['degenerate']}")
        if self.info.get("held_note"):
            lines.append(f"held (std inf): {self.info['held_note']}")
        lines += _not_determined_lines(self.info.get("not_determined", {}))
        if self.info.get("ill_conditioned"):
            lines.append("warning: the information matrix is ill-conditioned (rank deficient to rounding): "
                         "some parameter or combination is not determined by these runs")
        lines.append(self._convergence_line())
        lines += _noise_lines(self.info)
        if self.info.get("estimator_advice"):
            lines.append(f"note: {self.info['estimator_advice']}")
        if self.info.get("prior"):
            lines += prior_summary_lines(self.info["prior"])
        if self.fit:
            lines += ["", f"{'output':<18}{'RMS error':>12}{'Theil U':>10}"]
            lines += [f"{k:<18}{v['rms']:12.4g}{v['theil']:10.4f}" for k, v in self.fit.items()]
            if self.info.get("modelled"):
                lines.append(f"(modelled outputs: {self.info['modelled']})")
        if self.info.get("frequency_domain"):  # the CIFER-style view of a frequency-domain fit
            lines += [""] + self.accuracy_lines()
        lines += ["", "modes of the identified model:", format_modes(self.model.modes())]
        check = identifiability.report_lines(self.identifiability())
        return "\n".join(lines + ([""] + check if check else []))

    def _convergence_line(self) -> str:
        if "converged" not in self.info:
            return "convergence: not iterative (one least-squares solution)"
        it, stop = self.info.get("iterations"), self.info.get("stop", "")
        if self.info["converged"]:
            return f"convergence: converged after {it} iterations ({stop})" if stop else \
                f"convergence: converged after {it} iterations"
        return f"convergence: NOT CONVERGED after {it} iterations ({stop}): the estimates are not final"

    def markdown(self, truth: dict[str, float] | None = None, start: dict[str, float] | None = None,
                 start_label: str = "a priori") -> str:
        """The :meth:`summary` as Markdown for reports: parameter table, fit table, modes. The
        ``start_label`` column holds ``start`` values where given (``-`` for a parameter it lacks),
        else the profile's values, the fit's starting point (the a priori for a first fit)."""
        cols = ["parameter", "estimate", "std error", "rel. std %", start_label] + (["truth"] if truth else [])
        lines = [f"{self.method.upper()} identification of `{self.profile.name}` from "
                 f"{len(self.runs) or 1} run(s).", "", "| " + " | ".join(cols) + " |",
                 "| --- |" + " ---: |" * (len(cols) - 1)]
        for name, v, s, r, a in zip(self.names, self.theta, self.std, self.relative_std, self.apriori):
            a = a if start is None else start.get(name)
            cells = [f"`{name}`", f"{v:.6g}"] + ([f"{s:.4g}", f"{r:.2f}"] if not np.isnan(s) else
                                                ["not determined", "-"]) + ["-" if a is None else f"{a:.5g}"]
            if truth:
                cells.append(f"{truth.get(name, float('nan')):.5g}")
            lines.append("| " + " | ".join(cells) + " |")
        lines += ["", f"Standard errors: {self.info.get('standard_errors', 'Cramér-Rao (white residuals)')}."]
        lines += [f"Not determined: `{n}`: {why}." for n, why in self.info.get("not_determined", {}).items()]
        if self.fit:
            lines += ["", "| output | RMS error | Theil U |", "| --- | ---: | ---: |"]
            lines += [f"| {k} | {v['rms']:.4g} | {v['theil']:.4f} |" for k, v in self.fit.items()]
        lines += ["", "Modes of the identified model:", "", "```", format_modes(self.model.modes()), "```"]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """A JSON-ready dict: non-finite floats become None (strict JSON), long arrays summaries."""
        check = self.identifiability()
        modes = [{"real": m.eigenvalue.real, "imag": m.eigenvalue.imag, "frequency": m.frequency,
                  "damping": m.damping} for m in self.model.modes()]
        for m, u in zip(modes, check["modes"]):  # both slowest first, one per conjugate pair
            m.update(std_real=u["std_real"], std_imag=u["std_imag"],
                     stability_determined=u["stability_determined"])
        out = {
            "method": self.method,
            "profile": self.profile.name,
            "runs": self.runs,
            "converged": self.converged,
            "parameters": {n: {"value": float(v), "std": float(s), "apriori": float(a), **_prior_of(self.info, n)}
                           for n, v, s, a in zip(self.names, self.theta, self.std, self.apriori)},
            "correlation": {"names": self.names, "matrix": self.correlation},
            "identifiability": check,
            "fit": self.fit,
            "eigenvalues": modes,
            "info": _summarised(self.info),
            "notes": [NULL_NOTE],
            "profile_toml": self.profile.to_toml(),  # the a priori, so that from_json rebuilds the result
        }
        return jsonable(out)

    def save(self, outdir: str | Path) -> Path:
        """Write ``result.json``, ``identified_profile.toml``, ``summary.txt`` (the :meth:`summary`)
        and, when the result holds them, the time histories (``time_histories.npz``: what
        :meth:`from_json` needs to re-plot) into ``outdir``."""
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        (outdir / "result.json").write_text(dumps(self.to_dict()))
        self.identified_profile().save(outdir / "identified_profile.toml")
        (outdir / "summary.txt").write_text(self.summary() + "\n")
        if self.time:
            arrays = {f"{kind}_{r}": a for kind, seq in (("time", self.time), ("measured", self.measured),
                                                         ("modelled", self.modelled), ("simulated", self.simulated))
                      for r, a in enumerate(seq)}
            np.savez_compressed(outdir / HISTORIES, **arrays)
        return outdir

    @classmethod
    def from_json(cls, path: str | Path) -> "IdentificationResult":
        """The result ``save`` wrote to ``path`` (``result.json``), to re-plot or compare without
        re-fitting: estimates, standard errors, covariance (from the stored correlation), fit, info
        and, if ``time_histories.npz`` lies beside it, the runs' measured and modelled outputs.
        Long info arrays come back as stored (cut, see ``_summarised``); None values as NaN/inf."""
        from ..errors import RunError
        from ..model.profile import parse_profile
        path = Path(path)
        try:
            data = json.loads(path.read_text())
            profile = parse_profile(data["profile_toml"], source=f"{path} (profile_toml)")
            params = data["parameters"]
        except (OSError, ValueError, KeyError) as exc:
            raise RunError(f"{path}: not a result.json that identify wrote ({exc})") from None
        names = profile.free_names
        theta = np.array([params[n]["value"] for n in names], float)
        std = np.array([np.inf if params[n]["std"] is None else params[n]["std"] for n in names], float)
        corr = np.array([[np.nan if c is None else c for c in row] for row in data["correlation"]["matrix"]], float)
        with np.errstate(invalid="ignore"):
            cov = corr * np.outer(std, std)
        np.fill_diagonal(cov, std ** 2)
        result = cls(data["method"], profile, theta, std, data.get("fit", {}), data.get("info", {}),
                     data.get("runs", []), covariance=cov)
        histories = path.with_name(HISTORIES)
        if histories.exists():
            with np.load(histories) as z:
                for r in range(sum(k.startswith("time_") for k in z.files)):
                    result.time.append(z[f"time_{r}"])
                    result.measured.append(z[f"measured_{r}"])
                    result.modelled.append(z[f"modelled_{r}"])
                    if f"simulated_{r}" in z.files:
                        result.simulated.append(z[f"simulated_{r}"])
        return result

def _not_determined_lines(reasons: dict) -> list[str]:
    """One line per reason, the parameters that share it listed together."""
    grouped: dict[str, list[str]] = {}
    for name, why in reasons.items():
        grouped.setdefault(why, []).append(name)
    return [f"not determined: {', '.join(names)}: {why}" for why, names in grouped.items()]


def _prior_of(info: dict, name: str) -> dict:
    """A parameter's prior and data share for result.json (the estimate is the posterior), or nothing."""
    entry = (info.get("prior") or {}).get("parameters", {}).get(name)
    if not entry:
        return {}
    return {"prior": entry["prior"], "data_share": entry["data_share"], "decided_by_prior": entry["decided_by_prior"]}


def _noise_lines(info: dict) -> list[str]:
    """The filter-error method's noise estimates: F and R with their bounds ("not determined" on
    a boundary, never 0)."""
    if "process_noise" not in info:
        return []

    def bound(s):
        return f"{s:.3g}" if np.isfinite(s) else "not determined"

    lines = [""] + ([info["process_noise_model"]] if info.get("process_noise_model") else [])
    lines += _turbulence_lines(info.get("turbulence"))
    if info.get("r_start_choice"):
        lines.append(f"R start: {info['r_start_choice']}")
    lines.append(f"process noise F ({info['process_noise_convention']}):")
    lines += [f"  {k:<16}{v['F']:12.4g}  std {bound(v['std'])}" for k, v in info["process_noise"].items()] or ["  none"]
    lines.append("measurement noise R (variances, output units squared):")
    lines += [f"  {k:<16}{v['variance']:12.4g}  std {bound(v['std'])}" for k, v in info["measurement_noise"].items()]
    return lines + [f"  note: {n}: {why}" for n, why in info.get("not_determined", {}).items()
                     if n.startswith(("F of ", "R of "))]


def _turbulence_lines(turb: dict | None) -> list[str]:
    """The fitted gusts: corner and intensity per velocity with their bounds."""
    if not turb:
        return []

    def pm(v, s, held=False):
        return f"{v:.4g} (held)" if held else f"{v:.4g} ± {s:.2g}" if s is not None and np.isfinite(s) else f"{v:.4g} (bound not determined)"

    lines = ["turbulence (gust std = F / sqrt(2 corner); bounds: 1 std):"]
    for s, g in turb["gusts"].items():
        extra = f" = {g['intensity_m_s']:.3g} m/s" if g.get("intensity_m_s") is not None else ""
        lines.append(f"  {s:<6} corner {pm(g['corner'], g.get('corner_std'), not g['corner_estimated'])} rad/s, "
                     f"intensity {pm(g['intensity'], g['intensity_std'])} {g['unit']}{extra}")
    return lines


HISTORIES = "time_histories.npz"  # the runs' time, measured and modelled outputs beside result.json
CR_GUIDELINE, INSENSITIVITY_GUIDELINE = 20.0, 10.0  # %: Tischler & Remple's marks of a parameter worth keeping
NULL_NOTE = ("null stands for a value that is not finite: an infinite standard error (a parameter no input excites) "
             "or NaN (not determined: the reason in info.not_determined)")
MAX_LAGS = 200  # noise autocorrelation lags kept in result.json
MAX_LISTED = 100  # per-segment entries kept in result.json


def dumps(obj) -> str:
    """Strict JSON text (no NaN/Infinity: they must be None already, see :func:`jsonable`)."""
    return json.dumps(jsonable(obj), indent=1, allow_nan=False)


def _summarised(info: dict) -> dict:
    """``info`` with the long arrays cut: the noise autocorrelation to its first MAX_LAGS lags,
    the per-segment list to its first MAX_LISTED entries (the count and a note say so)."""
    info = dict(info)
    acf = info.get("noise_autocorrelation")
    if acf is not None and len(acf) > MAX_LAGS:
        info["noise_autocorrelation"] = np.asarray(acf)[:MAX_LAGS]
        info["noise_autocorrelation_note"] = f"first {MAX_LAGS} of {len(acf)} lags"
    segs = info.get("segments")
    if segs is not None and len(segs) > MAX_LISTED:
        info["segments"] = segs[:MAX_LISTED]
        info["segments_note"] = f"first {MAX_LISTED} of {len(segs)} segments listed"
    return info


def jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return jsonable(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, complex):
        return {"real": jsonable(obj.real), "imag": jsonable(obj.imag)}
    return obj
