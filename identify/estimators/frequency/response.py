"""Frequency responses from flown runs, their coherence, and the frequency-domain fit cost J.

The CIFER-style view of a test point: for every input-output pair a frequency response
``H(jw)`` with its coherence, estimated from the runs without any model, against which any model's
response (a priori, identified) is checked by Tischler's cost J.

Estimation (:func:`frequency_response`): each run is cut into overlapping (default 50 %) segments of
several window lengths ``T_w``; each segment is detrended, Hann-windowed and Fourier-transformed at
the frequencies of a log-spaced grid (:func:`~identify.estimators.frequency.base.fourier_sum`, a
direct evaluation at arbitrary frequencies, the job a chirp-z transform does in CIFER). Segments of all runs are pooled (runs are concatenated
without any window spanning two runs), giving per window the spectral matrix
``G_ab(w) = mean_s conj(A_s) B_s`` of inputs and outputs. Per output ``y`` the frequency responses
to all inputs together solve ``G_uu H_y = G_uy`` (multi-input conditioning: correct even when the
inputs are correlated, e.g. a pilot's cross-coupled stick), and the coherence of input ``i`` is the
*partial* coherence of ``u_i`` and ``y`` with the other inputs' contributions removed,
``|P_iy|^2 / (P_ii P_yy)`` from ``P`` the inverse of the spectral matrix of ``[u, y]`` (the
ordinary coherence for one input). The normalised random error of ``|H|`` (and the phase error in
rad) is Bendat & Piersol's ``eps = sqrt(1 - g^2) / (|g| sqrt(2 n_d))`` with ``n_d`` the effective
number of averages (Hann, 50 % overlap: ``K / (1 + 2 * 0.167^2)``) less the inputs conditioned on,
``K = (sum_s p_s)^2 / sum_s p_s^2`` counting only the segments that carry the input power ``p_s``
at that frequency. With stationary noise all segments would count (the regression variance is
``sigma^2 / sum_s p_s``); counting only the excited ones keeps the error honest when the noise grows
with the response, as on real flights, at the price of overstating it about twice on
white-noise simulations (test data: RMS of error / eps about 0.5).

Leakage: over a segment the tapered output is ``H U_w + j H' U_w' + ...`` (``U_w'`` the input
tapered by the window's time derivative): the response to input before the segment and the taper's
smearing of H over the window's resolution ~1/T bias the estimate by ``j G_uu^-1 G_uu' H'``. This
bias is coherent -- repeated runs of one sweep leak alike -- so the coherence does not reveal it
and a high-coherence estimate can lie many random errors off (the start of a sweep in the longest
window: 15 % in |H| at 3 cycles). Each window's estimate is corrected by this first-order term,
``H'`` taken from the window's own estimate (its derivative in frequency), and a window is not used
at a frequency where the term exceeds MAX_LEAKAGE random errors (the higher-order rest is then
small against the random error). A window is also used only at frequencies where it holds
MIN_CYCLES cycles (the longest window MIN_CYCLES_LONGEST: it alone sets the lowest frequency) and
has enough averages; where no window is valid nothing is estimated (H nan,
coherence 0, :attr:`FrequencyResponse.resolved` False, shaded grey in the plots).
The composite estimate combines the windows per frequency and pair with weights ``1 / eps_k^2``
(the most accurate window dominates); because all windows see the same data their errors are
correlated, so the composite error is the weighted mean of the windows' errors, an upper bound
(``var(sum w_k H_k) <= (sum w_k sigma_k)^2``), not the smaller independent-average value.

Fit cost (:func:`fit_cost`): Tischler's ``J = 20 / n_w * sum W_g (dB error)^2 + W_p (deg error)^2``
weighted by ``W_gamma = (1.58 (1 - exp(-g^2)))^2``, over the frequencies with a valid estimate, a
coherence of at least 0.6 and a random error of at most MAX_RANDOM_ERROR (nothing is judged where
nothing is resolved), and only for pairs with MIN_POINTS such points and an input some run moves
(``g^2`` is the coherence as stored here, the squared coherence function); a mean ``J <= 100`` with no
pair above 200 is the usual mark of a model that fits (Tischler & Remple). The report states the
lowest resolved frequency against the slowest mode the inputs excite: below it no model is judged.
"""
from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...data.runs import Run
from ...errors import EstimationError
from ...model.linear import LinearModel
from ...model.pseudo_inputs import APPLIED
from .base import fourier_sum

