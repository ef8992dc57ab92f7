"""Are a fit's residuals (output error) or innovations (filter error) white? Ljung-Box, per output.

The Cramér-Rao bounds of ML and FEM hold for white residuals only: coloured ones (turbulence
output error cannot model, a process-noise model that does not match the gusts, a pilot or SAS in
the loop) make them too narrow, by several times on turbulent data. After every fit each output's
residuals are tested with the Ljung-Box portmanteau statistic, pooled over the runs::

    Q = N (N + 2) sum_{k=1..h} rho_k^2 / (N - k)        ~ chi-square(h) when white

``rho_k`` the autocorrelation at lag k (each run's mean removed, sums pooled over runs), ``h``
``WHITENESS_LAGS`` (fewer for short records), N the samples. An output is called coloured when its
p-value is below ``WHITENESS_LEVEL`` over the number of outputs (Bonferroni: the family of outputs
at that level). The record (``info["whiteness"]``): per output Q, lags, p-value, lag-1
autocorrelation and the verdict, and the list of coloured outputs.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

WHITENESS_LAGS = 20  # lags of the portmanteau statistic (0.4 s at 50 Hz: a gust's or a loop's colour shows)
WHITENESS_LEVEL = 0.01  # family-wise level over the outputs


def pooled_autocovariance(residuals, lags: int) -> np.ndarray:
    """``(lags + 1, ny)`` sums of lagged products of residuals (N_r, ny) per run, each run's mean
    removed, pooled over the runs (row 0 the sums of squares): the Ljung-Box statistic's ingredients,
    shared with refine's residual diagnostics."""
    acov = np.zeros((lags + 1, np.shape(residuals[0])[1]))
    for e in residuals:
        e = np.asarray(e, float) - np.mean(e, axis=0)
        for k in range(lags + 1):
            acov[k] += np.einsum("ij,ij->j", e[:len(e) - k], e[k:])
    return acov


def whiteness(residuals: list[np.ndarray], outputs: list[str], lags: int = WHITENESS_LAGS,
              level: float = WHITENESS_LEVEL) -> dict:
    """``{"outputs": {name: {Q, lags, p_value, rho_1, white}}, "coloured": [names], "level", "test"}``
    of residuals (N_r, ny) per run; an output without variance (or too few samples) is left out."""
    ny = len(outputs)
    n_total = sum(len(e) for e in residuals)
    h = int(max(1, min(lags, n_total // 5, min(len(e) for e in residuals) - 1)))
    acov = pooled_autocovariance(residuals, h)
    per_output, coloured = {}, []
    for j, name in enumerate(outputs):
        if not (acov[0, j] > 0) or n_total <= h + 1:
            continue
        rho = acov[1:, j] / acov[0, j]
        q = float(n_total * (n_total + 2) * np.sum(rho ** 2 / (n_total - np.arange(1, h + 1))))
        p = float(chi2.sf(q, h))
        white = bool(p >= level / ny)
        per_output[name] = {"Q": q, "lags": h, "p_value": p, "rho_1": float(rho[0]), "white": white}
        if not white:
            coloured.append(name)
    return {"test": f"Ljung-Box, {h} lags, family-wise level {level:g} over the outputs",
            "level": level, "outputs": per_output, "coloured": coloured}


def whiteness_line(record: dict, what: str = "residuals") -> str:
    """One line: which outputs' ``what`` are coloured (their lag-1 autocorrelation), or all white."""
    if not record or not record.get("outputs"):
        return f"whiteness of the {what}: not tested"
    out = record["outputs"]
    if not record["coloured"]:
        return f"whiteness of the {what}: white on every output ({record['test']})"
    listed = ", ".join(f"{y} (rho_1 {out[y]['rho_1']:.2f})" for y in record["coloured"])
    return f"whiteness of the {what}: coloured on {listed} ({record['test']})"
