"""Identifiability of an estimate: what the runs could not pin down, said in the open.

From the parameter covariance (p, p) of an estimate (Cramér-Rao, possibly corrected for coloured
residuals) three checks, all first-order (linearised about the estimate):

* **correlation**: pairs of parameters with ``|rho| > CORRELATION_LIMIT`` — the runs move them
  together, so each alone is poorly known (Morelli & Klein flag |rho| > 0.9);
* **poorly determined**: parameters whose standard error exceeds ``REL_STD_LIMIT`` of their
  magnitude (the estimate is not distinguishable from zero at about 2 sigma);
* **modes**: the standard deviation of every eigenvalue's real part from the eigenvalue
  sensitivities ``d lambda / d theta_i = w^H dA_i v / (w^H v)`` (v, w right and left
  eigenvectors). A mode whose real part lies within ``MODE_SIGMAS`` standard deviations of zero
  has a stability the runs do not determine: its estimate may be stable or unstable by chance
  (e.g. a phugoid a 3211 barely excites). The parameters that move it most are named.

Two more say what the runs cannot separate at all:

* **redundant**: a pair with ``|rho| >= REDUNDANT_LIMIT`` or a direction the information matrix
  does not see (scaled eigenvalue below ``RANK_TOL``: rank deficient). The fit determines only the
  combination across it (for a pair ``a - k b``, with its value and standard error), which is
  named; with exact redundancy the parameters' own standard errors are not determined (NaN);
* **zero-shift duplicates**: a declared output bias (a free output-equation entry on a constant
  pseudo-input) where the estimator also fits each run's zero shift of that output: the two are
  the same unknown, so the declared bias is not determined.

The remedy is an input that excites what is missing: ``signaldesign band`` (the frequency band a
mode needs) and ``signaldesign design`` (a sequence with the information in that band).
"""
from __future__ import annotations

import numpy as np

CORRELATION_LIMIT = 0.9
REL_STD_LIMIT = 0.5
MODE_SIGMAS = 2.0
REDUNDANT_LIMIT = 0.999  # |rho|: the pair is (nearly) redundant; only a combination is determined
EXACT_LIMIT = 1 - 1e-7  # |rho|: redundant to rounding (a rank-deficient information matrix)
RANK_TOL = 1e-10  # scaled information eigenvalue / largest: a direction the runs do not see
ADVICE = ("fly an input that excites what is flagged: `signaldesign band` gives the frequency band "
          "these parameters and modes need, `signaldesign design` a sequence with information there")


def correlation(cov: np.ndarray) -> np.ndarray:
    """Correlation matrix (p, p) of a covariance; rows of parameters with zero or infinite
    variance are 0 (their correlation is undefined), the diagonal 1."""
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    ok = np.isfinite(d) & (d > 0)
    rho = np.zeros_like(cov, dtype=float)
    i = np.flatnonzero(ok)
    rho[np.ix_(i, i)] = cov[np.ix_(i, i)] / np.outer(d[i], d[i])
    np.fill_diagonal(rho, 1.0)
    return np.clip(rho, -1.0, 1.0)


def correlated_pairs(names: list[str], rho: np.ndarray, limit: float = CORRELATION_LIMIT) -> list[dict]:
    """Pairs ``{"a", "b", "rho"}`` with |rho| > limit, strongest first."""
    i, j = np.triu_indices(len(names), 1)
    hit = np.abs(rho[i, j]) > limit
    pairs = [{"a": names[a], "b": names[b], "rho": float(rho[a, b])} for a, b in zip(i[hit], j[hit])]
    return sorted(pairs, key=lambda q: -abs(q["rho"]))


def poorly_determined(names: list[str], theta: np.ndarray, std: np.ndarray,
                      limit: float = REL_STD_LIMIT) -> list[str]:
    """Parameters whose standard error exceeds ``limit`` times |estimate| (or is infinite)."""
    return [n for n, v, s in zip(names, theta, std) if not np.isfinite(s) or s > limit * abs(v)]