MIN_COHERENCE = 0.6  # frequencies below it carry too little information for J and plots' judgement
OVERLAP_VARIANCE_FACTOR = 1 + 2 * 0.167 ** 2  # Hann at 50 % overlap: correlation of adjacent segments
MAX_LEAKAGE = 2.0  # a window's leakage bias (corrected to first order) may be at most this many random errors
MIN_CYCLES = 3.0  # a window must hold this many periods of a frequency (fewer: leakage bias) ...
MIN_CYCLES_LONGEST = 2.0  # ... except the longest, which sets the lowest frequency (Tischler & Remple:
# w_min = 2 (2 pi / T_max)); a shorter window at 2-3 cycles would only add a worse estimate where a
# longer one already holds 3
N_WINDOWS = 5
W_GAIN, W_PHASE = 1.0, 0.01745  # Tischler's weights on dB and deg errors
MIN_POINTS = 5  # resolved coherent points a pair needs before its J says anything about a model
# a point judges models only if its random error is at most this: with few averages a coherence of
# 0.6 still leaves 30 % errors, more than the difference between a good and a 30 %-off model
MAX_RANDOM_ERROR = 0.2
J_MEAN_FITS, J_PAIR_MAX = 100.0, 200.0  # Tischler & Remple: mean J <= 100 and no pair above 200


