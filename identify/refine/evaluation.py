"""What refine measures on a model's prediction: errors, likelihoods, the validation split, the
identifiability check before the first fit and the residual left after candidate columns.

The prediction itself (a model on runs, state-built terms from its simulated states) is the
estimator's: :mod:`identify.estimators.prediction`.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..estimators.prediction import ModelFit, block_design, evaluate
from ..model.profile import Profile

MIN_SAMPLES = 50  # per run: fewer leave the residual tests without power
HOLD_OUT = 1 / 3  # of each run's excitation held out (to choose and judge) when no validation runs are given


def unexplained(residuals: list[np.ndarray], shared: list[np.ndarray], nuisance: list[np.ndarray],
                sigma: np.ndarray, extra: list[list[np.ndarray]] = ((),)) -> list[list[np.ndarray]]:
    """Residuals (N_r, ny) per run minus their least-squares fit on the columns ``shared``
    (N_r, ny, k, common to all runs) and ``nuisance`` (N_r, ny, k_r, per run), weighted 1/sigma,
    and on each group of ``extra`` columns in turn (per run (N_r, ny, q)): a list of runs per group
    (one for no extra). The common columns' Gram matrix is formed once, each group's border added."""
    return unexplaining(residuals, shared, nuisance, sigma)(extra)


def unexplaining(residuals: list[np.ndarray], shared: list[np.ndarray], nuisance: list[np.ndarray],
                 sigma: np.ndarray):
    """:func:`unexplained` as a function of the groups ``extra`` alone: the common columns'
    Gram matrix formed once for every call (refine's score round adds groups after rejections)."""
    w = np.tile(1.0 / sigma, sum(len(e) for e in residuals))

    def normed(C: np.ndarray) -> np.ndarray:
        C = C * w[:, None]
        return C / np.maximum(np.linalg.norm(C, axis=0), 1e-300)

    B = normed(block_design(shared, nuisance))
    e = np.concatenate([r.ravel() for r in residuals]) * w
    G, g = B.T @ B, B.T @ e

    def fitted(extra: list[list[np.ndarray]] = ((),)) -> list[list[np.ndarray]]:
        out = []
        for group in extra:
            C = normed(np.concatenate([c.reshape(-1, c.shape[2]) for c in group])) if len(group) else B[:, :0]
            BC = B.T @ C
            full = np.block([[G, BC], [BC.T, C.T @ C]])
            coef = np.linalg.solve(full + 1e-10 * np.trace(full) / len(full) * np.eye(len(full)),
                                   np.r_[g, C.T @ e])
            clean = (e - B @ coef[:len(G)] - C @ coef[len(G):]) / w
            parts = np.split(clean, np.cumsum([r.size for r in residuals])[:-1])
            out.append([c.reshape(r.shape) for c, r in zip(parts, residuals)])
        return out

    return fitted


def errors(evaluation: ModelFit, outputs, scale: np.ndarray) -> dict:
    """RMS error per output and the normalised ``overall`` (see the module docstring)."""
    E = np.vstack(evaluation.residuals)
    rms = np.sqrt(np.mean(E ** 2, axis=0))
    out = {y: float(r) for y, r in zip(outputs, rms)}
    out["overall"] = float(np.sqrt(np.mean((rms / scale) ** 2)))
    return out


def neg_log_likelihood(residuals: list[np.ndarray]) -> float:
    """Concentrated Gaussian negative log-likelihood with a diagonal noise covariance estimated
    from the residuals: (N/2) sum_y log(mean e_y^2)."""
    E = np.vstack(residuals)
    return 0.5 * E.shape[0] * float(np.sum(np.log(np.maximum(np.mean(E ** 2, axis=0), 1e-300))))


def split_validation(runs: list[Run], inputs: list[str] | None = None) -> tuple[list[Run], list[Run]]:
    """Validation runs into a *choosing* and a *judging* part, each run cut in two in time where
    its input excitation is shared half and half (:func:`excitation_midpoint`), so that both parts
    carry every input that was flown: flight tests fly one run per control axis, and a split by
    whole runs gives each part only some axes (an effect on one input, a delay, could then be
    judged only on data that cannot show it). The first part chooses in even-numbered runs, the
    second in odd ones. A run too short for two parts of ``MIN_SAMPLES`` only judges."""
    choose, judge = [], []
    for i, r in enumerate(runs):
        if len(r) < 2 * MIN_SAMPLES:
            judge.append(r)
            continue
        k = excitation_midpoint(r, inputs if inputs is not None else [])
        first = replace(r.slice(None, r.time[k] - 0.5 * r.dt), source=f"{r.source} [to {r.time[k]:.3g} s]")
        second = replace(r.slice(r.time[k], None), source=f"{r.source} [from {r.time[k]:.3g} s]")
        a, b = (first, second) if i % 2 == 0 else (second, first)
        choose.append(a)
        judge.append(b)
    return choose, judge


def hold_out(runs: list[Run], inputs: list[str], share: float = HOLD_OUT) -> tuple[list[Run], list[Run]]:
    """Without validation runs: each run cut in time where ``1 - share`` of its input excitation
    has passed (:func:`excitation_midpoint`), the first part fitted and the rest held out, so that
    the held-out data carry every input that was flown (one run per control axis: every run gives
    its part). A run shorter than ``3 MIN_SAMPLES`` is only fitted. ``(fit, held)``."""
    fit, held = [], []
    for r in runs:
        if len(r) < 3 * MIN_SAMPLES:
            fit.append(r)
            continue
        k = min(excitation_midpoint(r, inputs, 1.0 - share), len(r) - 2 * MIN_SAMPLES)
        fit.append(replace(r.slice(None, r.time[k] - 0.5 * r.dt), source=f"{r.source} [to {r.time[k]:.3g} s]"))
        held.append(replace(r.slice(r.time[k], None), source=f"{r.source} [from {r.time[k]:.3g} s]"))
    return fit, held


HELD_OUT_NOTE = {True: "no validation runs: the last third of each run's input excitation is held out to choose and "
                       "judge effects, the rest fitted", False: f"no validation runs and none long enough to hold a "
                 f"part out ({3 * MIN_SAMPLES} samples): effects are judged by the tests alone"}  # said by refine


def excitation_midpoint(run: Run, inputs: list[str], share: float = 0.5) -> int:
    """The sample that halves the run's input excitation (or leaves ``share`` of it before): each
    input's squared deviation from its median, normalised to a unit sum per input (so that every
    flown input counts alike), summed and accumulated; that share of the samples when no input
    varies. Kept ``MIN_SAMPLES`` from either end."""
    N = len(run)
    energy = np.zeros(N)
    for name in inputs:
        if name not in run.channels:
            continue
        e = (run[name] - np.median(run[name])) ** 2
        if e.sum() > 0:
            energy += e / e.sum()
    k = int(np.searchsorted(np.cumsum(energy), share * energy.sum())) if energy.sum() > 0 else int(share * N)
    return int(np.clip(k, MIN_SAMPLES, N - MIN_SAMPLES))


def check_identifiable(p: Profile, runs: list[Run], zero_shifts: bool, segment: float) -> None:
        """The fitted model's parameters must be identifiable beside the nuisance: rank test of the
        weighted sensitivity matrix, naming the parameters in its null space."""
        ev = evaluate(p, runs, zero_shifts, segment, jacobian=True)
        J = block_design(ev.dy, ev.nuisance)
        sigma = np.sqrt(np.mean(np.vstack(ev.residuals) ** 2, axis=0))
        Jw = J * np.tile(1 / np.where(sigma > 0, sigma, 1.0), len(J) // len(sigma))[:, None]
        names = p.free_names
        npar = len(names)
        # parameters beside the nuisance (initial states, zero shifts): project those out first, so
        # that an unobservable state's initial value is not mistaken for an unidentifiable parameter
        U, sn, _ = np.linalg.svd(Jw[:, npar:], full_matrices=False)
        Q = U[:, sn > 1e-10 * max(sn.max(initial=0.0), 1e-300)]
        Jp = Jw[:, :npar] - Q @ (Q.T @ Jw[:, :npar])
        Jp = Jp / np.maximum(np.linalg.norm(Jw[:, :npar], axis=0), 1e-300)
        _, s, Vt = np.linalg.svd(Jp, full_matrices=False)
        if s[-1] < 1e-7 * max(s[0], 1e-300) or s[0] == 0:
            null = Vt[s < 1e-7 * max(s[0], 1e-300)] if s[0] > 0 else Vt
            worst = [names[i] for i in np.flatnonzero(np.max(np.abs(null), axis=0) > 0.1)]
            raise EstimationError(f"profile '{p.name}': free parameters not identifiable from these runs "
                                  f"(no information separates {', '.join(worst)}); "
                                  f"fix some or add excitation")


__all__ = ["errors", "neg_log_likelihood", "unexplained", "unexplaining", "split_validation", "hold_out",
           "excitation_midpoint", "check_identifiable", "MIN_SAMPLES", "HOLD_OUT", "HELD_OUT_NOTE"]
