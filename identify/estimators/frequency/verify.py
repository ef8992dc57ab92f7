"""VERIFY: a model identified in the frequency domain predicts runs in the time domain.

CIFER's last step (Tischler & Remple ch. 12): the model, with every parameter frozen, is driven by
the recorded inputs of a run that took no part in the identification; only what a frequency
response cannot know is fitted to the run: the initial state ``x0`` and a constant zero shift per
output (trim offsets, sensor biases). Both enter the prediction linearly,
``y_k = y_forced,k + C Phi^k x0 + b``, so one linear least-squares fit (outputs weighted as in
J_rms) gives them. The profile's declared input delays are applied to the inputs first.

Figures (per run and over all): Theil's inequality coefficient per output and pooled,
``TIC = rms(z - y) / (rms(z) + rms(y))`` (0 perfect, 1 worthless), and

    J_rms = sqrt( 1 / (n_t n_o) sum_t (z - y)^T W (z - y) )

with Tischler's unit weighting: errors in deg, deg/s, ft/s, ft/s^2 weigh 1 (outputs in rad, rad/s,
m/s, m/s^2 are converted; an output of another unit keeps weight 1 in its own unit, and the report
says so). Guidelines: J_rms <= 1-2 and TIC <= 0.25-0.3 for a model that predicts well.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...data.runs import Run
from ...model.linear import LinearModel
from ...model.profile import output_units
from ...model.pseudo_inputs import prepare
from ...model.simulate import discretize, propagate
from ..result import theil

J_RMS_GUIDELINE, TIC_GUIDELINE = 2.0, 0.3  # upper ends of Tischler & Remple's guidelines (1-2, 0.25-0.3)
# unit -> factor to Tischler's weighting units (deg, deg/s, ft/s, ft/s^2 weigh 1)
UNIT_SCALE = {"rad": np.degrees(1.0), "rad/s": np.degrees(1.0), "rad/s^2": np.degrees(1.0),
              "deg": 1.0, "deg/s": 1.0, "m/s": 1 / 0.3048, "m/s^2": 1 / 0.3048, "m": 1 / 0.3048,
              "ft/s": 1.0, "ft/s^2": 1.0, "ft": 1.0}


@dataclass
class Prediction:
    """One run predicted: ``time`` (N,), ``measured``/``modelled`` (N, ny), fitted ``x0`` (n,) and
    ``zero_shifts`` (ny,), ``tic`` {output: TIC}, pooled ``tic_all`` and ``j_rms``."""

    source: str
    time: np.ndarray
    measured: np.ndarray
    modelled: np.ndarray
    x0: np.ndarray
    zero_shifts: np.ndarray
    tic: dict[str, float]
    tic_all: float
    j_rms: float


@dataclass
class Verification:
    """VERIFY over runs: the predictions and the verdict against the guidelines."""

    predictions: list[Prediction]
    outputs: list[str]
    notes: list[str] = field(default_factory=list)

    @property
    def j_rms(self) -> float:
        """Pooled over all runs (sample-weighted)."""
        n = np.array([len(p.time) for p in self.predictions])
        return float(np.sqrt(np.sum(n * np.array([p.j_rms for p in self.predictions]) ** 2) / n.sum()))

    @property
    def tic(self) -> float:
        """Pooled TIC of all runs and outputs (in the J_rms units)."""
        return float(np.sqrt(np.mean([p.tic_all ** 2 for p in self.predictions])))

    @property
    def passes(self) -> bool:
        return bool(self.j_rms <= J_RMS_GUIDELINE and self.tic <= TIC_GUIDELINE)

    def lines(self) -> list[str]:
        out = [f"VERIFY (time-domain prediction, x0 and zero shifts fitted): J_rms {self.j_rms:.3g}, "
               f"TIC {self.tic:.3g}: " + ("predicts well" if self.passes else "does NOT predict well")
               + f" (guidelines J_rms <= 1-{J_RMS_GUIDELINE:g}, TIC <= 0.25-{TIC_GUIDELINE:g})"]
        for p in self.predictions:
            out.append(f"  {p.source}: J_rms {p.j_rms:.3g}, TIC {p.tic_all:.3g}; per output "
                       + ", ".join(f"{y} {v:.3g}" for y, v in p.tic.items()))
        return out + [f"  note: {n}" for n in self.notes]

    def to_dict(self) -> dict:
        return {"j_rms": self.j_rms, "tic": self.tic, "passes": self.passes, "notes": self.notes,
                "runs": [{"source": p.source, "j_rms": p.j_rms, "tic": p.tic_all, "tic_per_output": p.tic,
                          "x0": p.x0.tolist(), "zero_shifts": p.zero_shifts.tolist()} for p in self.predictions]}


def output_weights(model: LinearModel) -> tuple[np.ndarray, list[str]]:
    """Per output the factor to Tischler's weighting units, and notes for units not known."""
    units = output_units(model.profile)
    scale, notes = [], []
    for y in model.profile.outputs:
        u = units.get(y, "")
        if u in UNIT_SCALE:
            scale.append(UNIT_SCALE[u])
        else:
            scale.append(1.0)
            notes.append(f"output {y} in unit '{u or 'unknown'}': weight 1 in its own unit for J_rms")
    return np.array(scale), notes