@dataclass
class FrequencyResponse:
    """Composite frequency responses of ``outputs`` to ``inputs``.

    ``omega`` (nf,) rad/s; ``H`` (nf, ny, nu) complex (output units per input unit);
    ``coherence`` (nf, ny, nu) partial coherence (ordinary for one input), 0..1;
    ``multiple_coherence`` (nf, ny) of each output with all inputs; ``random_error`` (nf, ny, nu)
    normalised random error of ``|H|`` (also the phase error in rad), inf where no window is valid;
    ``windows`` the window lengths (s) used; ``runs`` the sources.
    """

    omega: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    multiple_coherence: np.ndarray
    random_error: np.ndarray
    inputs: list[str]
    outputs: list[str]
    windows: list[float] = field(default_factory=list)
    runs: list[str] = field(default_factory=list)
    unmoved: list[str] = field(default_factory=list)  # inputs no run moves: their pairs say nothing
    # (nf, ny, nu) window length (s) behind each composite point, weighted as the estimate: its
    # resolution ~1.5/window Hz says how many neighbouring grid points share its errors
    window: np.ndarray | None = None
    # (n_windows, nf, ny, nu) each window's share of each composite point and the segments' overlap:
    # with them :func:`replay` puts other runs through exactly this estimate
    weights: np.ndarray | None = None
    overlap: float = 0.5

    @property
    def magnitude_db(self) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return 20 * np.log10(np.abs(self.H))

    @property
    def phase_deg(self) -> np.ndarray:
        """Phase in deg, unwrapped along frequency over the frequencies with an estimate (nan elsewhere)."""
        angle = np.angle(self.H)
        out = np.full(angle.shape, np.nan)
        for j, i in np.ndindex(angle.shape[1:]):
            ok = np.isfinite(angle[:, j, i])
            out[ok, j, i] = np.degrees(np.unwrap(angle[ok, j, i]))
        return out

    @property
    def resolved(self) -> np.ndarray:
        """(nf, ny, nu) True where some window gives a valid estimate: enough cycles and averages,
        leakage bias small against the random error; elsewhere H is nan and nothing is claimed."""
        return np.isfinite(self.random_error)

    def resolved_lines(self) -> list[str]:
        """Per pair the frequency range (Hz) with a valid estimate and its coherent share, for reports."""
        f = self.omega / (2 * np.pi)
        lines = [f"resolved frequencies (a valid window; coherence >= {MIN_COHERENCE} of them):"]
        if self.unmoved:
            lines.append(f"  inputs no run moves (their pairs left out): {', '.join(self.unmoved)}")
        for j, y in enumerate(self.outputs):
            for i, u in enumerate(self.inputs):
                if u in self.unmoved:
                    continue
                ok = self.resolved[:, j, i]
                coherent = int((ok & (self.coherence[:, j, i] >= MIN_COHERENCE)).sum())
                span = f"{f[ok].min():.3g}..{f[ok].max():.3g} Hz, {ok.sum()} of {f.size} frequencies" if ok.any() \
                    else "none"
                lines.append(f"  {y + '/' + u:<22}{span} ({coherent} coherent)")
        return lines

    @property
    def lowest_resolved(self) -> float:
        """Lowest frequency (rad/s) with a valid estimate for some pair of a moved input (nan if none)."""
        moved = [i for i, u in enumerate(self.inputs) if u not in self.unmoved]
        ok = self.resolved[:, :, moved].any(axis=(1, 2)) if moved else np.zeros(len(self.omega), bool)
        return float(self.omega[ok].min()) if ok.any() else float("nan")

    def resolution_line(self, model: LinearModel | None = None) -> str:
        """The lowest resolved frequency against the model's slowest mode that the inputs excite,
        and what record would resolve it when the data do not reach it."""
        lo = self.lowest_resolved
        head = f"lowest resolved frequency {lo / (2 * np.pi):.3g} Hz ({lo:.3g} rad/s; longest window " \
               f"{max(self.windows):.3g} s holding at least {MIN_CYCLES_LONGEST:g} cycles)"
        if model is None or not np.isfinite(lo):
            return head
        slow = excited_modes(model, [u for u in self.inputs if u not in self.unmoved])
        if not slow:
            return head + "; the inputs excite no mode of the model"
        w = slow[0]
        if w >= lo:
            return head + f": reaches the slowest input-excited mode ({w / (2 * np.pi):.3g} Hz)"
        T = MIN_CYCLES_LONGEST * 2 * np.pi / w
        miss = f": does NOT reach the slowest input-excited mode ({w / (2 * np.pi):.3g} Hz, {w:.3g} rad/s): "
        if T > max(self.windows):
            why = (f"that needs windows of {T:.3g} s, i.e. records of at least {2 * T:.3g} s "
                   f"(the windows here allow records of {2 * max(self.windows):.3g} s)")
        else:  # long enough, but the input's power there sits in too few segments
            why = ("the longest window holds it, but too few segments carry input at that frequency "
                   "(fewer than 2 averages: a single sweep passes it once); repeat the low end or fly more runs")
        return head + miss + why + f"; below {lo / (2 * np.pi):.3g} Hz the models are not judged"

    def pair(self, output: str, input: str) -> tuple[int, int]:
        return self.outputs.index(output), self.inputs.index(input)

    def to_csv(self, path: str | Path) -> Path:
        """One row per frequency and pair: omega, frequency (Hz), output, input, magnitude (dB),
        phase (deg), coherence, random error, resolved (1: a valid window; 0: no estimate)."""
        path = Path(path)
        mag, ph = self.magnitude_db, self.phase_deg
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["omega_rad_s", "frequency_hz", "output", "input", "magnitude_db", "phase_deg",
                        "coherence", "random_error", "resolved"])
            for j, y in enumerate(self.outputs):
                for i, u in enumerate(self.inputs):
                    for k, om in enumerate(self.omega):
                        w.writerow([f"{om:.6g}", f"{om / (2 * np.pi):.6g}", y, u, f"{mag[k, j, i]:.6g}",
                                    f"{ph[k, j, i]:.6g}", f"{self.coherence[k, j, i]:.6g}",
                                    f"{self.random_error[k, j, i]:.6g}", int(self.resolved[k, j, i])])
        return path