def mode_uncertainty(model, cov: np.ndarray, sigmas: float = MODE_SIGMAS, n_named: int = 3) -> list[dict]:
    """Per eigenvalue (one per conjugate pair, slowest first): ``real``, ``imag``, ``std_real``,
    ``std_imag`` (1/s or rad/s), ``stability_determined`` (|Re| > sigmas * std_real) and the
    ``parameters`` whose uncertainty moves the real part most (largest |d Re/d theta_i| sigma_i).

    ``model``: a :class:`~identify.LinearModel` at the estimate (``A`` (n, n), ``dA`` (p, n, n)).
    """
    lam, V = np.linalg.eig(model.A)
    try:
        W = np.linalg.inv(V).conj().T  # left eigenvectors, normalised so that w^H v = 1
    except np.linalg.LinAlgError:
        return []  # a defective A: first-order eigenvalue sensitivities do not exist
    grad = np.einsum("ik,pij,jk->kp", W.conj(), model.dA, V)  # (n, p): d lambda_k / d theta_p
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    finite = np.isfinite(std)
    c = np.where(finite[:, None] & finite[None, :], cov, 0.0)
    out = []
    for k in np.argsort(np.abs(lam)):
        if lam[k].imag < -1e-12 * max(1.0, abs(lam[k])):
            continue  # the conjugate of a pair already listed
        gr, gi = grad[k].real, grad[k].imag
        s_re = float(np.sqrt(max(gr @ c @ gr, 0.0)))
        s_im = float(np.sqrt(max(gi @ c @ gi, 0.0)))
        if np.any(~finite & (np.abs(grad[k]) > 0)):
            s_re = s_im = float("inf")  # a parameter it depends on is not excited at all
        # an unexcited (held) parameter it depends on weighs inf; one it does not depend on, 0 (not 0 x inf)
        weight = np.where(finite, np.abs(gr) * np.where(finite, std, 0.0), np.where(np.abs(gr) > 0, np.inf, 0.0))
        named = [model.names[i] for i in np.argsort(-weight)[:n_named] if weight[i] > 0]
        out.append({"real": float(lam[k].real), "imag": float(abs(lam[k].imag)), "std_real": s_re,
                    "std_imag": s_im, "stability_determined": bool(abs(lam[k].real) > sigmas * s_re),
                    "parameters": named})
    return out


def redundant(names: list[str], theta: np.ndarray, cov: np.ndarray, limit: float = REDUNDANT_LIMIT) -> list[dict]:
    """Sets of parameters the runs cannot separate, each ``{"parameters", "exact", "rho",
    "direction", "determined", "value", "std"}``.

    From the information matrix ``F = cov^+`` (finite part) scaled to a unit diagonal: every
    eigenvector whose eigenvalue is below ``1 - limit`` (a pair at |rho| = limit has eigenvalue
    ``1 - |rho|``) is a direction along which the parameters move (``direction``, theta units, the
    largest component 1) hardly changing the fit. For two parameters ``a, b`` the determined
    combination ``a - k b`` (k = da/db along that direction, so that it does not move) is given
    with its value and standard error; ``exact`` when the eigenvalue is at rounding level."""
    d = np.diag(cov)
    ok = np.flatnonzero(np.isfinite(d) & (d > 0))
    if ok.size < 2:
        return []
    sub = cov[np.ix_(ok, ok)]
    F = np.linalg.pinv(sub, hermitian=True, rcond=1e-13)
    f = np.diag(F)
    if not np.all(f > 0):
        return []
    D = 1 / np.sqrt(f)
    lam, V = np.linalg.eigh(F * np.outer(D, D))
    out = []
    for k in np.flatnonzero(lam < (1 - limit) * max(lam.max(), 1.0)):
        v = V[:, k] * D  # theta units
        scale = np.abs(v).max()
        involved = np.flatnonzero(np.abs(v) > 0.05 * scale)
        if involved.size < 2:
            continue  # one parameter alone: poorly determined, not redundant (flagged there)
        v = v / v[involved[np.argmax(np.abs(v[involved]))]]
        entry = {"parameters": [names[ok[i]] for i in involved], "exact": bool(lam[k] <= RANK_TOL * lam.max()),
                 "direction": {names[ok[i]]: float(v[i]) for i in involved}, "determined": None,
                 "value": float("nan"), "std": float("nan")}
        if involved.size == 2:
            i, j = involved
            kk = v[i] / v[j]  # along the direction a changes kk times as much as b: a - kk b is unchanged
            w = np.zeros(len(ok))
            w[i], w[j] = 1.0, -kk
            r = sub[i, j] / np.sqrt(sub[i, i] * sub[j, j])
            entry.update(rho=float(np.clip(r, -1, 1)), determined=f"{names[ok[i]]} {'-' if kk >= 0 else '+'} "
                         f"{abs(kk):.6g} {names[ok[j]]}", value=float(theta[ok[i]] - kk * theta[ok[j]]),
                         std=float(np.sqrt(max(w @ sub @ w, 0.0))))
        out.append(entry)
    return out


