"""Standard errors of the frequency-response fit from the data's own noise (a residual bootstrap).

Why not Tischler's bound ``(G^T G / s^2)^-1`` alone: it treats the fitted points as independent with
one common error variance taken from the fit's residuals. Neither holds for a composite response.
Neighbouring grid points share their errors (each point averages segments over a resolution cell
~1/T wide, and the grid is finer than that: measured on the S 61 benchmark, the errors of adjacent
points correlate 0.89, of points five apart 0.33), and the fit's residuals are mostly the response
estimate's *deterministic* error (leakage and the transients of short segments: 5 % of |H| at the
median there, 2.7 times the random scatter), which repeats from flight to flight and says nothing
about the scatter of the estimates. So that bound was 3-4 times too small, and neither Bendat &
Piersol's coherence error (about 5 times the measured scatter on those runs: it counts only the
segments that carry input) nor a factor of grid points per cell gives the right size either.

What is done instead: the runs' noise is taken as the time-domain residual ``z - y`` of the
identified model's prediction (:func:`.verify.predict`, initial state and zero shifts fitted), less
its part coherent with the inputs (:func:`incoherent_part`: the model's misfit);
``n_draws`` surrogate runs are the prediction plus that residual with its Fourier phases
randomised (one random phase per frequency shared by all outputs of a run, so the noise keeps its
spectrum and its cross-spectra between outputs, coloured or white); each surrogate goes through the
same response estimate and the same fit (started at the estimate, so a few Gauss-Newton steps),
and the sample covariance of the refitted parameters is the estimate's covariance. This propagates
the noise through everything the estimate does (window averaging, the composite's window weights,
the coherence gates, the cost's weighting), with no factor chosen. Its own precision is that of a
sample variance: about ``1 / sqrt(2 (n_draws - 1))`` relative (13 % for 30 draws).
What it does not include: the deterministic error of the response estimate (a bias, the same in
every draw; the caller corrects it with a ratio held fixed over the draws, although across flights
it moves with the estimate: FR scales the covariance for that by its linearised fixed point's gain,
:meth:`.response_fit.FR._fixed_point_gain`). Misfit the band regression cannot take out
(a wrong unstable mode's growth over the record, wrong initial transients) stays in the residual
and enlarges the bounds: the premise is a model that predicts the runs to within their noise.
"""
from __future__ import annotations

import numpy as np

from ...data.runs import Run
from ...errors import EstimationError

N_DRAWS = 30
HALF_BAND = 3  # bins either side: 7 bins, 0.35 Hz on a 20-s run, narrower than the modes' own width
OUTLIER = 5.0  # robust z (median, scaled MAD) beyond which a refit counts as diverged, not as scatter


def incoherent_part(residual: np.ndarray, inputs: np.ndarray, half_band: int = HALF_BAND) -> np.ndarray:
    """Fourier transform (nf, ny) of the part of ``residual`` (N, ny) not coherent with ``inputs``
    (N, nu): per frequency bin, what a regression on the inputs over the ``2 half_band + 1`` bins
    around it leaves, scaled up for the degrees of freedom it took. A model's misfit is a response to
    the inputs, smooth in frequency: it goes into the regression; the noise stays."""
    E = np.fft.rfft(residual - residual.mean(axis=0), axis=0)
    U = np.fft.rfft(inputs - inputs.mean(axis=0), axis=0)
    U = U[:, np.ptp(inputs, axis=0) > 0]  # inputs this run moves
    if U.shape[1] == 0:
        return E
    nb = 2 * half_band + 1
    kernel = np.ones(nb)
    band = lambda x: np.apply_along_axis(lambda c: np.convolve(c, kernel, mode="same"), 0, x)  # noqa: E731
    Suu = band(np.einsum("fa,fb->fab", U.conj(), U).reshape(len(U), -1)).reshape(len(U), U.shape[1], -1)
    Sue = band(np.einsum("fa,fy->fay", U.conj(), E).reshape(len(U), -1)).reshape(len(U), U.shape[1], -1)
    ridge = 1e-12 * np.einsum("fii->f", Suu).real.max() * np.eye(U.shape[1])
    X = np.linalg.solve(Suu + ridge, Sue)  # (nf, nu, ny) the residual's response to the inputs, band by band
    return (E - np.einsum("fa,fay->fy", U, X)) * np.sqrt(nb / (nb - U.shape[1]))


def surrogate_noise(residual: np.ndarray, rng: np.random.Generator, inputs: np.ndarray | None = None) -> np.ndarray:
    """Residual (N, ny) (its part not coherent with ``inputs``, if given) with its Fourier phases
    randomised, shared across columns: the same spectrum and cross-spectra, a new realisation."""
    R = np.fft.rfft(residual - residual.mean(axis=0), axis=0) if inputs is None else incoherent_part(residual, inputs)
    phase = np.exp(2j * np.pi * rng.random(R.shape[0]))
    phase[0] = 1.0
    if residual.shape[0] % 2 == 0:
        phase[-1] = np.sign(np.cos(np.angle(phase[-1]))) or 1.0  # the Nyquist term stays real
    return np.fft.irfft(R * phase[:, None], n=residual.shape[0], axis=0)


def bootstrap_covariance(refit, n_params: int, runs: list[Run], predictions, outputs: list[str],
                         inputs: list[str], n_draws: int = N_DRAWS, seed: int = 0) -> tuple[np.ndarray, int]:
    """Sample covariance (n_params, n_params) of ``refit(surrogate_runs) -> theta`` over ``n_draws``
    surrogates (NaN if fewer than 3 refits succeed) and the number of draws left out: refused by the
    response estimate or the fit (e.g. too few points), or diverged (some parameter more than OUTLIER
    robust standard deviations from the draws' median: one wild refit would otherwise set the bound)."""
    rng = np.random.default_rng(seed)
    thetas, failed = [], 0
    for _ in range(n_draws):
        draws = [r.with_channels({y: pr.modelled[:, k] + e[:, k] for k, y in enumerate(outputs)})
                 for r, pr in zip(runs, predictions)
                 for e in [surrogate_noise(pr.measured - pr.modelled, rng, r.matrix(inputs))]]
        try:
            thetas.append(refit(draws))
        except (ValueError, EstimationError):
            failed += 1
    T = np.array(thetas).reshape(len(thetas), n_params)
    if len(T):
        med = np.median(T, axis=0)
        mad = 1.4826 * np.median(np.abs(T - med), axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(mad > 0, np.abs(T - med) / mad, 0.0)
        keep = np.all(z <= OUTLIER, axis=1)
        failed += int((~keep).sum())
        T = T[keep]
    if len(T) < 3:
        return np.full((n_params, n_params), np.nan), failed
    return np.cov(T, rowvar=False, ddof=1).reshape(n_params, n_params), failed