# -- estimation ----------------------------------------------------------------------------------
def frequency_response(runs: Run | list[Run], inputs: list[str], outputs: list[str], *,
                       omega: np.ndarray | None = None, windows: list[float] | None = None,
                       f_range: tuple[float, float] | None = None, n_freq: int = 80,
                       overlap: float = 0.5) -> FrequencyResponse:
    """Composite frequency responses of ``outputs`` to ``inputs`` from one or several runs.

    ``omega``: frequencies (rad/s), default ``n_freq`` log-spaced over ``f_range`` (Hz; default
    from two cycles of the longest window to 0.4 x the sample rate, at most 5 Hz); ``windows``:
    window lengths (s), default five from the longest with enough averages down to a sixth of it.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    if not runs or not inputs or not outputs:
        raise EstimationError("frequency response: need runs, inputs and outputs")
    names = list(inputs) + list(outputs)
    for r in runs:
        r.require(names, "the frequency response")
        bad = [n for n in names if not np.all(np.isfinite(r[n]))]
        if bad:
            raise EstimationError(f"{r.source}: non-finite values in channel(s) {', '.join(bad)}")
    dt = runs[0].dt
    if any(abs(r.dt - dt) > 1e-6 * dt for r in runs):
        raise EstimationError("frequency response: runs have different sample rates")
    if not 0 <= overlap < 1:
        raise EstimationError(f"overlap must be within 0..1, got {overlap}")
    nu = len(inputs)
    windows = sorted(windows or default_windows([r.duration for r in runs], nu, overlap), reverse=True)
    if omega is None:
        lo, hi = f_range or (MIN_CYCLES_LONGEST / windows[0], min(0.4 / dt, 5.0))
        if not 0 < lo < hi:
            raise EstimationError(f"frequency range {lo:g}..{hi:g} Hz is empty")
        omega = 2 * np.pi * np.geomspace(lo, hi, n_freq)
    omega = np.asarray(omega, dtype=float)
    data = [r.matrix(names) for r in runs]
    # an input no run moves (held at trim, or absent from every record) has no response to estimate
    unmoved = [u for i, u in enumerate(inputs) if all(np.ptp(x[:, i]) <= 1e-12 * (1 + np.abs(x[:, i]).max())
                                                        for x in data)]
    per_window = [_window_estimate(data, dt, T, omega, nu, overlap, MIN_CYCLES_LONGEST if k == 0 else MIN_CYCLES)
                  for k, T in enumerate(windows)]
    H, coh, mult, err, window, weights = _composite(per_window, windows)
    return FrequencyResponse(omega, H, coh, mult, err, list(inputs), list(outputs), list(windows),
                             [r.source for r in runs], unmoved, window, weights, overlap)


def replay(fr: FrequencyResponse, runs: list[Run]) -> np.ndarray:
    """H (nf, ny, nu) that ``runs`` give through ``fr``'s estimate: its frequencies, windows, leakage
    correction and composite weights (nan where ``fr`` has no estimate). Runs simulated from a model
    with the flown inputs show what the estimate makes of that model's response (its deterministic
    error: leakage, the segments' transients), whatever their own noise level would have allowed."""
    data = [r.matrix(list(fr.inputs) + list(fr.outputs)) for r in runs]
    nu = len(fr.inputs)
    est = [_window_estimate(data, runs[0].dt, T, fr.omega, nu, fr.overlap) for T in fr.windows]
    H = np.stack([e[0] for e in est if e is not None])
    has = fr.weights.sum(axis=0) > 0
    return np.where(has, np.nansum(fr.weights * np.where(fr.weights > 0, H, 0), axis=0), np.nan + 0j)


def default_windows(durations: list[float], n_inputs: int, overlap: float = 0.5) -> list[float]:
    """Five window lengths (s): the longest (at most half the longest run) that still gives
    ``n_inputs + 2`` segments over the runs, down to a sixth of it."""
    step = 1 - overlap
    # K segments of T from a run of length D: floor((D - T) / (step T)) + 1; search the longest T
    need = n_inputs + 2
    candidates = np.linspace(max(durations), 0.02 * max(durations), 400)
    counts = [sum(max(0, int(np.floor((D - T) / (step * T) + 1e-9)) + 1) if D >= T else 0 for D in durations)
              for T in candidates]
    # at most half the longest run: a taper across a whole transient record distorts the relation
    ok = [T for T, c in zip(candidates, counts) if c >= need and T <= 0.5 * max(durations)]
    if not ok:
        raise EstimationError(f"runs too short for a frequency response with {n_inputs} input(s)")
    return list(np.geomspace(ok[0], ok[0] / 6, N_WINDOWS))