def predict(model: LinearModel, run: Run, scale: np.ndarray | None = None) -> Prediction:
    """The model's prediction of one run, initial state and zero shifts fitted (see the module notes)."""
    p = model.profile
    run = prepare(p, [run])[0]
    u = run.matrix(p.input_names)
    z = run.matrix(list(p.outputs))
    N, n, ny = len(run), model.n_states, len(p.outputs)
    scale = np.ones(ny) if scale is None else scale
    Phi, Gamma = discretize(model.A, model.B, run.dt)
    forced = propagate(Phi, u @ Gamma.T, np.zeros(n)) @ model.C.T + u @ model.D.T  # (N, ny)
    states = propagate(Phi, np.zeros((N, n, n)), np.eye(n))  # x_k = Phi^k x0: the initial state's share
    free = np.einsum("yn,knm->kym", model.C, states)  # (N, ny, n)
    # unknowns [x0 (n), b (ny)]: rows (k, output) weighted by the output's J_rms scale
    M = np.concatenate([free, np.broadcast_to(np.eye(ny), (N, ny, ny))], axis=2) * scale[None, :, None]
    rhs = (z - forced) * scale
    sol = np.linalg.lstsq(M.reshape(N * ny, n + ny), rhs.reshape(-1), rcond=None)[0]
    x0, b = sol[:n], sol[n:]
    y = forced + np.einsum("kym,m->ky", free, x0) + b
    tic = {name: theil(z[:, j], y[:, j]) for j, name in enumerate(p.outputs)}
    e = (z - y) * scale
    return Prediction(run.source, run.time, z, y, x0, b, tic, theil((z * scale).ravel(), (y * scale).ravel()),
                      float(np.sqrt(np.mean(e ** 2))))


def verify(model: LinearModel, runs: Run | list[Run]) -> Verification:
    """VERIFY ``model`` on ``runs`` (held out of its identification): predictions, TIC, J_rms."""
    runs = [runs] if isinstance(runs, Run) else list(runs)
    scale, notes = output_weights(model)
    return Verification([predict(model, r, scale) for r in runs], list(model.profile.outputs), notes)


def plot_verification(verification: Verification, path, units: dict[str, str] | None = None):
    """Measured and predicted outputs of every verified run (rows: outputs, columns: runs), TIC in
    each panel; written as a PNG on an Agg canvas. Returns the path."""
    from pathlib import Path

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    preds, outs = verification.predictions, verification.outputs
    units = units or {}
    fig = Figure(figsize=(3.6 * len(preds) + 0.8, 1.7 * len(outs) + 0.8))
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(outs), len(preds), sharex="col", squeeze=False)
    for c, p in enumerate(preds):
        for r, y in enumerate(outs):
            ax = axes[r, c]
            ax.plot(p.time, p.measured[:, r], "k-", lw=1.0, label="measured")
            ax.plot(p.time, p.modelled[:, r], "C3--", lw=1.0, label="predicted")
            ax.text(0.01, 0.97, f"TIC {p.tic[y]:.2f}", transform=ax.transAxes, va="top", fontsize=7)
            if c == 0:
                ax.set_ylabel(f"{y} [{units.get(y) or '-'}]", fontsize=8)
            if r == len(outs) - 1:
                ax.set_xlabel("time [s]")
        axes[0, c].set_title(f"{Path(p.source).name}: J_rms {p.j_rms:.2f}", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"VERIFY: J_rms {verification.j_rms:.2f}, TIC {verification.tic:.2f} "
                 f"(guidelines J_rms <= 1-2, TIC <= 0.25-0.3)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    return Path(path)