def zero_shift_duplicates(model) -> dict[str, str]:
    """``{parameter: output}`` of the free parameters that only enter the output equation of
    ``output`` on constant pseudo-inputs (a declared output bias): they duplicate a per-run zero
    shift of that output."""
    from ..model.pseudo_inputs import specs

    p = model.profile
    constant = [j for j, u in enumerate(p.input_names) if "constant" in specs(p).get(u, {})]
    if not constant:
        return {}
    out = {}
    for i, name in enumerate(model.names):
        if np.any(model.dA[i]) or np.any(model.dB[i]) or np.any(model.dC[i]):
            continue
        dD = model.dD[i]
        others = np.delete(dD, constant, axis=1)
        rows = np.flatnonzero(np.any(dD[:, constant] != 0, axis=1))
        if not np.any(others) and rows.size == 1:
            out[name] = list(p.outputs)[rows[0]]
    return out


def assess(names: list[str], theta: np.ndarray, std: np.ndarray, cov: np.ndarray, model) -> dict:
    """All checks together: ``correlated`` pairs, ``poorly_determined`` names, ``redundant`` sets,
    ``modes`` and the ``undetermined_modes`` (indices into ``modes``) whose stability the runs do
    not determine."""
    rho = correlation(cov)
    modes = mode_uncertainty(model, cov)
    return {"correlated": correlated_pairs(names, rho), "poorly_determined": poorly_determined(names, theta, std),
            "redundant": redundant(names, theta, cov),
            "modes": modes, "undetermined_modes": [i for i, m in enumerate(modes) if not m["stability_determined"]],
            "limits": {"correlation": CORRELATION_LIMIT, "relative_std": REL_STD_LIMIT, "mode_sigmas": MODE_SIGMAS,
                       "redundant": REDUNDANT_LIMIT}}


def report_lines(check: dict) -> list[str]:
    """Plain-text lines for ``summary()``: nothing when everything is well determined."""
    lines = []
    for r in check.get("redundant", []):
        lines.append(f"  REDUNDANT{' (exactly)' if r['exact'] else ''}: {', '.join(r['parameters'])} move together "
                     f"(direction {', '.join(f'{k} {v:+.4g}' for k, v in r['direction'].items())}) without "
                     f"changing the fit: not identifiable one by one"
                     + (f"; determined: {r['determined']} = {r['value']:.6g} ± {r['std']:.3g}" if r["determined"]
                        else "; only combinations across that direction are determined"))
    for q in check["correlated"]:
        lines.append(f"  correlated: {q['a']} and {q['b']} (rho = {q['rho']:+.3f}): the runs move them together")
    if check["poorly_determined"]:
        lines.append(f"  poorly determined (std error > {REL_STD_LIMIT:.0%} of the estimate): "
                     f"{', '.join(check['poorly_determined'])}")
    for i in check["undetermined_modes"]:
        m = check["modes"][i]
        ev = f"{m['real']:+.4g} ± {m['imag']:.4g}j" if m["imag"] > 0 else f"{m['real']:+.4g}"
        lines.append(f"  mode {ev}: NOT IDENTIFIABLE from these runs: real part {m['real']:+.3g} ± "
                     f"{m['std_real']:.3g} 1/s, stable or unstable by chance; most uncertain through "
                     f"{', '.join(m['parameters']) or '-'}")
    if lines:
        lines = ["identifiability:"] + lines + [f"  remedy: {ADVICE}"]
    return lines