def _segments(x: np.ndarray, L: int, step: int) -> np.ndarray:
    """Overlapping segments (K, L, nch) of a run (N, nch)."""
    starts = range(0, len(x) - L + 1, step)
    return np.stack([x[s:s + L] for s in starts]) if len(x) >= L else np.zeros((0, L, x.shape[1]))


def _detrend(seg: np.ndarray) -> np.ndarray:
    """Each segment (K, L, nch) minus its least-squares line in time (axis 1), as
    ``scipy.signal.detrend`` does; numpy alone: scipy.signal takes 0.4 s to import, a third of an
    ``identify estimate`` process."""
    L = seg.shape[1]
    t = np.arange(L) - (L - 1) / 2
    slope = np.einsum("l,klc->kc", t, seg) / max(float(t @ t), 1e-300)
    return seg - seg.mean(axis=1, keepdims=True) - t[None, :, None] * slope[:, None, :]


def _window_estimate(data: list[np.ndarray], dt: float, T: float, omega: np.ndarray, nu: int, overlap: float,
                     min_cycles: float = MIN_CYCLES):
    """For one window length: H corrected for leakage, partial and multiple coherence, and the
    random error (inf where this window's estimate is not valid)."""
    L = max(int(round(T / dt)), 4)
    step = max(1, int(round(L * (1 - overlap))))
    seg = np.concatenate([_segments(x, L, step) for x in data])  # (K, L, nch)
    if len(seg) == 0:
        return None
    valid = (omega * L * dt >= 2 * np.pi * min_cycles) & (omega < np.pi / dt)
    tr = _Transforms(_detrend(seg), dt, omega, nu)
    F, G = tr.F, tr.G
    # averages that count: segments whose input power at a frequency is small add nothing, so a
    # 3211 (power in one or two segments) or a sweep (each frequency in a few) has few per frequency
    power = (np.abs(F[:, :, :nu]) ** 2).sum(axis=2)  # (K, nf)
    n_eff = power.sum(axis=0) ** 2 / np.maximum((power ** 2).sum(axis=0), 1e-300)
    n_d = n_eff / (OVERLAP_VARIANCE_FACTOR if overlap > 0 else 1.0) - (nu - 1)
    valid = valid & (n_d >= 2)  # coherence from fewer averages is near 1 whatever the data
    H = np.swapaxes(tr.solve(G[:, :nu, nu:]), 1, 2)  # (nf, ny, nu)
    coh, mult = _coherences(G, nu)
    bias = tr.leakage_bias(H)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.sqrt((1 - coh) / (coh * 2 * np.maximum(n_d, 1e-9)[:, None, None]))
        leak = np.abs(bias) / np.abs(H)
    valid = valid[:, None, None] & (leak <= MAX_LEAKAGE * err)
    err[~valid | ~np.isfinite(err)] = np.inf
    return H - bias, coh, mult, err


def _coherences(G: np.ndarray, nu: int) -> tuple[np.ndarray, np.ndarray]:
    """Partial coherence (nf, ny, nu) of each input with each output (the other inputs' parts
    removed) and multiple coherence (nf, ny), from the spectral matrix G (nf, nch, nch)."""
    nf, ny = G.shape[0], G.shape[1] - nu
    coh, mult = np.zeros((nf, ny, nu)), np.zeros((nf, ny))
    for j in range(ny):
        idx = list(range(nu)) + [nu + j]
        M = G[:, idx][:, :, idx]
        P = np.linalg.inv(M + _ridge(M))
        Pyy = P[:, nu, nu].real
        coh[:, j] = np.abs(P[:, :nu, nu]) ** 2 / (np.einsum("fii->fi", P[:, :nu, :nu]).real * Pyy[:, None])
        mult[:, j] = 1 - 1 / np.maximum(Pyy * M[:, nu, nu].real, 1.0)
    return np.clip(np.nan_to_num(coh), 0.0, 1.0), np.clip(mult, 0.0, 1.0)


class _Transforms:
    """Hann-tapered transforms of segments (K, L, nch) at omega (rad/s): ``F`` (K, nf, nch) and
    the spectral matrix ``G`` (nf, nch, nch), ``G_ab = mean_s conj(A_s) B_s``."""

    def __init__(self, seg: np.ndarray, dt: float, omega: np.ndarray, nu: int):
        self.seg, self.nu = seg, nu
        self.t, self.omega = np.arange(seg.shape[1]) * dt, omega
        self.hann = np.hanning(seg.shape[1])
        self.F = self._transform(self.hann)
        self.G = np.einsum("sfa,sfb->fab", self.F.conj(), self.F) / len(seg)
        Guu = self.G[:, :nu, :nu]
        self._Guu = Guu + _ridge(Guu)

    def _transform(self, taper: np.ndarray, channels=slice(None)) -> np.ndarray:
        return fourier_sum(self.seg[:, :, channels] * taper[None, :, None], self.t, self.omega)

    def _cross(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """(nf, nu, nb) mean over segments of conj(A) B, A's inputs only."""
        return np.einsum("sfa,sfb->fab", A[:, :, :self.nu].conj(), B) / len(A)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``G_uu^-1 rhs`` per frequency, rhs (nf, nu, k)."""
        return np.linalg.solve(self._Guu, rhs)

    def leakage_bias(self, H: np.ndarray) -> np.ndarray:
        """First-order leakage bias (nf, ny, nu) of the estimate ``H`` (nf, ny, nu) from these segments.

        Over a segment the tapered output is ``Y_w(w) = H(w) U_w(w) + j H'(w) U_w'(w) + ...``, ``U_w'``
        the transform of the input tapered by the window's time derivative (``(v - w) W(w - v)`` is
        the transform of ``j w'(t)``): the response to input before the segment and the taper's
        smearing of H over its resolution ~1/T. Averaged, ``E[H_est] - H = j G_uu^-1 G_uu' H'``.
        ``G_uu'`` vanishes for an input spread evenly over the segment (the taper's derivative is
        odd about its middle) and is large where a frequency's input power sits near a segment's
        edge or just beside it in frequency: the start of a sweep in a long window, the end of a
        sweep cut by the record's end. Repeated runs leak alike, so the coherence cannot see this
        bias. ``H'`` is the derivative of the estimate itself (transforms of ``-j t`` times the
        tapered signals): the slope at the window's own resolution, the scale that leaks."""
        nu = self.nu
        Gud = self._cross(self.F, self._transform(np.gradient(self.hann, self.t), slice(0, nu)))  # (nf, nu, nu)
        Ft = -1j * self._transform(self.t * self.hann)  # dF/dw (a real taper: one real transform)
        dG = self._cross(Ft, self.F) + self._cross(self.F, Ft)  # d/dw of [G_uu, G_uy]
        dH = self.solve(dG[:, :, nu:] - dG[:, :, :nu] @ np.swapaxes(H, 1, 2))  # d/dw of H^T (nf, nu, ny)
        return np.swapaxes(1j * self.solve(Gud @ dH), 1, 2)


def _ridge(M: np.ndarray) -> np.ndarray:
    """A tiny diagonal load (1e-12 of the largest power) so that an input without power at some
    frequency gives zero coherence instead of a singular solve."""
    d = np.einsum("fii->fi", M).real
    scale = np.maximum(d.max(axis=1), 1e-300)[:, None] * 1e-12
    return np.einsum("fi,ij->fij", np.broadcast_to(scale, d.shape), np.eye(M.shape[1]))


def _composite(per_window, windows):
    """Combine window estimates with weights 1/eps^2 (see the module notes); also the weighted
    window length behind each point."""
    lengths = np.array([T for w, T in zip(per_window, windows) if w is not None])
    est = [w for w in per_window if w is not None]
    if not est:
        raise EstimationError("frequency response: no window fits in the runs")
    H = np.stack([e[0] for e in est])
    coh = np.stack([e[1] for e in est])
    mult = np.stack([e[2] for e in est])
    err = np.stack([e[3] for e in est])
    with np.errstate(divide="ignore"):
        w = np.where(np.isfinite(err), 1 / np.maximum(err, 1e-12) ** 2, 0.0)
    total = w.sum(axis=0)
    has = total > 0
    wn = np.where(has, w / np.where(has, total, 1.0), 0.0)
    H_c = np.where(has, (wn * H).sum(axis=0), np.nan + 0j)
    coh_c = np.where(has, (wn * coh).sum(axis=0), 0.0)
    err_c = np.where(has, (wn * np.where(np.isfinite(err), err, 0.0)).sum(axis=0), np.inf)
    w_out = wn.mean(axis=3)  # output-level weights for the multiple coherence
    mult_c = (w_out * mult).sum(axis=0)
    window_c = np.where(has, np.tensordot(lengths, wn, axes=1), np.nan)
    return H_c, coh_c, mult_c, err_c, window_c, wn


# -- models against the estimate -----------------------------------------------------------------
def model_response(model: LinearModel, omega: np.ndarray, inputs: list[str] | None = None,
                   outputs: list[str] | None = None, applied: dict[str, float] | None = None) -> np.ndarray:
    """The model's response (nf, ny, nu) as flown: :meth:`LinearModel.frequency_response` times
    ``e^{-jw tau}`` for the profile's declared input delays (``meta.delays``: refine's, a control
    system's), less those ``applied`` already to the runs' inputs (prepared runs carry them)."""
    p = model.profile
    H = model.frequency_response(omega, inputs, outputs)
    delays = {k: float(v) for k, v in dict(p.meta.get("delays", {})).items()}
    applied = applied or {}
    tau = np.array([delays.get(u, 0.0) - float(applied.get(u, 0.0)) for u in (inputs or p.input_names)])
    s = 1j * np.atleast_1d(np.asarray(omega, dtype=float))
    return H * np.exp(-s[:, None] * tau[None, :])[:, None, :] if tau.any() else H


def excited_modes(model: LinearModel, inputs: list[str]) -> list[float]:
    """Natural frequencies (rad/s, ascending) of the model's modes that ``inputs`` excite (nonzero
    controllability through the input matrix and observability in the outputs); zero eigenvalues
    (pure integrations) left out."""
    p = model.profile
    ui = [p.input_names.index(u) for u in inputs if u in p.input_names]
    if not ui:
        return []
    lam, V = np.linalg.eig(model.A)
    try:
        W = np.linalg.inv(V)
    except np.linalg.LinAlgError:
        return sorted({float(abs(v)) for v in lam if abs(v) > 1e-9})
    gain = np.abs(W @ model.B[:, ui]).max(axis=1) * np.abs(model.C @ V).max(axis=0)
    keep = (gain > 1e-9 * max(gain.max(), 1e-300)) & (np.abs(lam) > 1e-6)
    return sorted({round(float(abs(v)), 12) for v in lam[keep]})


def fit_cost(fr: FrequencyResponse, model: LinearModel, min_coherence: float = MIN_COHERENCE,
             applied: dict[str, float] | None = None) -> dict:
    """Tischler's J per input-output pair of ``fr`` (for pairs the model has) and their mean.

    Only points that are resolved (a valid window), coherent (>= ``min_coherence``) and accurate
    (random error <= MAX_RANDOM_ERROR) count; a pair with fewer than MIN_POINTS of them is not
    judged, and pairs of inputs no run moves are left out.
    Returns ``{"pairs": {"y/u": J}, "mean": J or None, "n_frequencies": {"y/u": n}, "not_judged":
    {"y/u": n}, "left_out": [inputs], "worst": "y/u" or None, "fits": bool or None}``.
    """
    p = model.profile
    outs = [y for y in fr.outputs if y in p.outputs]
    ins = [u for u in fr.inputs if u in p.input_names and u not in fr.unmoved]
    Hm = model_response(model, fr.omega, ins, outs, applied)
    pairs, counts, not_judged = {}, {}, {}
    for jm, y in enumerate(outs):
        for im, u in enumerate(ins):
            j, i = fr.pair(y, u)
            g2 = fr.coherence[:, j, i]
            use = fr.resolved[:, j, i] & (g2 >= min_coherence) & np.isfinite(fr.H[:, j, i]) & \
                (fr.random_error[:, j, i] <= MAX_RANDOM_ERROR) & (np.abs(Hm[:, jm, im]) > 0)
            key = f"{y}/{u}"
            counts[key] = int(use.sum())
            if use.sum() < MIN_POINTS:
                not_judged[key] = int(use.sum())
                continue
            Hd, Hc = fr.H[use, j, i], Hm[use, jm, im]
            mag = 20 * np.log10(np.abs(Hc) / np.abs(Hd))
            phase = np.degrees(np.angle(Hc / Hd))  # wrapped difference: no unwrapping ambiguity
            w = (1.58 * (1 - np.exp(-g2[use]))) ** 2
            pairs[key] = float(20 / use.sum() * np.sum(w * (W_GAIN * mag ** 2 + W_PHASE * phase ** 2)))
    mean = float(np.mean(list(pairs.values()))) if pairs else None
    worst = max(pairs, key=pairs.get) if pairs else None
    fits = None if mean is None else bool(mean <= J_MEAN_FITS and pairs[worst] <= J_PAIR_MAX)
    return {"pairs": pairs, "mean": mean, "n_frequencies": counts, "not_judged": not_judged,
            "left_out": [u for u in fr.inputs if u in fr.unmoved and u in p.input_names], "worst": worst,
            "fits": fits}


def format_cost(cost: dict, label: str = "model", details: bool = True) -> str:
    """One verdict line per model, then J per judged pair on one line; with ``details`` the pairs
    not judged and the inputs left out on one line each (the data's, the same for every model)."""
    if cost.get("mean") is None:
        lines = [f"fit cost J of the {label}: not judged (no pair has {MIN_POINTS} resolved points of coherence "
                 f">= {MIN_COHERENCE} and random error <= {MAX_RANDOM_ERROR:g})"]
    else:
        w = cost["worst"]
        verdict = "fits" if cost["fits"] else "does NOT fit"
        lines = [f"fit cost J of the {label}: mean {cost['mean']:.1f} over {len(cost['pairs'])} pair(s), worst {w} "
                 f"{cost['pairs'][w]:.1f}: {verdict} (Tischler: mean <= {J_MEAN_FITS:g}, no pair > {J_PAIR_MAX:g})",
                 "  " + ", ".join(f"{k} {v:.1f}" for k, v in cost["pairs"].items())]
    if not details:
        return "\n".join(lines)
    if cost.get("not_judged"):
        lines.append(f"  not judged (fewer than {MIN_POINTS} resolved points of coherence >= {MIN_COHERENCE}, "
                     f"random error <= {MAX_RANDOM_ERROR:g}): "
                     + ", ".join(cost["not_judged"]))
    if cost.get("left_out"):
        lines.append(f"  left out: the pairs of {', '.join(cost['left_out'])} (no run moves it)")
    return "\n".join(lines)


def cost_report(runs: list[Run], models: dict[str, LinearModel]) -> tuple[str, dict]:
    """J of each model against the runs' frequency responses (the profile's inputs and outputs):
    text lines for a report and ``{label: cost}``; says so instead when no response can be had."""
    p = next(iter(models.values())).profile
    try:
        fr = frequency_response(runs, p.input_names, list(p.outputs))
    except EstimationError as exc:
        return f"frequency-domain fit cost J: not computed ({exc})", {"not_computed": str(exc)}
    # runs prepared for a profile carry its delays in their inputs already (their metadata says so)
    applied = {k: float(v) for k, v in json.loads(runs[0].meta.get(APPLIED, "{}")).items()} if runs else {}
    costs = {label: fit_cost(fr, m, applied=applied) for label, m in models.items()}
    line = fr.resolution_line(next(iter(models.values())))
    labels = list(costs)
    text = "\n".join([f"frequency-domain fit cost J (Tischler), {line}"] +
                     [format_cost(costs[k], k, details=k == labels[-1]) for k in labels])
    for c in costs.values():  # the data's resolution, with each model's verdict (reports iterate models)
        c["resolution"] = line
    return text, costs
